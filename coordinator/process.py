"""``covswarm coordinator``: broadcasts the moving domain S(t) and monitors the team.

The coordinator is the mission clock. It broadcasts Domain messages at a fixed rate
(vertices, vertex velocities, wall-clock stamp, mission time) so agents can extrapolate
between messages; it holds the domain at t = 0 ("waiting") until every agent and robot holds
a liveliness token, runs the scenario for its duration, says "done" for a moment and exits.

It is the one process that subscribes to every pose: it samples the aggregate error e_a(t)
over the robots alive, publishes Status, reports processes whose liveliness token
disappears and at the end writes the same outputs as ``covswarm sim`` (mission.report).
The bookkeeping is in coordinator.monitor; this module is the network shell around it.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
import numpy as np

from covswarm.coordinator.monitor import (
    DONE,
    RUNNING,
    WAITING,
    ErrorRecord,
    Liveness,
    MissionClock,
    TeamChange,
    agent_figures,
    agent_guards,
    clip_sample_time,
    losses_summary,
    mean_pose_time,
    team_changes_summary,
    team_of,
)
from covswarm.coordinator.steering import Limits, Steering, default_max_domain_speed
from covswarm.mission.crowding import Crowding
from covswarm.mission.crowding import crowding as estimate_crowding
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import SCENARIO_HELP, Scenario
from covswarm.protocol.security import SECURE_OPTION
from covswarm.records.live import FOXGLOVE_OPTION
from covswarm.runtime.clock import StopFlag, Ticker, scaled
from covswarm.runtime.options import TIME_SCALE_OPTION

if TYPE_CHECKING:
    from covswarm.records.recorder import RunRecorder

log = logging.getLogger("covswarm.coordinator")

DONE_HOLD = 1.0  # s of "done" broadcasts, so every agent sees it and stops its robot
# s the whole team holds its tokens before the mission starts: every agent has then had its
# early beacons (within a second of the last token) and knows the robots next to it, which
# its safety filter needs before its robot moves (coordinator.monitor.MissionClock.settle).
START_SETTLE = 1.5
STATUS_PERIOD = 0.5  # s
STATS_RECORD_PERIOD = 1.0  # s of mission time between two records of the agents' stats
MISSION_FILE = "mission.json"  # in --out: the start wall time, for --resume
STEERING_JOURNAL = "steering.jsonl"  # in --out: accepted steering requests, for --resume
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


def steering_limits(settings: Settings) -> Limits:
    """What a steering request may ask of this run's team (coordinator.steering.Limits)."""
    from covswarm.tvd.drive import KHEPERA_IV

    speed = settings.max_domain_speed
    if speed is None:
        speed = default_max_domain_speed(KHEPERA_IV.max_wheel_speed, settings.kappa)
    return Limits.for_team(
        settings.agents, speed, settings.scenario.workspace, settings.scenario.robot_diameter
    )


@dataclass(frozen=True)
class Settings:
    """What one coordinator run does (CLI options, scenario defaults filled in)."""

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

    @cached_property
    def crowding(self) -> Crowding:
        """Whether the team fits S over the mission: estimated once, for the warning at the
        start and for summary.json."""
        return estimate_crowding(self.scenario, self.agents, self.duration)


@dataclass
class Observed:
    """Everything the coordinator learnt from the network during the run."""

    record: ErrorRecord = field(default_factory=ErrorRecord)
    liveness: Liveness = field(default_factory=Liveness)
    poses: dict[int, tuple[float, float]] = field(default_factory=dict)
    pose_stamps: dict[int, float] = field(default_factory=dict)  # s, the run's wall clock
    agent_stats: dict[int, dict[str, float]] = field(default_factory=dict)
    rejected: int = 0  # messages dropped as malformed (ProtocolError)
    clipped_samples: int = 0  # e_a samples not placed at their poses' time (clip_sample_time)
    started_wall: float | None = None
    team_changes: list[TeamChange] = field(default_factory=list)


