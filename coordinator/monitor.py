"""Pure bookkeeping of the coordinator: mission clock, liveness, error record, summary.

No I/O and no zenoh here: coordinator.core feeds these from its subscriptions, so the
logic that decides when the mission starts, who died when and what the summary says is
unit-tested without a network.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field

import numpy as np

from covswarm.tvd.safety import SAFETY_RADIUS

WAITING, RUNNING, DONE = "waiting", "running", "done"

# s the whole team holds its tokens before the mission starts: every agent has then had its
# early beacons (within a second of the last token) and knows the robots next to it, which
# its safety filter needs before its robot moves (MissionPhase.settle).
START_SETTLE = 1.5
# Rounds of the neighbour exchange (an agent's AgentState out, the AgentStates and beacon
# tiles it follows chosen again: AgentBrain.exchange_due) the team holds its tokens for, at
# the slowest agent's pace, when that is longer than START_SETTLE (:func:`start_settle`).
# A robot knows a neighbour for its safety filter after about three of its rounds: the
# neighbour takes the newcomer's token and beacons, the newcomer reads the beacon and
# follows its AgentStates, then reads one. START_SETTLE was written for 10 Hz rounds; an
# overloaded machine steps its brains at ~1.25 Hz (1000 robots in real time), and the
# mission then started ~2 rounds after the last token: robots backed away from a known
# neighbour inside the safe distance into one they did not know yet (the unseen-speed
# limit, covswarm.tvd.safety.unseen_speed_limit, assumes those are beyond SAFETY_RADIUS).
# covswarm.deploy.netsim (which starts as this rule does), circle-400 with S 8x slower,
# brains stepped every 0.45-1.15 s, robots stopping 1 s after a command, 12 s, seeds 0-3
# (30 Nov 2026): 3, 3, 4 and 4 pairs within a body diameter, the closest 0.111 m, with
# 1.5 s; none but one 0.3 mm inside it (seed 2, an arc: brain.ARC_TURN) with three rounds
# (3.45 s), and mean e_a over the first 5 s alike (0.289-0.309 m, 0.289-0.311 m): the team
# waits, and nobody stands while S moves. The brain-side alternative, each robot standing
# still for its first three turns after declaring itself alive, raised that mean by 31 %
# (seed 0: 0.401 against 0.307 m) and e_a at 12 s to 0.164 m (0.077 m): two robots placed
# on S's edge stood while its trailing corner passed them, and outside S a robot's cell is
# empty, it aims through the packed team at S's centroid, and the filter holds it off.
START_ROUNDS = 3
# s: the longest the start waits for slow rounds: one agent's state stamped long after its
# last (a stalled process) must not hold the whole team for minutes.
MAX_START_SETTLE = 10.0
# s beyond the settle the start waits for the team's neighbour discovery to show no gap
# (:func:`discovery_gaps`), then starts anyway and says so. A robot whose brain does not know
# the robot next to it drives into it at its first mission step, at up to top speed: 100
# robots at 30 Hz on an overloaded host, robot 14 at 0.76 m/s into robot 39, 0.162 m away,
# to 0.055 m, 39's last state before the start naming no neighbour (docs/scaling.md, 3 Dec
# 2026). A pair can also sit on a knife-edge of the geometry that no waiting resolves: hence
# the bound.
DISCOVERY_WAIT = 5.0
# m: the shortest shared edge of two robots' cells, in the tessellation of their measured
# poses, for which the start waits until each agent names the other (:func:`discovery_gaps`).
# Shorter, the pair meets at a near-degenerate vertex (four robots on the corners of a
# square), which the agents' own diagrams, from positions heard rather than measured, may
# resolve the other way: their cells barely touch, and each filters against the other as a
# robot within its safety radius whether or not it names it.
DISCOVERY_EDGE = 0.02
# m: only pairs this close are waited for: the agents' safety radius
# (covswarm.tvd.safety.SAFETY_RADIUS), beyond which their speed limit already assumes
# robots they do not know (unseen_speed_limit). Farther apart, two brains that do not know
# each other cover S badly for a while, not dangerously: robots put down outside S whose
# cells reach into it from two sides (scenarios/scatter-in.toml, live: five such pairs,
# 0.7-2.6 m apart, held the start for DISCOVERY_WAIT) meet as they drive in.
DISCOVERY_REACH = SAFETY_RADIUS
# s between two tessellations of the team's poses for :func:`discovery_gaps` while the start
# waits (the coordinator's, CoordinatorCore.discovery_gaps): robots stand still meanwhile,
# and 1000 robots' cells cost tens of ms.
DISCOVERY_PERIOD = 0.5


def discovery_gaps(
    listed: Mapping[int, AbstractSet[int]], team: AbstractSet[int], pairs: np.ndarray
) -> list[str]:
    """What the AgentStates heard before the start say is missing from the team's neighbour
    discovery (none: nothing known to be missing). ``pairs``: (m, 2) robot ids whose cells
    in S, tessellated from their measured poses, share an edge of at least DISCOVERY_EDGE
    and which stand within DISCOVERY_REACH of each other
    (covswarm.tvd.coverage.neighbour_pairs); ``listed``: id -> the neighbours its agent's
    last state names; ``team``: the ids that count. A gap is a pair of the team one agent of
    which does not name the other. Agents not heard yet are not held against it (their
    rounds are the settle's, :func:`start_settle`); neither are robots outside S, whose
    cells are empty and whose brains name nobody."""
    gaps = []
    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2).tolist():
        if i not in team or j not in team:
            continue
        for me, other in ((i, j), (j, i)):
            if me in listed and other not in listed[me]:
                gaps.append(f"agent {me} does not name {other}, whose cell meets its own")
    return gaps


@dataclass
class ExchangeGaps:
    """The time between each agent's last two AgentStates (their stamps, the agent's own
    clock): one round of its neighbour exchange, as slow as its brain is stepped."""

    last: dict[int, float] = field(default_factory=dict)  # id -> its newest state's stamp
    gaps: dict[int, float] = field(default_factory=dict)  # id -> s between its last two

    def add(self, ident: int, stamp: float) -> None:
        """Agent ``ident``'s AgentState stamped ``stamp`` (s); an older or repeated one
        changes nothing."""
        last = self.last.get(ident)
        if last is not None:
            if not stamp > last:
                return
            self.gaps[ident] = stamp - last
        self.last[ident] = stamp

    def slowest(self) -> float:
        """s: the longest round of any agent heard twice (0 before any)."""
        return max(self.gaps.values(), default=0.0)


def start_settle(slowest: float) -> float:
    """s the team must have held its tokens before the mission starts, when the slowest
    agent's neighbour exchange takes ``slowest`` s a round: START_SETTLE, or START_ROUNDS of
    those rounds when longer (never above MAX_START_SETTLE). At 10 Hz: START_SETTLE."""
    rounds = START_ROUNDS * slowest if math.isfinite(slowest) else 0.0
    return min(max(START_SETTLE, rounds), MAX_START_SETTLE)


@dataclass
class MissionPhase:
    """waiting -> running (once the team is up) -> done (at ``duration``).

    Times are monotonic seconds; mission time is 0 until the start and frozen at
    ``duration`` once done, so agents never see a domain past the end of the scenario.
    """

    duration: float
    started_at: float | None = None
    stopped_at: float | None = None
    # s the team must have been up before the mission starts (0: at once). Agents meet their
    # neighbours through beacons sent within a second of a teammate's token; a robot that
    # moves before it knows who is next to it cannot avoid them.
    settle: float = 0.0
    ready_since: float | None = None
    # s beyond ``settle`` the start waits for ``discovered`` (DISCOVERY_WAIT); whether the
    # mission started without it
    discovery_wait: float = 0.0
    started_undiscovered: bool = False

    @property
    def state(self) -> str:
        if self.started_at is None:
            return WAITING
        return DONE if self.stopped_at is not None else RUNNING

    def update(self, now: float, team_ready: bool, discovered: bool = True) -> str:
        """Advance the state machine; returns the state at ``now``. ``discovered``: nothing is
        known to be missing from the team's neighbour discovery (:func:`discovery_gaps`)."""
        if not team_ready:
            self.ready_since = None
        elif self.ready_since is None:
            self.ready_since = now
        if self.started_at is None and team_ready and now - self.ready_since >= self.settle:
            if discovered or now - self.ready_since >= self.settle + self.discovery_wait:
                self.started_at = now
                self.started_undiscovered = not discovered
        if self.state == RUNNING and now - self.started_at >= self.duration:
            self.stopped_at = self.started_at + self.duration
        return self.state

    def stop(self, now: float) -> None:
        """End early (operator interrupt): done from ``now`` if running, else stays waiting."""
        if self.state == RUNNING:
            self.stopped_at = now

    def mission_time(self, now: float) -> float:
        if self.started_at is None:
            return 0.0
        end = self.stopped_at if self.stopped_at is not None else now
        return min(end - self.started_at, self.duration)


