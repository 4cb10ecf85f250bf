"""The coordinator as a sans-IO state machine: messages and the clock in, actions out.

Feed it what the network delivered: :meth:`CoordinatorCore.on_liveliness` (a token's key
appeared or vanished), :meth:`~CoordinatorCore.on_pose` (or ``on_poses``, a batch) and
:meth:`~CoordinatorCore.on_agent_state` (raw payloads), :meth:`~CoordinatorCore.on_steer`
(a steering query's payload, answered at once with a :class:`ReplySteer`); once per
broadcast period :meth:`~CoordinatorCore.tick` returns what to do, in order:
:class:`MissionStarted` (once), :class:`PublishDomain`, :class:`PublishWorld` (on the first
tick, before the mission starts, then every WORLD_PERIOD), :class:`PublishStatus` (every
STATUS_PERIOD, with a :class:`RecordScriptClock` while running) and :class:`Finished`
(after DONE_HOLD s of "done", or when stopped before the start). No zenoh and no clock of
its own: ``now`` is monotonic mission seconds (the shell's runtime.clock.scaled monotonic
clock), ``wall`` seconds since the epoch (the run's real wall clock; message stamps are
``wall * time_scale``, as runtime.clock.scaled), and the CPU-cost timers of the sampling
and recording budgets are passed in. The shell (coordinator.link) only carries the actions
out.

S is the script's S_script(tau(t)) (or the steered S at tau): coordinator.pace slows tau
down to the control rate the agents report holding, and the mission ends when tau reaches
the duration; steering requests are handled (and recorded, journalled) in script time.

Composed pieces: coordinator.monitor (the mission's state machine, liveness, e_a record),
coordinator.steering (who moves S; ``Steering.checks`` vetoes a planned motion) and the run
recorder (covswarm.records.recorder.RunRecorder, or None), which the core calls directly:
recording is file output whose CPU cost the core budgets, not a network action.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from covswarm.coordinator.config import DEPLOY_TIMEOUT, CoordinatorConfig
from covswarm.coordinator.monitor import (
    DISCOVERY_EDGE,
    DISCOVERY_PERIOD,
    DISCOVERY_REACH,
    DISCOVERY_WAIT,
    DONE,
    RUNNING,
    START_SETTLE,
    WAITING,
    ErrorRecord,
    ExchangeGaps,
    Liveness,
    MissionPhase,
    TeamChange,
    clip_sample_time,
    discovery_gaps,
    mean_pose_time,
    positions_at,
    start_settle,
)
from covswarm.coordinator.pace import (
    DEPLOY_ALIGN,
    Pace,
    ScriptClock,
    aligned_by,
    broadcast_motion,
    check_deploy_kappa,
    deploy_release,
    hold_gain,
    paced_density,
)
from covswarm.coordinator.steering import (
    Limits,
    MotionCheck,
    Steering,
    default_max_domain_speed,
    world_check,
)
from covswarm.coordinator.team import REPORTED_IDS, Roster
from covswarm.mission.crowding import Crowding
from covswarm.mission.crowding import crowding as estimate_crowding
from covswarm.mission.scenarios import Scenario
from covswarm.protocol import (
    AgentState,
    Domain,
    KeyIds,
    Pose,
    ProtocolError,
    Status,
    World,
    parse_alive_key,
)
from covswarm.protocol.keys import format_ids
from covswarm.records.observations import timed_layers
from covswarm.runtime.ratelog import RateLog
from covswarm.tvd.coverage import aggregate_error, cells, neighbour_pairs
from covswarm.tvd.drive import KHEPERA_IV
from covswarm.world.map_image import map_image
from covswarm.world.wire import to_message

if TYPE_CHECKING:  # the recorder pulls in mcap and websockets; the core only calls it
    from covswarm.records.recorder import RunRecorder

log = logging.getLogger("covswarm.coordinator")

# What the coordinator reads of an AgentState. Every field is checked as AgentState.decode
# checks it (a malformed state is dropped and counted), but neither the message nor its
# relay (neighbours' positions, which only agents read) is built: 10 000 states a second
# at 1000 robots.
_read_state = AgentState.reader("id", "stamp", "neighbors", "stats")

# Own Domains remembered to recognise them when they come back (2.5 s at 20 Hz: far longer
# than a loopback or LAN round trip).
OWN_DOMAINS_KEPT = 50

DONE_HOLD = 1.0  # s of "done" broadcasts, so every agent sees it and stops its robot
STATUS_PERIOD = 0.5  # s
WORLD_PERIOD = 1.0  # s between World broadcasts: a late joiner has the arena within this
# s between two log lines naming the processes the team still waits for (the one clue a
# process started by hand under another --swarm gets: it hears nothing and says nothing)
WAITING_REPORT = 10.0
WAITING_FOR = "still waiting for the team:"  # how the report starts (the launcher quotes it)
STATS_RECORD_PERIOD = 1.0  # s of mission time between two records of the agents' stats
# Largest share of a core that computing e_a may take (it costs ~4 ms for 100 robots,
# ~50 ms for 1000): the coordinator shares the machine with the agents it monitors.
SAMPLE_SHARE = 0.05
# Likewise for recording (covswarm.records): past this share of a core, poses are recorded
# every k-th tick instead of every tick (about 1 ms a tick at 100 robots: every tick).
RECORD_SHARE = 0.05
# Beacon tile side, in units of the mean spacing of the team in S(0): a converged cell's
# reach (agent.neighborhood.cell_reach) is about 2.1 spacings while the domain moves, so it
# fits in an agent's 3 x 3 tiles, which hold ~56 robots whatever the team's size and
# density (at 2 spacings the reach needs 5 x 5 tiles, at 3 they hold 81 robots).
TILE_SPACINGS = 2.5


def swarm_tile_size(scenario: Scenario, agents: int) -> float:
    """The beacon tile size of a run: TILE_SPACINGS x the team's mean spacing in S(0).

    Chosen once per run by the coordinator and broadcast in every Domain: every agent of a
    swarm must use the same tiles (protocol.Domain.tile_size).
    """
    vertices, _ = scenario.domain(0.0)
    x, y = np.asarray(vertices, dtype=float).T
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    return round(TILE_SPACINGS * math.sqrt(area / agents), 3)


@dataclass(frozen=True)
class CoordinatorSettings:
    """What one coordinator run does: its CoordinatorConfig with the scenario loaded and
    the scenario's defaults filled in (:meth:`from_config`)."""

    scenario: Scenario
    swarm: str
    agents: int
    duration: float
    kappa: float
    rate: float  # Hz of Domain broadcasts
    sample_rate: float  # Hz of e_a samples (at most)
    feedforward: bool  # what the agents were started with, recorded in the summary
    law: str = "da"  # the agents' control law ("da" or "d1"), recorded in the summary
    time_scale: float = 1.0  # mission s per wall s (runtime.clock.scaled)
    tile_size: float | None = None  # beacon tiles broadcast to the agents (None: default)
    max_domain_speed: float | None = None  # m/s, steered vertices (None: derived from kappa)
    agent_rate: float = 10.0  # Hz the agents were asked to step at (coordinator.pace)
    pace: bool = True  # slow the script to what the team holds (coordinator.pace)
    # m: hold the script at S(0) from the start until e_a is this low (the deploy hold,
    # coordinator.pace), at most deploy_timeout s of mission time; None: no hold
    deploy_error: float | None = None
    deploy_timeout: float = DEPLOY_TIMEOUT
    # 1/s: the gain broadcast while the hold lasts (S still: Lloyd's iterations, which the
    # mission's gain, chosen for tracking, takes ~3x as many periods over); None: kappa
    deploy_kappa: float | None = None
    record_states: bool = True  # the agents' AgentStates go to the recorder too

    @property
    def hold_kappa(self) -> float:
        """The gain (1/s) broadcast while the deploy hold lasts: deploy_kappa, else kappa."""
        return self.kappa if self.deploy_kappa is None else self.deploy_kappa

    @property
    def script_ends(self) -> bool:
        """Whether the mission ends when the script's tau reaches the duration (paced or
        deployed first), not when the mission time does."""
        return self.pace or self.deploy_error is not None

    @classmethod
    def from_config(cls, config: CoordinatorConfig, scenario: Scenario) -> CoordinatorSettings:
        """``config`` against ``scenario`` (loaded from ``config.scenario``); ValueError for a
        deploy hold's gain without a hold (check_deploy_kappa)."""
        check_deploy_kappa(config.deploy_error, config.deploy_kappa)
        agents = scenario.agents if config.agents is None else config.agents
        return cls(
            scenario=scenario,
            swarm=config.swarm,
            agents=agents,
            duration=scenario.duration if config.duration is None else config.duration,
            kappa=scenario.kappa if config.kappa is None else config.kappa,
            rate=config.rate,
            sample_rate=config.sample_rate,
            feedforward=config.feedforward,
            law=config.law,
            time_scale=config.time_scale,
            tile_size=(
                swarm_tile_size(scenario, agents) if config.tile_size is None else config.tile_size
            ),
            max_domain_speed=config.max_domain_speed,
            agent_rate=config.agent_rate,
            pace=config.pace,
            deploy_error=config.deploy_error,
            deploy_timeout=config.deploy_timeout,
            deploy_kappa=config.deploy_kappa,
            record_states=config.record_states,
        )

    @cached_property
    def crowding(self) -> Crowding:
        """Whether the team fits S over the mission: estimated once, for the warning at the
        start and for summary.json."""
        return estimate_crowding(self.scenario, self.agents, self.duration)

    def steering_limits(self) -> Limits:
        """What a steering request may ask of this run's team (coordinator.steering.Limits)."""
        speed = self.max_domain_speed
        if speed is None:
            speed = default_max_domain_speed(KHEPERA_IV.max_wheel_speed, self.kappa)
        return Limits.for_team(
            self.agents, speed, self.scenario.workspace, self.scenario.robot_diameter
        )