class Coordinator:
    """The coordinator's subscriptions, publishers and loop on one open zenoh session."""

    def __init__(
        self,
        session: Any,
        settings: Settings,
        *,
        mission_file: Path | None = None,
        resume_wall: float | None = None,
        recorder: RunRecorder | None = None,
    ) -> None:
        """``mission_file``: where to record the mission's start wall time once it starts;
        ``resume_wall``: a start wall time read back from it, to continue that mission (a
        restarted coordinator) instead of waiting for the team; ``recorder``: where what the
        coordinator sees goes (run.mcap, trajectories.csv, a live Foxglove view)."""
        import zenoh

        from covswarm.protocol import (
            alive_key,
            alive_selector,
            all_agent_states_selector,
            all_poses_selector,
            domain_key,
            status_key,
            steer_key,
        )

        self.settings = settings
        self.observed = Observed()
        self.clock = MissionClock(settings.duration, settle=START_SETTLE)
        # Mission-time clocks: the clock ticks and the stamps agents extrapolate from.
        self._mono = scaled(time.monotonic, settings.time_scale)
        self._wall = scaled(time.time, settings.time_scale)
        self.mission_file = mission_file
        if resume_wall is not None:
            # Mission time is wall time since the original start, so agents extrapolating
            # the last domain and the restarted broadcasts agree.
            self.clock.started_at = self._mono() - (
                self._wall() - resume_wall * settings.time_scale
            )
            self.observed.started_wall = resume_wall
        swarm, n = settings.swarm, settings.agents
        self._delete = zenoh.SampleKind.DELETE
        # Liveliness changes must never be dropped (FIFO); poses and agent states are
        # "latest wins" and drained every tick, so a ring that overwrites is right.
        ring = max(1024, 8 * n)
        self._token = session.liveliness().declare_token(alive_key(swarm, "coordinator", 0))
        self._alive = session.liveliness().declare_subscriber(
            alive_selector(swarm), zenoh.handlers.FifoChannel(max(1024, 4 * n)), history=True
        )
        self._poses = session.declare_subscriber(
            all_poses_selector(swarm), zenoh.handlers.RingChannel(ring)
        )
        self._states = session.declare_subscriber(
            all_agent_states_selector(swarm), zenoh.handlers.RingChannel(ring)
        )
        self._domain = session.declare_publisher(domain_key(swarm))
        # Steering requests (coordinator.steering): a queryable drained every tick, so a
        # request is answered and acted on within one broadcast period.
        self._steer = session.declare_queryable(steer_key(swarm), zenoh.handlers.FifoChannel(64))
        self.steering = Steering(settings.scenario.domain, steering_limits(settings))
        self._journal = None if mission_file is None else mission_file.with_name(STEERING_JOURNAL)
        if resume_wall is not None and self._journal is not None and self._journal.exists():
            lines = self._journal.read_text(encoding="utf-8").splitlines()
            log.info("resumed %d steering requests", self.steering.replay(lines))
        self._status = session.declare_publisher(status_key(swarm))
        self._seq = 0
        # Newest undecoded pose payload per key: every robot's pose arrives at 20 Hz, but
        # only the ones present when e_a is sampled are ever read.
        self._pose_payloads: dict[str, bytes] = {}
        self.recorder = recorder
        # Every (key, pose payload) received while the mission runs, until the recorder
        # takes them (bounded: a few seconds of the team's poses).
        self._pose_backlog: deque[tuple[str, bytes]] = deque(maxlen=64 * max(n, 16))
        self._last_pose_time: dict[int, float] = {}  # mission time of each robot's last record
        self._last_record_t = 0.0
        self._next_stats_record = 0.0
        self.recording = {  # what recording cost and what it could not record, counted
            "seconds": 0.0,  # CPU time spent in _record (decoding every pose too)
            "skipped_ticks": 0,  # ticks not recorded because recording was too expensive
            "thinned_poses": 0,  # older poses of a robot left out after skipped ticks
            "backlog_overflow": 0,  # poses dropped because the backlog was full
            "stale_poses": 0,  # poses not newer than the robot's last recorded one
            "rejected_poses": 0,  # payloads that did not decode (ProtocolError)
        }

    # -- inputs ---------------------------------------------------------------------------

    def _drain(self, now: float) -> None:
        from covswarm.protocol import AgentState, ProtocolError, parse_alive_key

        obs, swarm = self.observed, self.settings.swarm
        t = self.clock.mission_time(now) if self.clock.state != WAITING else None
        team = team_of(obs.liveness.alive)
        while (sample := self._alive.try_recv()) is not None:
            try:
                role, ident = parse_alive_key(str(sample.key_expr), swarm)
            except ValueError:
                obs.rejected += 1
                continue
            alive = sample.kind != self._delete
            # Tokens vanishing after "done" are processes shutting down, not failures.
            if self.clock.state == DONE and not alive:
                continue
            event = obs.liveness.update(role, ident, alive, time.time(), t)
            if event is not None and not alive:
                when = "before the start" if t is None else f"at t = {t:.1f} s"
                log.warning("%s %d lost its liveliness token %s", role, ident, when)
        if self.clock.state == RUNNING and (now_team := team_of(obs.liveness.alive)) != team:
            change = TeamChange(
                t, time.time(), tuple(sorted(team - now_team)), tuple(sorted(now_team - team))
            )
            obs.team_changes.append(change)
            log.warning(
                "team changed at t = %.1f s: lost %s, joined %s", t, change.lost, change.joined
            )
        if self.clock.state == WAITING:  # the first record holds the poses of one tick
            self._pose_backlog.clear()
        while (sample := self._poses.try_recv()) is not None:
            key, payload = str(sample.key_expr), sample.payload.to_bytes()
            self._pose_payloads[key] = payload
            if self.recorder is not None:
                if len(self._pose_backlog) == self._pose_backlog.maxlen:
                    self.recording["backlog_overflow"] += 1
                self._pose_backlog.append((key, payload))
        while (sample := self._states.try_recv()) is not None:
            try:
                state = AgentState.decode(sample.payload.to_bytes())
            except ProtocolError:
                obs.rejected += 1
                continue
            if state.stats is not None:  # agents attach them about once a second
                obs.agent_stats[state.id] = dict(state.stats)

    def _decode_poses(self) -> None:
        """Decode the newest pose of every robot heard from since the last call."""
        from covswarm.protocol import Pose, ProtocolError

        obs = self.observed
        for payload in self._pose_payloads.values():
            try:
                pose = Pose.decode(payload)
            except ProtocolError:
                obs.rejected += 1
                continue
            obs.poses[pose.id] = (pose.x, pose.y)
            obs.pose_stamps[pose.id] = pose.stamp
        self._pose_payloads.clear()

    def team_ready(self) -> bool:
        live = self.observed.liveness
        n = self.settings.agents
        return live.count("agent") >= n and live.count("robot") >= n

    def alive_positions(self) -> dict[int, tuple[float, float]]:
        """Latest pose of every team member (robot and agent both hold their token)."""
        self._decode_poses()
        team = team_of(self.observed.liveness.alive)
        return {i: xy for i, xy in self.observed.poses.items() if i in team}

    def _serve_steering(self, now: float) -> None:
        """Answer every pending steering request; accepted ones take over S from ``now``."""
        running = self.clock.state == RUNNING
        t = self.clock.mission_time(now)
        while (query := self._steer.try_recv()) is not None:
            payload = b"" if query.payload is None else query.payload.to_bytes()
            reply = self.steering.handle(payload, t, time.time(), running)
            self.record_steering(t, self.steering.records[-1].to_dict())
            if reply.accepted:
                log.info("steering at t = %.2f s: %s", t, self.steering.records[-1].request)
                if self._journal is not None:
                    with self._journal.open("a", encoding="utf-8") as journal:
                        journal.write(self.steering.journal_line() + "\n")
            else:
                log.warning("steering request refused at t = %.2f s: %s", t, reply.reason)
            query.reply(query.key_expr, reply.encode())
            query.drop()  # the final answer: the client stops waiting

    # -- outputs --------------------------------------------------------------------------

    def _publish_domain(self, state: str, t: float) -> np.ndarray:
        from covswarm.protocol import Domain

        vertices, velocities = self.steering.domain(t)
        density = self.settings.scenario.density(t)
        if state != RUNNING:
            velocities = np.zeros_like(velocities)  # held still while waiting / done
            density = None if density is None else density.frozen()
        self._domain.put(
            Domain(
                seq=self._seq,
                stamp=self._wall(),
                t=t,
                state=state,
                vertices=vertices,
                velocities=velocities,
                kappa=self.settings.kappa,
                density=None if density is None else density.to_dict(),
                tile_size=self.settings.tile_size,
            ).encode()
        )
        self._seq += 1
        return vertices

    def _sample(self, t: float, polygon: np.ndarray) -> None:
        """One e_a sample, against S at the time the team's poses were measured."""
        from covswarm.tvd.coverage import aggregate_error

        positions = self.alive_positions()
        if not positions:
            return
        ids = sorted(positions)
        record = self.observed.record
        measured = t
        if self.clock.state == RUNNING:  # once done, S holds still at S(duration)
            stamps = [self.observed.pose_stamps[i] for i in ids]
            when = mean_pose_time(t, self._wall(), stamps)
            measured = clip_sample_time(when, t, record.t[-1] if record.t else 0.0)
            # Poses too old, out of order or badly stamped: the sample is placed at a bound.
            self.observed.clipped_samples += measured != when
            polygon = self.steering.domain(measured)[0]
        error = aggregate_error(
            np.array([positions[i] for i in ids]), polygon, self.settings.scenario.density(measured)
        )
        record.add(measured, error, positions, polygon)
        if self.recorder is not None:
            self.recorder.error(measured, error, len(ids))

    # -- recording ------------------------------------------------------------------------

    def record_steering(self, t: float, event: dict[str, Any]) -> None:
        """A steering event (JSON-able) at mission time ``t`` on the recorder's /steering."""
        if self.recorder is not None:
            self.recorder.steering(t, event)

    def _record(self, t: float, polygon: np.ndarray, thin: bool) -> float:
        """Every pose received since the last record, each at the mission time it was
        measured (covswarm.records.observations), S(t), and at lower rates the cells and the
        agents' stats (covswarm.records.recorder). ``thin``: ticks were skipped, record only
        each robot's newest pose, so that skipping bounds the work. Returns the CPU time
        the poses and S took, s (the cells have their own budget): a busy machine that
        descheduled us is not recording's cost."""
        from covswarm.protocol import Pose, ProtocolError
        from covswarm.records.observations import timed_layers

        recorder, counts = self.recorder, self.recording
        began = time.thread_time()
        payloads = [payload for _, payload in self._pose_backlog]
        if thin:
            payloads = list(dict(self._pose_backlog).values())  # the newest per key
            counts["thinned_poses"] += len(self._pose_backlog) - len(payloads)
        self._pose_backlog.clear()
        observations = []
        for payload in payloads:
            try:
                pose = Pose.decode(payload)
            except ProtocolError:
                counts["rejected_poses"] += 1
                continue
            observations.append((pose.id, pose.seq, pose.stamp, pose.x, pose.y, pose.theta))
        layers, stale = timed_layers(
            np.array(observations, dtype=float).reshape(-1, 6),
            t,
            self._last_record_t,
            self._wall(),
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
        cost = time.thread_time() - began
        if recorder.cells_due(t) and (positions := self.alive_positions()):
            team = sorted(positions)
            recorder.cells(t, team, np.array([positions[i] for i in team]), polygon)
        if t >= self._next_stats_record and self.observed.agent_stats:
            recorder.agent_stats(t, self.observed.agent_stats)
            self._next_stats_record = t + STATS_RECORD_PERIOD
        counts["seconds"] += time.thread_time() - began
        return cost

    def _publish_status(self, state: str, t: float) -> None:
        from covswarm.protocol import Status

        live, record = self.observed.liveness, self.observed.record
        self._status.put(
            Status(
                stamp=self._wall(),
                t=t,
                state=state,
                error=record.error[-1] if record.error else None,
                alive_agents=live.count("agent"),
                alive_robots=live.count("robot"),
            ).encode()
        )

    # -- loop -----------------------------------------------------------------------------

    def run(self, stop: StopFlag) -> None:
        """Broadcast until the mission is done (or ``stop`` is set), sampling on the way."""
        ticker = Ticker(self.settings.rate, time_scale=self.settings.time_scale)
        next_status = ticker.now()
        every = max(1, round(self.settings.rate / self.settings.sample_rate))
        ticks_to_sample = ticks_to_record = skipped = 0
        done_since: float | None = None
        log.info("waiting for %d agents and %d robots", self.settings.agents, self.settings.agents)
        while True:
            now = ticker.wait(stop)
            self._drain(now)
            self._serve_steering(now)
            if stop.is_set():
                self.clock.stop(now)
            before = self.clock.state
            state = self.clock.update(now, self.team_ready())
            if state == WAITING and stop.is_set():
                log.info("stopped before the mission started")
                return
            if before == WAITING and state == RUNNING:
                self.observed.started_wall = time.time()
                log.info("team ready: mission started")
                if self.mission_file is not None:
                    mission = {
                        "swarm": self.settings.swarm,
                        "started_wall": self.observed.started_wall,
                    }
                    self.mission_file.parent.mkdir(parents=True, exist_ok=True)
                    self.mission_file.write_text(json.dumps(mission) + "\n", encoding="utf-8")
                    self._journal.unlink(missing_ok=True)  # a previous mission's requests
            t = self.clock.mission_time(now)
            polygon = self._publish_domain(state, t)
            ticks_to_sample -= 1
            if state == RUNNING and ticks_to_sample <= 0:
                began = time.monotonic()
                self._sample(t, polygon)
                cost = time.monotonic() - began
                # Sample less often while e_a is expensive (big team, overloaded machine),
                # so that it takes at most SAMPLE_SHARE of a core; back to normal once cheap.
                ticks_to_sample = max(
                    every,
                    math.ceil(cost / SAMPLE_SHARE * self.settings.rate * self.settings.time_scale),
                )
            if state == DONE and done_since is None:
                done_since = now
                self._sample(t, polygon)  # the final error, at the end of the mission
                log.info("mission done at t = %.1f s (%d overrun ticks)", t, ticker.overruns)
            if self.recorder is not None and (state == RUNNING or done_since == now):
                ticks_to_record -= 1
                if ticks_to_record <= 0 or done_since == now:
                    cost = self._record(t, polygon, thin=skipped > 0)
                    skipped = 0
                    # Past RECORD_SHARE of a core, record every k-th tick (newest poses).
                    ticks_to_record = math.ceil(
                        cost / RECORD_SHARE * self.settings.rate * self.settings.time_scale
                    )
                else:
                    self.recording["skipped_ticks"] += 1
                    skipped += 1
            finished = done_since is not None and now - done_since >= DONE_HOLD
            if now >= next_status or finished:
                self._publish_status(state, t)
                next_status = now + STATUS_PERIOD
            if finished:
                return


def build_summary(
    settings: Settings, observed: Observed, steering: Steering | None = None
) -> dict[str, Any]:
    """summary.json: the keys of ``covswarm sim`` plus process-level figures."""
    from covswarm.mission.physical import agent_wheel_figures, physical_summary
    from covswarm.mission.report import neighbor_histogram, steady_state_mean

    record = observed.record
    final = record.positions[-1]
    ids = sorted(final)
    return {
        "scenario": settings.scenario.name,
        "agents": settings.agents,
        "law": settings.law,
        "feedforward": settings.feedforward,
        "kappa": float(settings.kappa),
        "duration": float(settings.duration),
        "mission_time": record.t[-1],
        "dynamics": "unicycle",
        "samples": len(record.t),
        "steady_state_error_mean": steady_state_mean(np.array(record.t), np.array(record.error)),
        "final_error": record.error[-1],
        "initial_error": record.error[0],
        "neighbor_histogram": neighbor_histogram(
            np.array([final[i] for i in ids]), record.polygons[-1]
        ),
        "alive_at_end": {
            "agents": observed.liveness.count("agent"),
            "robots": observed.liveness.count("robot"),
        },
        "lost_processes": losses_summary(observed.liveness.events),
        "team_changes": team_changes_summary(observed.team_changes, record),
        "agent_stats": agent_figures(observed.agent_stats),
        "guards": agent_guards(observed.agent_stats),
        "rejected_messages": observed.rejected,
        "error_samples_clipped": observed.clipped_samples,
        "crowding": settings.crowding.to_dict(),
        "tile_size": settings.tile_size,
        "started_wall": observed.started_wall,
        **({} if steering is None else steering_summary(steering)),
        **physical_summary(
            np.array(record.t),
            record.trajectories(),
            settings.scenario.robot_diameter,
            record.robot_ids(),
        )[0],
        **agent_wheel_figures(observed.agent_stats, record.t[-1]),
    }


def steering_summary(steering: Steering) -> dict[str, Any]:
    """summary.json's record of steering: every request, refusals per reason, the limit."""
    return {
        "steering": [record.to_dict() for record in steering.records],
        "steering_refused": dict(sorted(steering.refused.items())),
        "steering_largest_jump": steering.largest_jump,
        "max_domain_speed": steering.limits.max_speed,
    }


def open_recorder(
    settings: Settings,
    out_dir: Path | None,
    live_port: int | None,
    seed: int | None,
    resume: bool = False,
) -> RunRecorder | None:
    """The run's recorder (run.mcap in ``out_dir``, live view on ``live_port``), or None.

    A resumed coordinator records its part beside the first (run-1.mcap, ...).
    """
    if out_dir is None and live_port is None:
        return None
    from covswarm.records.recorder import LIVE_HOST, LiveViewError, RunRecorder

    scenario = settings.scenario
    try:
        recorder = RunRecorder(
            out_dir,
            run_metadata={
                "source": "run",
                "scenario": scenario.name,
                "law": settings.law,
                "feedforward": settings.feedforward,
                "kappa": settings.kappa,
                "seed": seed,
                "agents": settings.agents,
                "duration": settings.duration,
                "swarm": settings.swarm,
                "time_scale": settings.time_scale,
                "pose_rate_hz": settings.rate,
            },
            workspace=scenario.workspace,
            obstacles=scenario.obstacles,
            live_port=live_port,
            continued=resume,
        )
    except LiveViewError as exc:
        raise click.ClickException(f"--foxglove: {exc}") from None
    if recorder.live_port is not None:
        log.info("Foxglove live view on ws://%s:%d", LIVE_HOST, recorder.live_port)
    return recorder


def read_mission_start(path: Path, swarm: str) -> float:
    """The start wall time recorded in ``path`` for ``swarm`` (UsageError if there is none)."""
    try:
        mission = json.loads(path.read_text(encoding="utf-8"))
        started = float(mission["started_wall"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise click.UsageError(f"--resume: no mission start in {path}: {exc}") from None
    if mission.get("swarm") != swarm or not math.isfinite(started):
        raise click.UsageError(f"--resume: {path} is not a mission of swarm {swarm!r}")
    return started


def write_run_outputs(
    out_dir: Path, settings: Settings, observed: Observed, steering: Steering | None = None
) -> None:
    """summary.json, error.csv, error.png, trajectories.png through mission.report."""
    from covswarm.mission.report import write_outputs

    record = observed.record
    write_outputs(
        out_dir,
        summary=build_summary(settings, observed, steering),
        t=np.array(record.t),
        error=np.array(record.error),
        trajectories=record.trajectories(),
        polygons=record.polygons,
        obstacles=list(settings.scenario.obstacles),
        workspace=settings.scenario.workspace,
        density=settings.scenario.density(record.t[-1]) if record.t else None,
    )


@click.command("coordinator")
@click.option(
    "--scenario",
    "scenario_name",
    default="passage",
    show_default=True,
    help=SCENARIO_HELP,
)
@click.option(
    "--connect",
    multiple=True,
    required=True,
    help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable).",
)
@click.option("--swarm", required=True, help="Swarm name (key prefix) shared by the run.")
@click.option("--agents", type=click.IntRange(min=1), help="Team size to wait for [scenario].")
@click.option(
    "--duration", type=click.FloatRange(min=0, min_open=True), help="Mission length, s [scenario]."
)
@click.option(
    "--rate",
    type=click.FloatRange(min=0, min_open=True),
    default=20.0,
    show_default=True,
    help="Domain broadcasts per second.",
)
@click.option(
    "--sample-rate",
    type=click.FloatRange(min=0, min_open=True),
    default=10.0,
    show_default=True,
    help="e_a samples per second (at most).",
)
@click.option("--kappa", type=click.FloatRange(min=0, min_open=True), help="Gain [scenario].")
@click.option(
    "--tile-size",
    type=click.FloatRange(min=0, min_open=True),
    help=f"Beacon tile side broadcast to every agent, m [{TILE_SPACINGS:g} x the team's mean "
    "spacing in S(0)].",
)
@click.option(
    "--feedforward/--no-feedforward",
    default=True,
    help="How the agents run (recorded in summary.json).",
)
@click.option(
    "--law",
    type=click.Choice(("da", "d1")),
    default="da",
    show_default=True,
    help="The agents' control law (recorded in summary.json).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Output folder.",
)
@click.option(
    "--resume",
    is_flag=True,
    help=f"Continue the mission recorded in OUT/{MISSION_FILE} (a restarted coordinator).",
)
@click.option(
    "--max-domain-speed",
    type=click.FloatRange(min=0, min_open=True),
    help="Fastest a steered vertex of S may move, m/s [robots' top speed less kappa x "
    "one body diameter, at least a quarter of it].",
)
@click.option(
    "--record/--no-record",
    default=True,
    show_default=True,
    help="Write OUT/run.mcap and OUT/trajectories.csv (docs/records.md).",
)
@FOXGLOVE_OPTION
@click.option("--seed", type=int, help="Seed of the robots' start (recorded in run.mcap only).")
@TIME_SCALE_OPTION
@SECURE_OPTION
def coordinator_command(
    scenario_name: str,
    connect: Sequence[str],
    swarm: str,
    agents: int | None,
    duration: float | None,
    rate: float,
    sample_rate: float,
    kappa: float | None,
    tile_size: float | None,
    feedforward: bool,
    law: str,
    out_dir: Path,
    resume: bool,
    max_domain_speed: float | None,
    record: bool,
    foxglove_port: int | None,
    seed: int | None,
    time_scale: float,
    secure: Path | None,
) -> None:
    """Broadcast the moving domain, monitor the team, write the run's outputs."""
    import zenoh

    from covswarm.protocol import alive_key, check_swarm
    from covswarm.protocol.session import session_config
    from covswarm.runtime.claims import token_exists

    logging.basicConfig(level=logging.INFO, format="%(asctime)s coordinator %(message)s")
    try:
        scenario = load_scenario(scenario_name)
        check_swarm(swarm)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    team = scenario.agents if agents is None else agents
    settings = Settings(
        scenario=scenario,
        swarm=swarm,
        agents=team,
        duration=scenario.duration if duration is None else duration,
        kappa=scenario.kappa if kappa is None else kappa,
        rate=rate,
        sample_rate=sample_rate,
        feedforward=feedforward,
        law=law,
        time_scale=time_scale,
        tile_size=swarm_tile_size(scenario, team) if tile_size is None else tile_size,
        max_domain_speed=max_domain_speed,
    )
    if settings.crowding.crowded:
        log.warning(settings.crowding.warning(team))
    resume_wall = read_mission_start(out_dir / MISSION_FILE, swarm) if resume else None
    stop = StopFlag()
    with zenoh.open(session_config(list(connect), secure=secure)) as session:
        if token_exists(session, alive_key(swarm, "coordinator", 0)):
            raise click.ClickException(f"swarm {swarm!r} already has a coordinator")
        recorder = open_recorder(settings, out_dir if record else None, foxglove_port, seed, resume)
        coordinator = None
        try:
            coordinator = Coordinator(
                session,
                settings,
                mission_file=out_dir / MISSION_FILE,
                resume_wall=resume_wall,
                recorder=recorder,
            )
            coordinator.run(stop)
        finally:
            if recorder is not None and coordinator is not None:
                recorder.note(
                    "recording",
                    {**coordinator.recording, "record_share": RECORD_SHARE, **recorder.counts},
                )
            if recorder is not None:
                recorder.close()
    if recorder is not None and coordinator.clock.state != WAITING:
        mission = coordinator.clock.mission_time(coordinator.clock.stopped_at or 0.0)
        cost = coordinator.recording
        log.info(
            "recording took %.2f s of CPU over %.1f s of mission (%.2f%% of a core); %s; %s",
            cost["seconds"],
            mission,
            100 * cost["seconds"] / max(mission / time_scale, 1e-9),
            {k: v for k, v in cost.items() if k != "seconds"},
            recorder.counts,
        )
    if not coordinator.observed.record.t:
        log.info("no samples recorded: no outputs written")
        return
    write_run_outputs(out_dir, settings, coordinator.observed, coordinator.steering)
    log.info("wrote %s", out_dir)