@dataclass(frozen=True)
class LivenessEvent:
    """A process appeared (``alive``) or its liveliness token disappeared."""

    role: str
    id: int
    alive: bool
    wall: float
    t: float | None  # mission time, None before the mission started


@dataclass
class Liveness:
    """Which processes hold a liveliness token, and the history of changes."""

    alive: dict[str, set[int]] = field(default_factory=dict)
    events: list[LivenessEvent] = field(default_factory=list)

    def update(
        self, role: str, ident: int, alive: bool, wall: float, t: float | None
    ) -> LivenessEvent | None:
        """Record a token put/delete; None if it changes nothing (e.g. a repeated put)."""
        members = self.alive.setdefault(role, set())
        if (ident in members) == alive:
            return None
        if alive:
            members.add(ident)
        else:
            members.discard(ident)
        event = LivenessEvent(role, ident, alive, wall, t)
        self.events.append(event)
        return event

    def count(self, role: str) -> int:
        return len(self.alive.get(role, ()))


# s: the oldest pose time an e_a sample may be placed at. Poses older than this (a robot
# that stopped publishing, a host whose clock is off) do not drag the sample back further.
MAX_POSE_AGE = 0.5


def mean_pose_time(t: float, wall_now: float, stamps: Iterable[float]) -> float:
    """Mission time (s) at which poses stamped ``stamps`` were measured, on average: a pose
    stamped s (the run's wall clock, as ``wall_now``) was taken at t - (wall_now - s). ``t``
    without stamps; NaN when a stamp is not finite.

    The coordinator evaluates e_a = ||p - c(p, t)|| against S at this time (clipped by
    :func:`clip_sample_time`): against S(now), a pose that is 25 ms old on average (20 Hz
    poses) adds the domain's motion over 25 ms to every robot's error, which is 20 % of a
    12 mm steady state at 0.1 m/s.
    """
    ages = wall_now - np.asarray(list(stamps), dtype=float)
    return t - float(np.mean(ages)) if ages.size else t