@dataclass
class Observed:
    """Everything the coordinator learnt from the network during the run."""

    record: ErrorRecord = field(default_factory=ErrorRecord)
    liveness: Liveness = field(default_factory=Liveness)
    poses: dict[int, tuple[float, float]] = field(default_factory=dict)
    pose_stamps: dict[int, float] = field(default_factory=dict)  # s, the run's wall clock
    # (stamp s, x m, y m) of each robot's pose before the latest (its velocity for e_a)
    earlier_poses: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    agent_stats: dict[int, dict[str, float]] = field(default_factory=dict)
    rejected: int = 0  # messages dropped as malformed (ProtocolError)
    clipped_samples: int = 0  # e_a samples not placed at their poses' time (clip_sample_time)
    # Domains heard on the swarm's domain key that this coordinator did not publish: a
    # second coordinator or a forger (issue 21), counted and reported.
    foreign_domains: int = 0
    # Poses and AgentStates whose own id is not their key's: in secure mode a process may
    # put only on its own keys, so a message naming another robot is a forger's with some
    # robot's credentials (covswarm.protocol.KeyIds); dropped and counted.
    wrong_ids: int = 0
    started_wall: float | None = None
    # What was missing from the team's neighbour discovery when the mission started after
    # DISCOVERY_WAIT without it (coordinator.monitor.discovery_gaps; empty: nothing).
    undiscovered_start: list[str] = field(default_factory=list)
    team_changes: list[TeamChange] = field(default_factory=list)
    # Who may be a team member (ids 0..N-1) and what came from any other id (issue 21);
    # None only for an Observed built outside a core.
    roster: Roster | None = None
    # S at every recorded instant (the rows of domain.csv): mission time, vertices (k, 2).
    domain_t: list[float] = field(default_factory=list)
    domain_polygons: list[np.ndarray] = field(default_factory=list)
    # The script's clock tau(t) and what the agents held (None only outside a core).
    pace: Pace | None = None
    # Mission time (s) at which the mission ended (done); None while it runs. The last e_a
    # sample is placed at its poses' time, a little before.
    ended: float | None = None

    def mission_time(self) -> float:
        """How long the mission ran, s of mission time: until it ended, else until the last
        e_a sample."""
        return self.ended if self.ended is not None else self.record.t[-1]


# -- actions (what the shell carries out) --------------------------------------------------


@dataclass(frozen=True)
class PublishDomain:
    """Put ``domain`` on the swarm's domain key."""

    domain: Domain


@dataclass(frozen=True)
class PublishWorld:
    """Put ``world`` (the arena, protocol.World) on the swarm's world key."""

    world: World


@dataclass(frozen=True)
class PublishStatus:
    """Put ``status`` on the swarm's status key."""

    status: Status


@dataclass(frozen=True)
class ReplySteer:
    """Answer the steering query just handed in with ``payload`` (a SteerReply), final."""

    payload: bytes
    accepted: bool


@dataclass(frozen=True)
class JournalSteering:
    """Append ``line`` to the steering journal (accepted requests, for --resume)."""

    line: str


@dataclass(frozen=True)
class MissionStarted:
    """The team is ready and the mission runs from now: record ``started_wall`` (for
    --resume) and forget a previous mission's steering journal."""

    swarm: str
    started_wall: float


@dataclass(frozen=True)
class RecordScriptClock:
    """Record where the script's clock stands (for --resume: the script continues from
    there, not from the mission time)."""

    swarm: str
    clock: ScriptClock


@dataclass(frozen=True)
class Finished:
    """The loop ends; ``started``: whether the mission ever ran (outputs to write)."""

    started: bool


Action = (
    PublishDomain
    | PublishWorld
    | PublishStatus
    | ReplySteer
    | JournalSteering
    | MissionStarted
    | RecordScriptClock
    | Finished
)


def run_inline(job: Callable[[], Any]) -> Future:
    """Run ``job`` now; its result (or exception) as a completed Future. The core's default
    ``offload``: tests and small teams sample e_a within the tick."""
    future: Future = Future()
    try:
        future.set_result(job())
    except Exception as exc:  # raised again by Future.result, in the tick that collects it
        future.set_exception(exc)
    return future


@dataclass(frozen=True)
class PendingSample:
    """An e_a sample handed to ``offload``: the poses and S it is computed from, and the
    Future of (e_a, the s it took)."""

    t: float  # mission time the poses were measured at, on average
    positions: dict[int, tuple[float, float]]
    polygon: np.ndarray
    tick: int  # the core's tick count when it started
    result: Future


def recording_counts() -> dict[str, float | int]:
    """What recording cost and what it could not record, counted (all zero at the start)."""
    return {
        "seconds": 0.0,  # CPU time spent recording (decoding every pose too)
        "skipped_ticks": 0,  # ticks not recorded because recording was too expensive
        "thinned_poses": 0,  # older poses of a robot left out after skipped ticks
        "backlog_overflow": 0,  # poses dropped because the backlog was full
        "stale_poses": 0,  # poses not newer than the robot's last recorded one
        "rejected_poses": 0,  # payloads that did not decode (ProtocolError)
        "wrong_id_poses": 0,  # poses whose id is not their key's (Observed.wrong_ids)
        "thinned_states": 0,  # older AgentStates of an agent left out after skipped ticks
        "state_backlog_overflow": 0,  # AgentStates dropped because their backlog was full
    }