def clip_sample_time(when: float, t: float, earliest: float) -> float:
    """``when`` (s) clipped to [max(earliest, t - MAX_POSE_AGE), t]; ``t`` if not finite.
    earliest: the previous sample's time (samples stay in order)."""
    lower = min(t, max(earliest, t - MAX_POSE_AGE))
    return float(np.clip(when, lower, t)) if math.isfinite(when) else t


def positions_at(
    target: float,
    stamps: np.ndarray,
    points: np.ndarray,
    earlier_stamps: np.ndarray,
    earlier_points: np.ndarray,
) -> np.ndarray:
    """(n, 2) m: each robot's latest position ``points`` (n, 2), stamped ``stamps`` (n,) s,
    moved to the one time ``target`` (s, same clock) along its velocity since its earlier
    pose (``earlier_points`` stamped ``earlier_stamps``; NaN: none), by at most
    MAX_POSE_AGE; as measured where that velocity is unknown (no earlier pose, or one not
    older by more than 0 and at most MAX_POSE_AGE).

    e_a compares every robot with its centroid at one time; robots publish at their own
    phase, so the latest poses span a pose period (50 ms at 20 Hz). Taken as they are, a
    robot following S at 0.19 m/s is off by up to ~5 mm at the sample's time: ~0.006 m of
    e_a at 10 robots, ~0.02 m at 100 (it grows as the square root of n), more than the
    whole of the simulator's.
    """
    gap = stamps - earlier_stamps
    known = np.isfinite(gap) & (gap > 0.0) & (gap <= MAX_POSE_AGE)
    velocity = np.zeros_like(points)
    velocity[known] = (points[known] - earlier_points[known]) / gap[known, None]
    shift = np.clip(target - stamps, -MAX_POSE_AGE, MAX_POSE_AGE)
    return points + velocity * shift[:, None]


@dataclass
class ErrorRecord:
    """e_a(t) samples with the robot positions and domain they were computed from."""

    t: list[float] = field(default_factory=list)
    error: list[float] = field(default_factory=list)
    positions: list[dict[int, tuple[float, float]]] = field(default_factory=list)
    polygons: list[np.ndarray] = field(default_factory=list)

    def add(
        self, t: float, error: float, positions: Mapping[int, tuple[float, float]], polygon
    ) -> None:
        self.t.append(float(t))
        self.error.append(float(error))
        self.positions.append(dict(positions))
        self.polygons.append(np.asarray(polygon, dtype=float))

    def robot_ids(self) -> list[int]:
        """Every robot seen in any sample, sorted (the trajectory columns)."""
        return sorted({i for sample in self.positions for i in sample})

    def trajectories(self) -> np.ndarray:
        """(T, n, 2) positions, NaN where a robot was unknown or not alive."""
        ids = self.robot_ids()
        column = {ident: k for k, ident in enumerate(ids)}
        out = np.full((len(self.t), len(ids), 2), np.nan)
        for row, sample in enumerate(self.positions):
            for ident, xy in sample.items():
                out[row, column[ident]] = xy
        return out


# What the launcher shows and summary.json lists per agent (AgentBrain.stats' names):
# control rate achieved, share of control periods that overran their deadline, compute time
# per step, messages received per second.
HEADLINE_STATS = ("rate_hz", "missed_deadline", "step_us_p50", "step_us_p99", "rx_per_s")