class CoordinatorCore:
    """Mission clock, domain broadcasts, steering, e_a sampling and recording budgets."""

    def __init__(
        self,
        settings: CoordinatorSettings,
        *,
        recorder: RunRecorder | None = None,
        steer_checks: Sequence[MotionCheck] = (),
        cost_clock: Callable[[], float] = time.monotonic,
        cpu_clock: Callable[[], float] = time.thread_time,
        offload: Callable[[Callable[[], Any]], Future] = run_inline,
    ) -> None:
        """``recorder``: where what the coordinator sees goes (run.mcap, trajectories.csv,
        a live Foxglove view), or None; ``steer_checks``: vetoes on a steered motion of S
        (coordinator.steering.MotionCheck, e.g. against the world's obstacles);
        ``cost_clock`` times an e_a sample (elapsed: a slow sample on a loaded machine must
        slow sampling down too), ``cpu_clock`` a record (CPU: a busy machine that
        descheduled us is not recording's cost); ``offload`` runs the tessellations of an
        e_a sample and of the recorded cells (:func:`run_inline`, or a worker thread's
        submit: at 1000 robots they take ~65 and ~250 ms, more than a broadcast period,
        mostly in numpy, which releases the GIL, so the broadcasts keep their period). One
        of each is in flight at a time; its result is entered at the first tick after it
        completed."""
        self.settings = settings
        self.roster = Roster.of_size(settings.agents)
        # S(t) = S_script(tau(t)): the script slows down to what the team holds, and the
        # mission ends when tau reaches the duration (coordinator.pace); without pacing
        # tau = t and the phase ends the mission itself.
        self.pace = Pace(
            settings.agent_rate, enabled=settings.pace, deploying=settings.deploy_error is not None
        )
        self.observed = Observed(roster=self.roster, pace=self.pace)
        self.phase = MissionPhase(
            math.inf if settings.script_ends else settings.duration,
            settle=START_SETTLE,
            discovery_wait=DISCOVERY_WAIT,
        )
        # id -> the neighbours its last AgentState before the start names (discovery_gaps)
        self._listed: dict[int, frozenset[int]] = {}
        # The pairs whose cells meet (discovery_gaps), as of when (monotonic s)
        self._pairs = np.empty((0, 2), dtype=np.int64)
        self._pairs_at = -math.inf
        self._said_discovery_wait = False  # the log said the start waits for discovery
        # Each agent's round of the neighbour exchange while waiting: the start waits for
        # START_ROUNDS of the slowest (coordinator.monitor.start_settle), not only 1.5 s.
        self.exchange = ExchangeGaps()
        world = settings.scenario.world
        # S never touches the arena: every steered motion is swept against it first.
        checks = tuple(steer_checks)
        if world.workspace is not None or world.obstacles:
            checks = (world_check(world), *checks)
        self.steering = Steering(
            settings.scenario.domain,
            settings.steering_limits(),
            checks=checks,
            world=world,
            end=settings.duration,
        )
        self._next_world: float | None = None
        self.recorder = recorder
        self._cost_clock = cost_clock
        self._cpu_clock = cpu_clock
        self._offload = offload
        self._pending: PendingSample | None = None
        # Cells being tessellated for the recorder: (mission time, ids, Future of (cells,
        # CPU s)); offloaded like e_a (at 1000 robots ~250 ms, five broadcast periods).
        self._pending_cells: tuple[float, list[int], Future] | None = None
        self._ticks = 0  # ticks so far (an offloaded sample's budget counts from its start)
        self._next_waiting_report: float | None = None  # now of the next log of who is missing
        self._outsiders_told: set[int] = set()  # robots outside the team already warned of
        n = settings.agents
        self._seq = 0
        # (seq, stamp) of the Domains published lately: hearing one of them is hearing
        # ourselves; any other Domain on the key is someone else's.
        self._published: deque[tuple[int, float]] = deque(maxlen=OWN_DOMAINS_KEPT)
        self._ratelog = RateLog(log)
        self._pose_ids = KeyIds(settings.swarm, "pose")
        self._state_ids = KeyIds(settings.swarm, "state")
        # Newest undecoded pose payload per key: every robot's pose arrives at 20 Hz, but
        # only the ones present when e_a is sampled are ever read.
        self._pose_payloads: dict[str, bytes] = {}
        # Every (key, pose payload) received while the mission runs, until the recorder
        # takes them (bounded: a few seconds of the team's poses).
        self._pose_backlog: deque[tuple[str, bytes]] = deque(maxlen=64 * max(n, 16))
        # Likewise every (id, AgentState payload) of an admitted agent (half the poses' rate);
        # while waiting only each agent's newest, by id (what it believed when the mission
        # started), for the first record.
        self._state_backlog: deque[tuple[int, bytes]] | None = (
            deque(maxlen=64 * max(n, 16))
            if recorder is not None and settings.record_states
            else None
        )
        self._waiting_states: dict[int, bytes] = {}
        self._last_pose_time: dict[int, float] = {}  # mission time of each robot's last record
        self._last_record_t = 0.0
        self._next_stats_record = 0.0
        self.recording = recording_counts()
        # Budgets: ticks until the next e_a sample / record, ticks not recorded since the last.
        self._every = max(1, round(settings.rate / settings.sample_rate))
        self._ticks_to_sample = self._ticks_to_record = self._skipped = 0
        self._next_status: float | None = None
        self._done_since: float | None = None
        self._wall = 0.0  # the latest wall time handed in (stamps between ticks)
        self._now = 0.0  # the latest clock handed in (what arrives between ticks)
        self._team: frozenset[int] = frozenset()  # the team at the last tick

    # -- inputs ---------------------------------------------------------------------------

    def stamp(self, wall: float) -> float:
        """A message stamp at real wall time ``wall``: the run's scaled wall clock."""
        return wall * self.settings.time_scale

    def resume(
        self,
        started_wall: float,
        now: float,
        wall: float,
        journal: list[str],
        script: ScriptClock | None = None,
    ) -> None:
        """Continue the mission that started at ``started_wall`` (a restarted coordinator),
        with the accepted steering requests of ``journal`` (its lines) replayed, and the
        script's clock from where the first coordinator last recorded it (``script``; None:
        from the mission time, as if the script had never been slowed)."""
        # Mission time is wall time since the original start, so agents extrapolating the
        # last domain and the restarted broadcasts agree.
        self.phase.started_at = now - (self.stamp(wall) - started_wall * self.settings.time_scale)
        self.observed.started_wall = started_wall
        if script is not None:
            self.pace.resume(script)
        else:
            self.pace.deploying = False  # tau = t: as if the script had run from the start
        if journal:
            log.info("resumed %d steering requests", self.steering.replay(journal))

    def _mission_t(self, now: float) -> float | None:
        return self.phase.mission_time(now) if self.phase.state != WAITING else None

    def on_liveliness(self, key: str, alive: bool, now: float, wall: float) -> None:
        """A liveliness token ``key`` appeared (``alive``) or vanished."""
        obs = self.observed
        try:
            role, ident = parse_alive_key(key, self.settings.swarm)
        except ValueError:
            obs.rejected += 1
            return
        if not self.roster.admit_token(role, ident, alive):  # not of the team: counted
            self._enter_newcomers(now, wall)
            if role == "robot" and alive and ident not in self.roster.admitted:
                self._warn_outsider(ident)
            return
        # Tokens vanishing after "done" are processes shutting down, not failures.
        if self.phase.state == DONE and not alive:
            return
        t = self._mission_t(now)
        event = obs.liveness.update(role, ident, alive, wall, t)
        if event is not None and not alive:
            when = "before the start" if t is None else f"at t = {t:.1f} s"
            log.warning("%s %d lost its liveliness token %s", role, ident, when)

    def _warn_outsider(self, rid: int) -> None:
        """Once per id: a robot that holds its token outside the team (a bridge serving more
        robots than ``--agents``). No brain of the team moves it and the agents keep clear
        of it as of a robot left standing (covswarm.agent.brain.AgentBrain.stranded), which
        costs the coverage: say so where the operator looks, not only in summary.json."""
        if rid in self._outsiders_told or len(self._outsiders_told) >= REPORTED_IDS:
            return
        self._outsiders_told.add(rid)
        n = self.settings.agents
        log.warning(
            "robot %d holds a liveliness token outside the team (ids 0-%d): until an agent of "
            "its own joins (a newcomer), no brain moves it and the team's agents keep clear of "
            "it as of a standing robot; a bridge serving it needs --agents %d or more",
            rid, n - 1, rid + 1,
        )  # fmt: skip

    def _enter_newcomers(self, now: float, wall: float) -> None:
        """Enter the tokens of newcomers the roster just admitted in the liveness."""
        for role, ident in self.roster.take_admitted():
            self.observed.liveness.update(role, ident, True, wall, self._mission_t(now))
            log.warning("%s %d joined the team (a newcomer)", role, ident)

    def _note_team_change(self, now: float, wall: float) -> None:
        """One TeamChange for every liveliness change since the last tick that changed the
        running team (robot and agent both alive), however many tokens it took."""
        team = self.roster.members(self.observed.liveness.alive)
        if self.phase.state == RUNNING and team != self._team:
            t = self.phase.mission_time(now)
            lost, joined = tuple(sorted(self._team - team)), tuple(sorted(team - self._team))
            self.observed.team_changes.append(TeamChange(t, wall, lost, joined))
            log.warning("team changed at t = %.1f s: lost %s, joined %s", t, lost, joined)
        self._team = team

    def on_pose(self, key: str, payload: bytes) -> None:
        """A robot's pose payload on ``key`` (decoded only when sampled or recorded)."""
        self.on_poses([(key, payload)])

    def on_poses(self, received: list[tuple[str, bytes]]) -> None:
        """(key, pose payload) pairs in the order received: :meth:`on_pose` of each, in bulk
        (the link's batch of a tick, 1000 poses at 1000 robots: the dict and the backlog
        take them in one call each, not a Python step per pose)."""
        self._pose_payloads.update(received)
        if self.recorder is not None:  # (tick empties the backlog while waiting)
            backlog = self._pose_backlog
            assert backlog.maxlen is not None
            # Every pose appended to a full backlog pushes out its oldest.
            self.recording["backlog_overflow"] += max(
                0, len(received) - (backlog.maxlen - len(backlog))
            )
            backlog.extend(received)

    def on_domain_heard(self, payload: bytes) -> None:
        """A payload on the swarm's domain key: one of ours coming back, or a Domain some
        other process publishes (a second coordinator, a forger), which is counted in
        summary.json and logged (rate-limited): the agents may be following it."""
        try:
            domain = Domain.decode(payload)
        except ProtocolError:
            domain = None
        if domain is not None and (domain.seq, domain.stamp) in self._published:
            return
        self.observed.foreign_domains += 1
        self._ratelog.log(
            logging.ERROR,
            "foreign domain",
            "another process publishes on swarm %s's domain key (%d so far): a second "
            "coordinator or a forger; agents may follow it (secure mode prevents this)",
            self.settings.swarm,
            self.observed.foreign_domains,
        )

    def _wrong_id(self, kind: str, key: str, rid: int) -> None:
        """A message whose own id ``rid`` is not its key's: counted (``wrong_ids``) and
        logged (rate-limited), never taken."""
        self.observed.wrong_ids += 1
        self._ratelog.log(
            logging.ERROR,
            "wrong id",
            "a %s saying id %d on %s, another robot's key (%d so far): dropped; a forger with "
            "some robot's credentials, or a bridge that mislabels its robots",
            kind,
            rid,
            key,
            self.observed.wrong_ids,
        )

    def on_agent_state(self, key: str, payload: bytes) -> None:
        """An agent's AgentState payload on ``key``: its stats (about once a second) are
        kept, its neighbours vouch for newcomers (coordinator.team)."""
        try:
            rid, stamp, neighbors, stats = _read_state(payload)
        except ProtocolError:
            self.observed.rejected += 1
            return
        if rid != self._state_ids(key):
            self._wrong_id("AgentState", key, rid)
            return
        # Vouching never admits the sender itself: a state an unadmitted id sent is counted
        # and vouches for nobody either way.
        if not self.roster.admit_state(rid):
            return
        backlog = self._state_backlog
        if self.phase.state == WAITING:
            if backlog is not None:
                self._waiting_states[rid] = payload
            self.exchange.add(rid, stamp)
            self._listed[rid] = frozenset(neighbors)
        elif backlog is not None and self.phase.state != DONE:  # no record comes after done
            if len(backlog) == backlog.maxlen:
                self.recording["state_backlog_overflow"] += 1
            backlog.append((rid, payload))
        if self.roster.vouch(rid, neighbors):
            self._enter_newcomers(self._now, self._wall)
        if stats is not None:  # a map of its own (no message holds it)
            self.observed.agent_stats[rid] = stats
            if self.phase.state != DONE:  # the held rate is the mission's, not the hold's
                self.pace.report(rid, stats, stamp)

    def on_steer(
        self, payload: bytes, now: float, wall: float, requester: str | None = None
    ) -> list[Action]:
        """Answer one steering request; an accepted one takes over S from ``now``.

        ``requester``: who sent it (coordinator.steering.requester_key), rate-limited per
        requester; None: not rate-limited."""
        t = self.phase.mission_time(now)
        running = self.phase.state == RUNNING
        # Steering moves S in script time, as the script does: a steered S slows down with
        # an overloaded team too (its records and journal are in script time).
        tau = self.pace.script_time(t) if running else t
        reply = self.steering.handle(payload, tau, wall, running, requester)
        record = self.steering.records[-1]
        if self.recorder is not None:  # a goto's route too, for Foxglove and replays
            event = record.to_dict()
            if reply.route is not None:
                event["route"] = [list(stop) for stop in reply.route]
            self.recorder.steering(t, event)
        actions: list[Action] = []
        if reply.accepted:
            log.info("steering at t = %.2f s: %s", t, record.request)
            if running and self.pace.deploying:  # the operator takes over from the hold
                self._end_deploy_hold(t, "steered")
            actions.append(JournalSteering(self.steering.journal_line()))
        else:
            log.warning("steering request refused at t = %.2f s: %s", t, reply.reason)
        return [ReplySteer(reply.encode(), reply.accepted), *actions]

    def _report_waiting(self, now: float) -> None:
        """Every WAITING_REPORT s before the mission: the ids whose agent or robot has not
        appeared yet, and the swarm name a process started by hand must be given."""
        if self._next_waiting_report is None:
            self._next_waiting_report = now + WAITING_REPORT
            return
        if now < self._next_waiting_report:
            return
        self._next_waiting_report = now + WAITING_REPORT
        live, team = self.observed.liveness, range(self.settings.agents)
        missing = {
            role: [i for i in team if i not in live.alive.get(role, ())]
            for role in ("agent", "robot")
        }
        said = "; ".join(
            f"{role}s {format_ids(ids)} missing" for role, ids in missing.items() if ids
        )
        if said:
            log.info(
                "%s %s (a process started by hand joins with --swarm %s)",
                WAITING_FOR,
                said,
                self.settings.swarm,
            )

    def discovery_gaps(self, now: float) -> list[str]:
        """What the AgentStates heard before the start say is missing from the team's
        neighbour discovery (coordinator.monitor.discovery_gaps): the pairs whose cells meet
        in S(0), tessellated from the team's latest poses (robots whose agent and robot both
        hold their tokens; stranded robots as still generators, as the agents take them) at
        most DISCOVERY_PERIOD s ago."""
        if now - self._pairs_at >= DISCOVERY_PERIOD:
            self._pairs_at, self._pairs = now, self._meeting_pairs()
        team = self.roster.members(self.observed.liveness.alive)
        return discovery_gaps(self._listed, team, self._pairs)

    def _meeting_pairs(self) -> np.ndarray:
        """(m, 2) ids of the team members within DISCOVERY_REACH of each other whose cells in
        S(0) share an edge of at least DISCOVERY_EDGE, from their latest poses
        (covswarm.tvd.coverage.neighbour_pairs)."""
        positions = self.alive_positions()
        obs = self.observed
        if len(positions) < 2:
            return np.empty((0, 2), dtype=np.int64)
        stranded = [i for i in self.roster.stranded(obs.liveness.alive) if i in obs.poses]
        ids = [*positions, *stranded]
        points = np.array([*positions.values(), *(obs.poses[i] for i in stranded)], dtype=float)
        still = np.arange(len(ids)) >= len(positions)  # none still: still_mask's None
        polygon = self.steering.domain(0.0)[0]
        pairs = neighbour_pairs(points, polygon, DISCOVERY_EDGE, still, DISCOVERY_REACH)
        return np.asarray(ids, dtype=np.int64)[pairs].reshape(-1, 2)

    def team_ready(self) -> bool:
        live = self.observed.liveness
        n = self.settings.agents
        return live.count("agent") >= n and live.count("robot") >= n

    def alive_positions(self) -> dict[int, tuple[float, float]]:
        """Latest pose of every team member (robot and agent both hold their token)."""
        obs = self.observed
        for key, payload in self._pose_payloads.items():
            try:
                pose = Pose.decode(payload)
            except ProtocolError:
                obs.rejected += 1
                continue
            if pose.id != self._pose_ids(key):
                self._wrong_id("pose", key, pose.id)
                continue
            if not self.roster.admit_pose(pose.id):
                continue
            if pose.id in obs.poses and pose.stamp > obs.pose_stamps[pose.id]:
                obs.earlier_poses[pose.id] = (obs.pose_stamps[pose.id], *obs.poses[pose.id])
            obs.poses[pose.id] = (pose.x, pose.y)
            obs.pose_stamps[pose.id] = pose.stamp
        self._pose_payloads.clear()
        team = self.roster.members(obs.liveness.alive)
        return {i: xy for i, xy in obs.poses.items() if i in team}

    # -- the clock ------------------------------------------------------------------------

    def tick(self, now: float, wall: float, stopping: bool = False) -> list[Action]:
        """One broadcast period at ``now``: advance the mission, sample, record, broadcast.

        ``stopping``: the operator interrupted; the mission ends now (done if running).
        """
        settings, phase = self.settings, self.phase
        self._wall, self._now = wall, now
        self._note_team_change(now, wall)
        if stopping:
            phase.stop(now)
        before = phase.state
        if before == WAITING:
            phase.settle = start_settle(self.exchange.slowest())
        # The poses' cells only once the settle is over: the start waits for nothing else.
        settled = phase.ready_since is not None and now - phase.ready_since >= phase.settle
        gaps = self.discovery_gaps(now) if before == WAITING and settled else []
        state = phase.update(now, self.team_ready(), not gaps)
        if state == WAITING and stopping:
            log.info("stopped before the mission started")
            return [Finished(started=False)]
        if state == WAITING:
            self._report_waiting(now)
            if gaps and not self._said_discovery_wait:
                self._said_discovery_wait = True
                log.info(
                    "the team is up; the start waits (at most %.0f s) for neighbours to name "
                    "each other: %s%s",
                    phase.discovery_wait,
                    "; ".join(gaps[:3]),
                    f" and {len(gaps) - 3} more" if len(gaps) > 3 else "",
                )
        actions: list[Action] = []
        if before == WAITING and state == RUNNING:
            self.observed.started_wall = wall
            log.info(
                "team ready: mission started, %.2f s after the whole team was up (the slowest "
                "agent's exchange round %.2f s: coordinator.monitor.start_settle)",
                now - (phase.ready_since if phase.ready_since is not None else now),
                self.exchange.slowest(),
            )
            if phase.started_undiscovered:
                log.warning(
                    "mission started %.1f s after the team was up with its neighbour discovery "
                    "incomplete (coordinator.monitor.DISCOVERY_WAIT): %s%s; a robot that does "
                    "not know the one next to it may drive into it",
                    phase.settle + phase.discovery_wait,
                    "; ".join(gaps[:5]),
                    f" and {len(gaps) - 5} more" if len(gaps) > 5 else "",
                )
                self.observed.undiscovered_start = gaps
            actions.append(MissionStarted(settings.swarm, wall))
        t = phase.mission_time(now)
        if state == RUNNING and self.pace.deploying:
            self._end_deploy_hold(t)
        if state != WAITING:
            slowed = self.pace.slowed
            tau = self.pace.advance(t, self._team, end=settings.duration)
            if slowed != self.pace.slowed:
                self._log_pace(t)
            if state == RUNNING and settings.script_ends and tau >= settings.duration:
                phase.stop(now)  # the script's end: done from this tick
                state = DONE
        polygon, domain = self._domain(state, t)
        actions.append(PublishDomain(domain))
        if self._next_world is None or now >= self._next_world:
            actions.append(PublishWorld(self.world_message()))
            self._next_world = now + WORLD_PERIOD
        self._ticks += 1
        self._ticks_to_sample -= 1
        self._collect_sample(wait=False)
        self._collect_cells(wait=False)
        if state == RUNNING and self._ticks_to_sample <= 0 and self._pending is None:
            self._pending = self._start_sample(t, self._offload)
            self._ticks_to_sample = self._every
            self._collect_sample(wait=False)  # done already unless offloaded
        done_now = state == DONE and self._done_since is None
        if done_now:
            self._done_since = now
            self.observed.ended = t
            self._collect_sample(wait=True)
            # The final error, at the end of the mission, before the outputs are written.
            self._pending = self._start_sample(t, run_inline)
            self._collect_sample(wait=True)
            log.info("mission done at t = %.1f s", t)
        if self.recorder is not None and (state == RUNNING or done_now):
            self._ticks_to_record -= 1
            if self._ticks_to_record <= 0 or done_now:
                cost = self._record(t, polygon, thin=self._skipped > 0)
                self._skipped = 0
                # Past RECORD_SHARE of a core, record every k-th tick (newest poses).
                self._ticks_to_record = math.ceil(
                    cost / RECORD_SHARE * settings.rate * settings.time_scale
                )
            else:
                self.recording["skipped_ticks"] += 1
                self._skipped += 1
        if state == WAITING:  # the first record holds the poses of one tick only
            self._pose_backlog.clear()
        finished = self._done_since is not None and now - self._done_since >= DONE_HOLD
        if finished:  # the recorder closes after the last tick
            self._collect_cells(wait=True)
        if self._next_status is None or now >= self._next_status or finished:
            actions.append(PublishStatus(self._status(state, t)))
            self._next_status = now + STATUS_PERIOD
            clock = self.pace.clock()
            if state == RUNNING and clock is not None:
                actions.append(RecordScriptClock(settings.swarm, clock))
        if finished:
            actions.append(Finished(started=True))
        return actions

    def _end_deploy_hold(self, t: float, reason: str | None = None) -> None:
        """Release the script at mission time ``t``: at once when ``reason`` says so (an
        operator steered), else DEPLOY_ALIGN s after the team has spread over S(0) or the
        hold timed out (coordinator.pace.deploy_release on the latest e_a sample), S held
        still meanwhile for the robots to face its start (Pace.align)."""
        settings, record, pace = self.settings, self.observed.record, self.pace
        latest = (record.t[-1], record.error[-1]) if record.t else None
        error = None if latest is None else latest[1]
        if reason is None and settings.deploy_error is not None:
            if pace.aligned_from is None:
                reason = deploy_release(t, latest, settings.deploy_error, settings.deploy_timeout)
                if reason is None:
                    return
                pace.align(t, reason, error)
                said = "no sample" if latest is None else f"e_a {latest[1]:.4f} m"
                (log.warning if reason == "timed out" else log.info)(
                    "t = %.1f s: the deploy hold ends (%s, %s): the robots face S's start "
                    "for %g s, then S starts moving", t, reason, said, DEPLOY_ALIGN
                )  # fmt: skip
            since, reason, error = pace.aligned_from
            if not aligned_by(t, since):
                return
        if reason is None:
            return
        pace.release(t, reason, error)

    def _log_pace(self, t: float) -> None:
        """Say that the script starts or stops running slower than the clock (an
        overloaded team, coordinator.pace)."""
        pace = self.pace
        if pace.pace < 1.0:
            log.warning(
                "t = %.1f s: the agents do not hold their %g Hz; the mission's script slows "
                "down to %.2fx (script at %.1f s)",
                t, pace.asked, pace.pace, pace.tau,
            )  # fmt: skip
        else:
            log.info("t = %.1f s: the agents hold their rate again; the script at full speed", t)

    # -- outputs --------------------------------------------------------------------------

    def _domain(self, state: str, t: float) -> tuple[np.ndarray, Domain]:
        """S(t)'s vertices and the Domain message that broadcasts it (next sequence number):
        S_script(tau) with the exact velocities dS/dt = S_script'(tau) * pace."""
        tau, pace = (self.pace.tau, self.pace.pace) if state != WAITING else (0.0, 1.0)
        vertices, velocities = self.steering.domain(tau)
        density = self.settings.scenario.density(tau)
        velocities, start = broadcast_motion(state, velocities, pace, self.pace.aligning)
        if density is not None:
            density = paced_density(density, pace, t) if state == RUNNING else density.frozen()
        domain = Domain(
            seq=self._seq,
            stamp=self.stamp(self._wall),
            t=t,
            state=state,
            vertices=vertices,
            velocities=velocities,
            kappa=self._kappa(state, t),
            density=None if density is None else density.to_dict(),
            tile_size=self.settings.tile_size,
            start_velocities=start,
        )
        self._seq += 1
        self._published.append((domain.seq, domain.stamp))
        return vertices, domain

    def _kappa(self, state: str, t: float) -> float:
        """The gain to broadcast at mission time ``t``: the deploy hold's while S holds still
        at S(0) for the team to spread over it (settings.deploy_kappa, when given, ramped
        up to from the mission's: coordinator.pace.hold_gain), else the mission's."""
        settings = self.settings
        if state == RUNNING and self.pace.deploying:
            return hold_gain(t, settings.kappa, settings.hold_kappa)
        return settings.kappa

    @cached_property
    def map_payload(self) -> bytes | None:
        """The answer to a query for the map's picture (protocol.world_map_key): an encoded
        protocol.MapImage of the scenario's occupancy map (world.map_image, built on the
        first query), None when the scenario has no map or its picture cannot be sent."""
        grid = self.settings.scenario.map
        if grid is None:
            return None
        try:
            return map_image(grid, seq=0).encode()  # seq of world_message's World
        except ValueError as exc:
            log.warning("the map's picture cannot be sent: %s", exc)
            return None

    def world_message(self) -> World:
        """The arena as broadcast (seq 0: the world never changes during a run)."""
        return to_message(self.settings.scenario.world, 0, self.stamp(self._wall))

    def _status(self, state: str, t: float) -> Status:
        live, record = self.observed.liveness, self.observed.record
        return Status(
            stamp=self.stamp(self._wall),
            t=t,
            state=state,
            error=record.error[-1] if record.error else None,
            alive_agents=live.count("agent"),
            alive_robots=live.count("robot"),
            route=self.steering.active_route(self.pace.tau) if state == RUNNING else None,
            pace=self.pace.pace if state == RUNNING else None,
            script_t=self.pace.tau if state != WAITING else None,
        )

    def _start_sample(
        self, t: float, offload: Callable[[Callable[[], Any]], Future]
    ) -> PendingSample | None:
        """One e_a sample, against S at the time the team's poses were measured: the poses
        are read now, the tessellation runs through ``offload``. None without poses."""
        positions = self.alive_positions()
        if not positions:
            return None
        ids = sorted(positions)
        record = self.observed.record
        points = np.array([positions[i] for i in ids])
        # The final sample too, taken in the tick the mission ends with the robots still
        # moving with S: against S(now), poses ~50 ms old and taken at different times read
        # as robots behind S (the 1000-robot run's last e_a was 0.054 m, the samples before
        # it 0.026 m).
        obs, wall_now = self.observed, self.stamp(self._wall)
        stamps = np.array([obs.pose_stamps[i] for i in ids])
        when = mean_pose_time(t, wall_now, stamps)
        measured = clip_sample_time(when, t, record.t[-1] if record.t else 0.0)
        # Poses too old, out of order or badly stamped: the sample is placed at a bound.
        obs.clipped_samples += measured != when
        script = self.pace.script_time(measured)
        polygon = self.steering.domain(script)[0]
        earlier = np.array([obs.earlier_poses.get(i, (np.nan,) * 3) for i in ids])
        points = positions_at(
            wall_now - (t - measured), stamps, points, earlier[:, 0], earlier[:, 1:]
        )
        positions = {i: (float(x), float(y)) for i, (x, y) in zip(ids, points, strict=True)}
        density = self.settings.scenario.density(script)
        clock = self._cost_clock
        # Robots whose brains died stand where they stopped: still generators, as the
        # agents take them (covswarm.tvd.control's ``still``), out of e_a themselves.
        still = [obs.poses[i] for i in self.roster.stranded(obs.liveness.alive) if i in obs.poses]
        generators, standing = points, None
        if still:
            generators = np.vstack([points, still])
            standing = np.arange(len(generators)) >= len(points)

        def job() -> tuple[float, float]:
            began = clock()
            return aggregate_error(generators, polygon, density, standing), clock() - began

        return PendingSample(measured, positions, polygon, self._ticks, offload(job))

    def _collect_cells(self, wait: bool) -> None:
        """Record the pending cells once tessellated (``wait``: block until they are)."""
        if self._pending_cells is None or not (wait or self._pending_cells[2].done()):
            return
        t, team, result = self._pending_cells
        self._pending_cells = None
        pieces, cost = result.result()
        if self.recorder is not None:
            self.recorder.log_cells(t, team, pieces, cost)

    def _collect_sample(self, wait: bool) -> None:
        """Enter the pending e_a sample in the record once computed (``wait``: block until
        it is); sample less often while e_a is expensive (big team, overloaded machine),
        so that it takes at most SAMPLE_SHARE of a core; back to normal once cheap."""
        pending = self._pending
        if pending is None or not (wait or pending.result.done()):
            return
        self._pending = None
        error, cost = pending.result.result()
        self.observed.record.add(pending.t, error, pending.positions, pending.polygon)
        if self.recorder is not None:
            self.recorder.error(pending.t, error, len(pending.positions))
        settings = self.settings
        budget = math.ceil(cost / SAMPLE_SHARE * settings.rate * settings.time_scale)
        self._ticks_to_sample = max(self._ticks_to_sample, budget - (self._ticks - pending.tick))

    def _record(self, t: float, polygon: np.ndarray, thin: bool) -> float:
        """Every pose received since the last record, each at the mission time it was
        measured (covswarm.records.observations), S(t), every AgentState received, and at
        lower rates the cells and the agents' stats (covswarm.records.recorder). ``thin``:
        ticks were skipped, record only each robot's newest pose and each agent's newest
        state, so that skipping bounds the work. Returns the CPU time the poses, S and the
        states took, s (the cells have their own budget)."""
        recorder, counts = self.recorder, self.recording
        assert recorder is not None
        began = self._cpu_clock()
        received: list[tuple[str, bytes]] = list(self._pose_backlog)
        if thin:
            received = list(dict(self._pose_backlog).items())  # the newest per key
            counts["thinned_poses"] += len(self._pose_backlog) - len(received)
        self._pose_backlog.clear()
        observations = []
        for key, payload in received:
            try:
                pose = Pose.decode(payload)
            except ProtocolError:
                counts["rejected_poses"] += 1
                continue
            if pose.id != self._pose_ids(key):
                counts["wrong_id_poses"] += 1  # counted once more when sampled for e_a
                continue
            observations.append((pose.id, pose.seq, pose.stamp, pose.x, pose.y, pose.theta))
        layers, stale = timed_layers(
            self.roster.admit_observations(np.array(observations, dtype=float).reshape(-1, 6)),
            t,
            self._last_record_t,
            self.stamp(self._wall),
            self._last_pose_time,
        )
        counts["stale_poses"] += stale
        for layer in layers:  # one /robots message per layer, no robot twice in one
            recorder.poses(t, layer.ids, layer.poses, layer.times, trajectories=False)
            self._last_pose_time.update(zip(layer.ids, layer.times.tolist(), strict=True))
        if layers:  # trajectories.csv in time order
            times = np.concatenate([layer.times for layer in layers])
            ids = np.concatenate([layer.ids for layer in layers])
            order = np.lexsort((ids, times))
            poses = np.concatenate([layer.poses for layer in layers])[order]
            recorder.trajectory_rows(times[order], ids[order].tolist(), poses)
        self._last_record_t = t
        recorder.domain(t, polygon)
        self.observed.domain_t.append(t)
        self.observed.domain_polygons.append(np.asarray(polygon, dtype=float))
        states = self._state_backlog
        if states is not None and (states or self._waiting_states):
            waited = list(self._waiting_states.items())  # the first record's, taken once
            self._waiting_states.clear()
            if thin:
                newest = dict(waited + list(states))
                counts["thinned_states"] += len(states) + len(waited) - len(newest)
                recorder.agent_states(t, list(newest.values()))
            else:
                recorder.agent_states(t, [payload for _, payload in waited + list(states)])
            states.clear()
        cost = self._cpu_clock() - began
        if self._pending_cells is None and recorder.cells_due(t):
            if positions := self.alive_positions():
                team = sorted(positions)
                points, cpu = np.array([positions[i] for i in team]), self._cpu_clock

                def job() -> tuple[list[np.ndarray], float]:
                    began = cpu()  # the CPU of the thread that runs it
                    return cells(points, polygon), cpu() - began

                self._pending_cells = (t, team, self._offload(job))
                self._collect_cells(wait=False)  # done already unless offloaded
        if t >= self._next_stats_record and self.observed.agent_stats:
            recorder.agent_stats(t, self.observed.agent_stats)
            self._next_stats_record = t + STATS_RECORD_PERIOD
        counts["seconds"] += self._cpu_clock() - began
        return cost

    def recording_note(self) -> dict[str, Any]:
        """What recording cost, for the recorder's "recording" note."""
        return {**self.recording, "record_share": RECORD_SHARE}