def agent_figures(stats: Mapping[int, Mapping[str, float]]) -> dict:
    """Team mean/min/max of every stat the agents report, and the headline stats per agent.

    ``stats``: the latest AgentState.stats of each agent. Stats an agent does not report are
    skipped, so a newer or older agent never breaks the summary.
    """
    team: dict[str, dict[str, float]] = {}
    names = sorted({name for entry in stats.values() for name in entry})
    for name in names:
        values = [float(e[name]) for e in stats.values() if name in e and math.isfinite(e[name])]
        if values:
            team[name] = {"mean": float(np.mean(values)), "min": min(values), "max": max(values)}
    per_agent = {
        str(i): {k: stats[i][k] for k in HEADLINE_STATS if k in stats[i]} for i in sorted(stats)
    }
    return {"team": team, "per_agent": per_agent}


def agent_guards(stats: Mapping[int, Mapping[str, float]]) -> dict:
    """How often the agents' amplification guard rescaled their control step, summed over the
    team from their latest stats (``guarded`` and ``mission_steps``; agents that do not report
    them are left out and counted in ``agents_reporting``)."""
    reporting = [e for e in stats.values() if "guarded" in e and "mission_steps" in e]
    guarded = int(sum(e["guarded"] for e in reporting))
    steps = int(sum(e["mission_steps"] for e in reporting))
    return {
        "agents_reporting": len(reporting),
        "robot_steps": steps,
        "rows_rescaled": guarded,
        "rows_rescaled_rate": guarded / steps if steps else 0.0,
    }


def losses_summary(events: Iterable[LivenessEvent]) -> list[dict]:
    """Tokens that disappeared (processes that died or hung), for summary.json."""
    return [{"role": e.role, "id": e.id, "t": e.t, "wall": e.wall} for e in events if not e.alive]


# Re-convergence after a team change (see docs/faults.md): e_a must come back below
# max(RECOVERY_FLOOR, RECOVERY_FACTOR x its mean over the RECOVERY_WINDOW before the change)
# and stay there for RECOVERY_HOLD. The floor keeps an already tiny pre-change level (a team
# at rest on a CVT) from demanding more precision than a healthy run reaches.
RECOVERY_WINDOW = 2.0  # s
RECOVERY_FACTOR = 1.5
RECOVERY_FLOOR = 0.03  # m
RECOVERY_HOLD = 1.0  # s


@dataclass(frozen=True)
class TeamChange:
    """The team (robots whose robot and agent both hold a token) changed during the mission."""

    t: float  # mission time
    wall: float
    lost: tuple[int, ...]
    joined: tuple[int, ...]


def team_of(alive: Mapping[str, set[int]]) -> frozenset[int]:
    """Robot ids that count in e_a: the robot and its agent both alive.

    A robot whose agent died is stopped (command timeout) and no longer covers anything; a
    brain whose robot died has nothing to steer.
    """
    return frozenset(alive.get("robot", set()) & alive.get("agent", set()))


def reconvergence(t: list[float], error: list[float], change_t: float) -> dict:
    """How e_a recovered after a team change at mission time ``change_t``.

    ``level_before``: mean e_a over the RECOVERY_WINDOW before the change (None without
    samples there, and the bound is then the floor); ``bound``; ``reconverged_after``: s from
    the change to the first sample from which e_a stays <= bound for RECOVERY_HOLD (None if
    that never happened before the end of the record).
    """
    times, values = np.asarray(t, dtype=float), np.asarray(error, dtype=float)
    before = values[(times >= change_t - RECOVERY_WINDOW) & (times < change_t)]
    level = float(before.mean()) if before.size else None
    bound = max(RECOVERY_FLOOR, RECOVERY_FACTOR * level) if level is not None else RECOVERY_FLOOR
    after = np.flatnonzero(times >= change_t)
    reconverged = None
    for start in after:
        held = (times >= times[start]) & (times <= times[start] + RECOVERY_HOLD)
        if times[-1] < times[start] + RECOVERY_HOLD:
            break  # not enough record left to show it holds
        if np.all(values[held] <= bound):
            reconverged = float(times[start] - change_t)
            break
    return {"level_before": level, "bound": bound, "reconverged_after": reconverged}


def team_changes_summary(changes: Iterable[TeamChange], record: ErrorRecord) -> list[dict]:
    """Who left or joined the team when, and how long e_a took to re-converge."""
    return [
        {
            "t": c.t,
            "wall": c.wall,
            "lost": list(c.lost),
            "joined": list(c.joined),
            **reconvergence(record.t, record.error, c.t),
        }
        for c in changes
    ]
