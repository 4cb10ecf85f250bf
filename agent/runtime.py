"""``covswarm agent``: the brain of one robot, as its own process.

Each agent knows only its neighbourhood: what it receives per second depends on how many
robots are near it, never on the team size.

Neighbour discovery
-------------------
- **Own robot**: subscribes to ``robot/<me>/pose``; publishes ``robot/<me>/cmd``.
- **Domain**: subscribes to the broadcast ``domain`` and extrapolates it between messages
  (vertices + velocities * time since its stamp, for at most ``--max-extrapolation`` s; after
  that the domain holds still and its velocities count as zero).
- **Beacons (bootstrap)**: every ``--beacon-period`` (10 s), and at most 1 s after the
  last one whenever another agent's liveliness token appears (a newcomer, or a team
  starting) or a neighbour's AgentState keeps leaving it out, the agent publishes a Beacon
  on ``beacon/<tx>/<ty>/<me>``, (tx, ty) = floor(position / tile_size) with the swarm's
  tile size from the Domain broadcast (none before the first Domain), and subscribes to
  the (2r+1)^2 tiles around its own with ``beacon/<tx>/<ty>/*`` selectors, re-declared
  when it changes tile. r starts at 1 (3x3 tiles) and grows, up to ``--max-tile-radius``,
  while its cell is too large for the tiles to hold every robot that could cut it (a
  robot farther than twice the cell radius cannot; see :func:`cell_reach`). A robot known
  only from its beacon is a candidate at the beacon's position while that beacon is the
  newest news of it.
- **Two-hop set**: the agent publishes AgentState at the control rate: its robot's
  position and velocity, its current Voronoi neighbour ids, and the positions and
  velocities of those neighbours as it used them (``relay``; first-hand ones only), with
  its stats about once a second. It subscribes to the AgentStates of its one-hop
  neighbours, whose relays give it the positions of the rest of its two-hop set, plus
  those of any two-hop robot that no fresh relay carries yet; per-id subscribers are
  declared and undeclared as the set changes and linger ``--linger`` s after an id leaves
  it, so a neighbour flickering across a Voronoi vertex does not churn subscriptions.
  Other robots' positions never come from their 20 Hz poses: one subscription and 10
  messages per second per one-hop neighbour, none per outer-ring robot, for positions
  one control period older (two when relayed).
- Positions are taken from a robot's own AgentState (or pose, for a bridge that sends
  them) while younger than ``--stale-timeout`` (receipt time, so clock skew between
  machines does not matter), else from the freshest neighbour's relay of it younger than
  that, else from its beacon while younger than ``--beacon-timeout``; older robots are
  dropped. All are dead-reckoned with the velocity they carry (what the robot's wheels
  achieve, not the unsaturated command), for at most DEAD_RECKONING_LIMIT s per hop.
- **Faults** (docs/faults.md): a robot whose agent's or robot's liveliness token is deleted
  (``alive/*/*``, changes only) leaves the local diagram at once; an agent whose own pose is
  stale commands (0, 0) and publishes no AgentState or beacon. ``--drop-poses`` /
  ``--delay-poses`` inject seeded loss and delay of poses and AgentStates
  (:class:`PoseImpairment`).

Bad input is dropped, counted per reason (``drop_<reason>`` in AgentState.stats) and
logged rate-limited (protocol.inbound): undecodable or invalid payloads (ProtocolError
reasons), a key and message that disagree about the id, a domain that is not a convex
polygon or is older than the one held, and stamps outside the clock policy of
protocol.inbound (more than ``--max-clock-skew`` ahead of this clock, or older than the
message's timeout plus that skew).

Each step the agent calls covswarm.tvd.control.local_step on itself plus the candidates that can
matter (its two-hop set and robots within 1.25x its cell's reach, see
:meth:`AgentBrain.relevant`): the local partial Voronoi diagram of its two-hop
neighbourhood, whose cost grows with the square of its size, so beacon-only robots far
away are left out. It maps the velocity to wheel speeds with covswarm.tvd.drive.wheel_speeds and
publishes a WheelCommand. Waiting/done, no domain, or no fresh own pose give a (0, 0)
command; so does any failure of the math (the robot stops rather than crash or receive
NaN). Neighbours are computed while waiting too, so the sets are warm at the start. The
liveliness token ``alive/agent/<id>`` is declared once the agent hears its own robot.

Message rates per agent (robot poses at 20 Hz, agents at 10 Hz, k one-hop neighbours, b
robots in the beacon tiles): receives 20 (own pose) + domain rate + 10 k (states) + b / 10
(beacons) per second; sends 10 commands + 10 states + 0.1 beacon per second.

``covswarm agent --ids 0-9`` runs several brains in one process (:func:`run_agents`: one
Zenoh session, each brain with its own keys, subscriptions, claim and token);
``--time-scale`` runs on mission time slower than real time (protocol.session.scaled).

Subscribers (liveliness included) use ring channels that the main loop polls once per
tick (:class:`Inbox`), so no Python callback thread exists; all decoding and math happen in
the main loop, and the brains of one process share the decoding of identical payloads
(:func:`decode`). The decision logic (:class:`AgentBrain`) is pure and unit-tested without
Zenoh.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Protocol

import click
import numpy as np
import zenoh

from covswarm import protocol
from covswarm.protocol.inbound import MAX_CLOCK_SKEW, STAMP_REASONS, DropLog, RateLimit, check_stamp
from covswarm.protocol.security import SECURE_OPTION
from covswarm.protocol.session import (
    MAX_CLOCK_SKEW_OPTION,
    TIME_SCALE_OPTION,
    StopFlag,
    Ticker,
    claim_or_refuse,
    id_selection,
    scaled,
    session_config,
)
from covswarm.tvd.control import local_step
from covswarm.tvd.coverage import validate_polygon
from covswarm.tvd.density import Density
from covswarm.tvd.drive import KHEPERA_IV, DiffDrive, achieved_velocity, wheel_speeds

log = logging.getLogger("covswarm.agent")

STATS_WINDOW = 5.0  # s over which rates are measured
TIMING_SAMPLES = 256  # step durations kept for the p50/p99
LOCAL_MARGIN = 1.25  # local diagram radius, in units of the cell reach (see relevant())
DROP_REASONS = (
    *protocol.REASONS,
    *STAMP_REASONS,
    "wrong_id",  # key and message disagree about the robot id, or a malformed key
    "bad_domain",  # valid message, invalid polygon (non-convex, self-intersecting, ...)
    "old_domain",  # older than the domain already held
)


@dataclass(frozen=True)
class AgentConfig:
    """Tunables of one agent; times in seconds, distances in metres."""

    kappa: float | None = None  # None: use the kappa broadcast with the domain
    feedforward: bool = True
    stale_timeout: float = 1.0
    # Beacons only bootstrap: neighbours' relays keep the two-hop set current, and a
    # teammate's new token triggers an early beacon (see AgentBrain.beacon).
    beacon_period: float = 10.0
    beacon_timeout: float = 25.0
    max_tile_radius: int = 3
    max_extrapolation: float = 1.0
    linger: float = 0.5
    max_clock_skew: float = MAX_CLOCK_SKEW
    robot: DiffDrive = KHEPERA_IV
    # Fault injection (docs/faults.md): drop this fraction of received poses, deliver the
    # rest this many s late; random draws seeded by (pose_seed, id).
    pose_loss: float = 0.0
    pose_delay: float = 0.0
    pose_seed: int = 0


RelayEntry = tuple[int, float, float, float, float]  # id, x, y, vx, vy (AgentState.relay)
InboxItem = tuple[str, int | None, bytes]  # (kind, id in the key (None: domain), payload)
# Samples kept per subscriber between two ticks: only the newest per key is used, but a
# beacon tile carries one key per robot in it.
RING_PER_KEY = 4
# Largest fraction of the gap to the centroid one control period may close (sampled_gain).
MAX_STEP_FRACTION = 0.8
# Seconds between control steps while the mission is not running (neighbour bookkeeping).
IDLE_STEP_PERIOD = 1.0
# s: at most this far ahead are positions dead-reckoned from a reported velocity.
DEAD_RECKONING_LIMIT = 0.25
RING_PER_TILE = 256
# s: an early beacon (a teammate appeared) follows the last one after at least this long, so
# a whole team starting at once costs each agent one beacon per second, not per tick.
BEACON_MIN_PERIOD = 1.0
# s: a neighbour whose AgentState has left us out of its neighbours for this long gets an
# early beacon (no relay told it about us; a common neighbour's usually does in a tick).
ASYMMETRY_GRACE = 0.3
# Token changes kept between two ticks: a ring never blocks Zenoh's threads, and only a
# whole team starting at once (two tokens per robot) comes near it.
LIVELINESS_RING = 8192
STATS_PERIOD = 1.0  # s between two AgentStates that carry the stats (monitors only read them)
FORGET_PERIOD = 1.0  # s between two sweeps of records older than every timeout


class RingSource(Protocol):
    def try_recv(self) -> zenoh.Sample | None: ...


IMPAIRED = ("pose", "state")  # the kinds of message that carry a robot's position


class PoseImpairment:
    """Seeded loss and delay of received positions, between the inbox and the brain (pure).

    Impairs every message that carries a robot's position: its own robot's poses and the
    AgentStates its neighbours' positions come from. Applied to what the agent would
    consume each tick (after the inbox kept the newest message per key), so ``loss`` is the
    fraction of position updates the controller never sees. Delayed ones are handed over
    in arrival order once ``delay`` s have passed; their receipt time is then, so staleness
    counts from when the agent got them.
    """

    def __init__(self, loss: float, delay: float, rng: np.random.Generator) -> None:
        if not (0.0 <= loss < 1.0 and 0.0 <= delay and math.isfinite(delay)):
            raise ValueError(f"pose loss must be in [0, 1) and delay >= 0, got {loss}, {delay}")
        self.loss, self.delay, self._rng = loss, delay, rng
        self._queue: deque[tuple[float, InboxItem]] = deque()
        self.dropped = 0

    def filter(self, items: list[InboxItem], now: float) -> list[InboxItem]:
        """The items to process at ``now``: the others at once, positions that survived and
        are due."""
        out = [item for item in items if item[0] not in IMPAIRED]
        for item in items:
            if item[0] not in IMPAIRED:
                continue
            if self._rng.random() < self.loss:
                self.dropped += 1
            else:
                self._queue.append((now + self.delay, item))
        while self._queue and self._queue[0][0] <= now:
            out.append(self._queue.popleft()[1])
        return out


@dataclass
class Track:
    """Last known position of another robot, when (monotonic) it was received, and the
    velocity its agent reported with it (0 for poses and beacons)."""

    x: float
    y: float
    received: float
    vx: float = 0.0
    vy: float = 0.0


@dataclass(frozen=True)
class Decision:
    """Outcome of one control step: wheel speeds and why."""

    left: float
    right: float
    reason: str  # "running" or why the robot holds still
    velocity: tuple[float, float] = (0.0, 0.0)  # m/s, the control law's
    achieved: tuple[float, float] = (0.0, 0.0)  # m/s, what the (saturated) wheels give


def extrapolate_domain(
    domain: protocol.Domain, now_wall: float, max_extrapolation: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and vertex velocities of the domain at ``now_wall`` (s since the epoch).

    Moves the vertices along their velocities for the time since the domain's stamp, at most
    ``max_extrapolation`` s; beyond that the domain holds still (zero velocities), so a lost
    coordinator cannot drag the swarm away.
    """
    vertices = np.array(domain.vertices, dtype=float)
    velocities = np.array(domain.velocities, dtype=float)
    elapsed = now_wall - domain.stamp
    if elapsed > max_extrapolation:
        return vertices + velocities * max_extrapolation, np.zeros_like(velocities)
    return vertices + velocities * max(elapsed, 0.0), velocities


def extrapolate_density(
    density: Density | None, elapsed: float, max_extrapolation: float
) -> Density | None:
    """The broadcast density ``elapsed`` s after its stamp, as ``extrapolate_domain``.

    Advanced linearly for at most ``max_extrapolation`` s, then held still (zero rates); a
    density that the linear advance would make invalid is held as received.
    """
    if density is None:
        return None
    try:
        advanced = density.at(density.time + min(max(elapsed, 0.0), max_extrapolation))
    except ValueError:
        return density.frozen()
    return advanced.frozen() if elapsed > max_extrapolation else advanced


def cell_reach(distance_to_centroid: float, mass: float) -> float:
    """Distance within which a robot can cut this cell: twice the cell radius R.

    R is estimated from the cell's centroid c and mass m as |p - c| + sqrt(m): 1.4x the
    true R of a square cell centred on p, about R for a 4:1 rectangle; the two-hop set
    covers what the estimate misses.
    """
    return 2.0 * (distance_to_centroid + math.sqrt(max(mass, 0.0)))


def tile_radius(reach: float, tile_size: float, current: int, max_radius: int) -> int:
    """Beacon tile radius r ((2r+1)^2 tiles) that holds every robot within ``reach``.

    Grows at once, shrinks only with a 25 % margin so a cell hovering at a tile boundary
    does not flap the subscriptions.
    """
    needed = min(max(1, math.ceil(reach / tile_size)), max_radius)
    if needed >= current:
        return needed
    relaxed = min(max(1, math.ceil(1.25 * reach / tile_size)), max_radius)
    return relaxed if relaxed < current else current


class _Percentiles:
    """Rolling p50/p99 of the last ``TIMING_SAMPLES`` values."""

    def __init__(self) -> None:
        self._values: deque[float] = deque(maxlen=TIMING_SAMPLES)

    def add(self, value: float) -> None:
        self._values.append(value)

    def get(self, q: float) -> float:
        if not self._values:
            return 0.0
        ordered = sorted(self._values)
        return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


class _Rate:
    """Events per second over the last ``STATS_WINDOW`` seconds from a cumulative count."""

    def __init__(self) -> None:
        self._samples: deque[tuple[float, int]] = deque()

    def add(self, now: float, total: int) -> float:
        self._samples.append((now, total))
        while self._samples[0][0] < now - STATS_WINDOW:
            self._samples.popleft()
        (t0, n0), (t1, n1) = self._samples[0], self._samples[-1]
        return (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0


@dataclass
class Counters:
    """Processed input and control steps, reported in AgentState.stats (drops: DropLog)."""

    received: int = 0  # payloads that reached the main loop
    coalesced: int = 0  # overwritten by a newer payload on the same key before processing
    stale: int = 0  # robots dropped from the local set because their data aged out
    step_errors: int = 0  # control steps that failed (robot commanded to stop)
    steps: int = 0
    mission_steps: int = 0  # steps while the mission runs
    # control periods of the mission whose command went out after the period had ended
    overruns: int = 0


class AgentBrain:
    """Pure decision logic of one agent: feed it messages, ask it for commands. No I/O.

    ``now`` arguments are monotonic seconds (receipt and staleness), ``now_wall`` seconds
    since the epoch (domain extrapolation and message stamps).
    """

    def __init__(self, robot_id: int, config: AgentConfig | None = None) -> None:
        self.id = protocol.check_id(robot_id)
        self.config = config or AgentConfig()
        self.pose: protocol.Pose | None = None
        self.pose_received = -math.inf
        self.domain: protocol.Domain | None = None
        self.density: Density | None = None  # the domain's density, validated (None: uniform)
        self.poses: dict[int, Track] = {}
        self.state_tracks: dict[int, Track] = {}
        self.beacons: dict[int, Track] = {}
        self.neighbor_sets: dict[int, tuple[frozenset[int], float]] = {}
        # relayer id -> (its AgentState.relay entries, when received)
        self.relays: dict[int, tuple[tuple[RelayEntry, ...], float]] = {}
        # id -> (x, y, vx, vy) of every candidate of the last step, reckoned to that step,
        # and the ids among them known first-hand (own pose or AgentState): what our
        # AgentState relays about our neighbours; its keys are the robots usable as
        # candidates at the last step.
        self._reckoned: dict[int, tuple[float, float, float, float]] = {}
        self._first_hand: set[int] = set()
        self._heard: dict[int, float] = {}  # id -> last receipt of its own pose or state
        # id -> roles ("agent", "robot") whose liveliness token was deleted: such a robot is
        # no team member (a stopped robot without brain, or a brain without robot).
        self.dead: dict[int, set[str]] = {}
        self.one_hop: frozenset[int] = frozenset()
        self.radius = 1
        self.reach: float | None = None  # cell_reach of our last non-empty cell
        self.counters = Counters()
        self.drops = DropLog(log, f"agent {self.id}", DROP_REASONS)
        self._failure_log = RateLimit()
        self._wanted: dict[int, float] = {}  # id -> last time it was in the two-hop set
        self._local = 0  # robots in the last local diagram besides ourselves
        self._last_beacon = -math.inf
        # An early beacon is owed: a teammate appeared, or a neighbour does not know us.
        self._beacon_due = False
        self._unrequited: dict[int, float] = {}  # neighbour id -> since when it omits us
        self._last_forget = -math.inf
        self._last_control: float | None = None  # wall time of the last control step
        self._last_idle_step = -math.inf
        self.velocity: tuple[float, float] = (0.0, 0.0)  # last achieved (saturated) command, m/s
        self._seq = 0
        self._step_us = _Percentiles()
        self._pose_age_ms = _Percentiles()
        self._step_rate = _Rate()
        self._rx_rate = _Rate()
        self._rates = (0.0, 0.0)

    # --- input -------------------------------------------------------------------------

    def receive(
        self, kind: str, payload: bytes, now: float, now_wall: float, key_id: int | None = None
    ) -> bool:
        """Decode, check and apply a raw payload of ``kind`` ("pose" | "state" | "beacon" |
        "domain"); ``key_id`` is the id in the key it arrived on. False if dropped."""
        self.counters.received += 1
        try:
            message = decode(kind, payload)
            max_age = self.config.beacon_timeout if kind == "beacon" else self.config.stale_timeout
            check_stamp(message.stamp, now_wall, max_age, self.config.max_clock_skew)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"{kind}: {exc}")
            return False
        if key_id is not None and message.id != key_id:
            self.drops.drop("wrong_id", f"{kind} from id {message.id} on the key of {key_id}")
            return False
        return _HANDLERS[kind](self, message, now)

    def on_pose(self, pose: protocol.Pose, now: float) -> bool:
        if pose.id == self.id:
            self.pose, self.pose_received = pose, now
        else:
            self.poses[pose.id] = Track(pose.x, pose.y, now)
            self._heard[pose.id] = now
            self._revive(pose.id, "robot")
        return True

    def on_agent_state(self, state: protocol.AgentState, now: float) -> bool:
        if state.id == self.id:
            return False
        self.state_tracks[state.id] = Track(state.x, state.y, now, state.vx or 0.0, state.vy or 0.0)
        self._heard[state.id] = now
        self._revive(state.id, "agent")
        self.neighbor_sets[state.id] = (frozenset(state.neighbors), now)
        if state.relay is None:
            self.relays.pop(state.id, None)
        else:
            self.relays[state.id] = (state.relay, now)
        return True

    def on_beacon(self, beacon: protocol.Beacon, now: float) -> bool:
        if beacon.id == self.id:
            return False  # our own beacon, heard through our own tile subscription
        self.beacons[beacon.id] = Track(beacon.x, beacon.y, now)
        self._revive(beacon.id, "agent")
        return True

    def on_liveliness(self, role: str, rid: int, alive: bool) -> None:
        """A liveliness token of another robot's agent or robot appeared or vanished.

        A vanished one takes that robot out of the local diagram at once (SIGKILL deletes the
        token immediately; a frozen process after the Zenoh lease). Fresh data from the same
        role revives it too (a process that came back after a router restart may re-declare
        its token before this agent's subscriber is back), so a missed PUT costs nothing.
        """
        if rid == self.id or role not in ("agent", "robot"):
            return
        if alive:
            if role == "agent" and rid not in self._reckoned:
                self._beacon_due = True  # a newcomer: let it find us without waiting
            self._revive(rid, role)
        else:
            self.dead.setdefault(rid, set()).add(role)

    def _revive(self, rid: int, role: str) -> None:
        roles = self.dead.get(rid)
        if roles is not None:
            roles.discard(role)
            if not roles:
                del self.dead[rid]

    @property
    def running(self) -> bool:
        """Whether the mission runs (by the last domain received)."""
        return self.domain is not None and self.domain.state == "running"

    def pose_fresh(self, now: float) -> bool:
        """Whether our own robot's pose is known and younger than ``stale_timeout``."""
        return self.pose is not None and now - self.pose_received <= self.config.stale_timeout

    def on_domain(self, domain: protocol.Domain, now: float) -> bool:
        if self.domain is not None and domain.stamp < self.domain.stamp:
            self.drops.drop("old_domain", f"domain stamped {domain.stamp} < {self.domain.stamp}")
            return False
        try:
            density = _domain_geometry(domain)
        except ValueError as exc:
            self.drops.drop("bad_domain", f"domain: {exc}")
            return False
        self.domain = domain
        self.density = density
        return True

    # --- neighbourhood -----------------------------------------------------------------

    def candidates(self, now: float) -> dict[int, tuple[float, float]]:
        """Positions of the other robots known well enough to enter the local diagram.

        In order of trust: the freshest of a robot's own pose and AgentState while younger
        than ``stale_timeout`` (a pose wins a tie); else the freshest relay of it in a
        neighbour's AgentState younger than that; else its beacon while younger than
        ``beacon_timeout``. Positions are dead-reckoned to ``now`` with the reported
        velocity (at most DEAD_RECKONING_LIMIT s): a state is up to a control period old
        when the next step reads it, and at 0.2 m/s that lag alone is a centimetre of
        error in every neighbour.
        """
        fresh = now - self.config.stale_timeout
        dead = self.dead
        chosen: dict[int, Track] = {}
        for table in (self.poses, self.state_tracks):
            for rid, track in table.items():
                if track.received >= fresh:
                    known = chosen.get(rid)
                    if known is None or track.received > known.received:
                        chosen[rid] = track
        reckoned: dict[int, tuple[float, float, float, float]] = {}
        for rid, track in chosen.items():
            if rid not in dead:
                lead = min(now - track.received, DEAD_RECKONING_LIMIT)
                reckoned[rid] = (
                    track.x + lead * track.vx,
                    track.y + lead * track.vy,
                    track.vx,
                    track.vy,
                )
        first_hand = set(reckoned)
        relayed: dict[int, float] = {}  # id -> receipt time of the relay used
        for relayer, (entries, received) in self.relays.items():
            if received < fresh or relayer in dead:
                continue
            lead = min(now - received, DEAD_RECKONING_LIMIT)
            for rid, x, y, vx, vy in entries:
                if rid in first_hand or rid in dead or rid == self.id:
                    continue
                if relayed.get(rid, -math.inf) < received:
                    relayed[rid] = received
                    reckoned[rid] = (x + lead * vx, y + lead * vy, vx, vy)
        # A beacon only while it is the newest news of its robot: one that went stale after
        # we heard its state must not bring back where it was seconds ago.
        oldest = now - self.config.beacon_timeout
        for rid, track in self.beacons.items():
            if track.received >= oldest and rid not in reckoned and rid not in dead:
                if self._heard.get(rid, -math.inf) < track.received:
                    reckoned[rid] = (track.x, track.y, 0.0, 0.0)
        self.counters.stale += len(self._reckoned.keys() - reckoned.keys())
        self._reckoned, self._first_hand = reckoned, first_hand
        if now - self._last_forget >= FORGET_PERIOD:
            self._last_forget = now
            self._forget(now)
        return {rid: (x, y) for rid, (x, y, _, _) in reckoned.items()}

    def _forget(self, now: float) -> None:
        """Drop records well past their timeout: memory stays bounded, and the tables that
        every step walks hold only the robots heard from lately."""
        config = self.config
        recent = 2.0 * max(config.stale_timeout, config.linger)
        for table, horizon in (
            (self.poses, recent),
            (self.state_tracks, recent),
            (self.beacons, 2.0 * config.beacon_timeout),
        ):
            for rid in [rid for rid, t in table.items() if now - t.received > horizon]:
                del table[rid]
        for sets in (self.neighbor_sets, self.relays):
            for rid in [rid for rid, (_, t) in sets.items() if now - t > recent]:
                del sets[rid]
        old = now - 2.0 * config.beacon_timeout
        for rid in [rid for rid, t in self._heard.items() if t < old]:
            del self._heard[rid]

    def relevant(
        self, others: dict[int, tuple[float, float]], now: float
    ) -> dict[int, tuple[float, float]]:
        """The candidates that can matter to our control, to keep the local diagram small.

        The two-hop set (neighbours' reported neighbours) plus every robot within
        LOCAL_MARGIN x our cell's reach: our cell is cut only within ``reach``, and since the
        reach overestimates (1.4x for a square cell) this also holds the second ring around
        us, i.e. our neighbours' neighbours, before their AgentStates arrive. Every known
        robot is used until a first non-empty cell gives a reach.
        """
        if self.reach is None or self.pose is None:
            return others
        limit = LOCAL_MARGIN * self.reach
        keep = self.two_hop(now)
        x, y = self.pose.x, self.pose.y
        return {
            rid: p
            for rid, p in others.items()
            if rid in keep or math.hypot(p[0] - x, p[1] - y) <= limit
        }

    def two_hop(self, now: float) -> frozenset[int]:
        """One-hop neighbours plus their fresh reported neighbours, without ourselves."""
        ids = set(self.one_hop)
        for rid in self.one_hop:
            entry = self.neighbor_sets.get(rid)
            if entry is not None and now - entry[1] <= self.config.stale_timeout:
                ids |= entry[0]
        ids.discard(self.id)
        return frozenset(ids)

    def wanted_state_ids(self, now: float) -> set[int]:
        """Ids whose AgentState to subscribe to: our one-hop neighbours, and the rest of the
        two-hop set whose positions no fresh relay of a neighbour carries; lingering
        ``linger`` s (a robot across a near-degenerate Voronoi vertex comes and goes every
        few ticks, and every declaration is a round of routing updates for the whole
        swarm)."""
        fresh = now - self.config.stale_timeout
        covered: set[int] = set()
        for rid in self.one_hop:
            relay = self.relays.get(rid)
            if relay is not None and relay[1] >= fresh:
                covered.update(entry[0] for entry in relay[0])
        wanted = self.one_hop | (self.two_hop(now) - covered)
        return _linger(self._wanted, wanted, now, self.config.linger)

    @property
    def tile_size(self) -> float | None:
        """The swarm's beacon tile size, from the domain broadcast (None before one)."""
        if self.domain is None:
            return None
        return self.domain.tile_size or protocol.DEFAULT_TILE_SIZE

    def wanted_tiles(self) -> set[tuple[int, int]]:
        """Beacon tiles to subscribe to: (2r+1)^2 around our own tile (none without a pose
        or before the domain says the swarm's tile size)."""
        tile_size = self.tile_size
        if self.pose is None or tile_size is None:
            return set()
        tx, ty = protocol.tile_of(self.pose.x, self.pose.y, tile_size)
        r = self.radius
        return {(tx + i, ty + j) for i in range(-r, r + 1) for j in range(-r, r + 1)}

    # --- control -------------------------------------------------------------------------

    def step(self, now: float, now_wall: float) -> Decision:
        """One control step: the wheel speeds to send now, (0, 0) whenever unsure."""
        decision = self._decide(now, now_wall)
        self.velocity = decision.achieved
        return decision

    def _decide(self, now: float, now_wall: float) -> Decision:
        self.counters.steps += 1
        self.counters.mission_steps += self.running
        self._rates = (
            self._step_rate.add(now, self.counters.steps),
            self._rx_rate.add(now, self.counters.received + self.counters.coalesced),
        )
        others = self.candidates(now)
        if not self.pose_fresh(now):
            return Decision(0.0, 0.0, "no-pose")
        if self.domain is None:
            return Decision(0.0, 0.0, "no-domain")
        if self.domain.state != "running" and now - self._last_idle_step < IDLE_STEP_PERIOD:
            # Before the mission the step only keeps the neighbour sets warm: at 10 Hz,
            # agents already up would starve the ones still starting on a loaded machine.
            return Decision(0.0, 0.0, self.domain.state)
        self._last_idle_step = now
        started = time.perf_counter()
        try:
            decision = self._control(self.relevant(others, now), now, now_wall)
        # Any failure of the geometry (degenerate input the math rejects, or a bug) must
        # stop this robot, not kill the process and leave the robot on its last command.
        except Exception as exc:
            self.counters.step_errors += 1
            if self._failure_log.ready():  # at most one line per LOG_INTERVAL, not per tick
                log.warning(
                    "agent %d: control step failed (%d so far), robot stopped: %r",
                    self.id,
                    self.counters.step_errors,
                    exc,
                )
            return Decision(0.0, 0.0, "error")
        self._step_us.add((time.perf_counter() - started) * 1e6)
        return decision

    def _check_symmetry(self, now: float) -> None:
        """Owe an early beacon to a neighbour that keeps leaving us out of its own.

        Voronoi neighbourhood is symmetric, so a neighbour whose fresh AgentState omits us
        for ASYMMETRY_GRACE does not know where we are: no relay reached it and our last
        routine beacon may be 10 s away. Meanwhile both cells are wrong where they meet.
        """
        fresh = now - self.config.stale_timeout
        unrequited = {}
        for rid in self.one_hop:
            entry = self.neighbor_sets.get(rid)
            if entry is not None and entry[1] >= fresh and self.id not in entry[0]:
                unrequited[rid] = self._unrequited.get(rid, now)
        self._unrequited = unrequited
        if any(now - since >= ASYMMETRY_GRACE for since in unrequited.values()):
            self._beacon_due = True

    def _control(
        self, others: dict[int, tuple[float, float]], now: float, now_wall: float
    ) -> Decision:
        assert self.pose is not None and self.domain is not None
        vertices, velocities = extrapolate_domain(
            self.domain, now_wall, self.config.max_extrapolation
        )
        me = np.array([self.pose.x, self.pose.y])
        kappa = self.config.kappa if self.config.kappa is not None else self.domain.kappa
        if self._last_control is not None:
            kappa = sampled_gain(kappa, min(now_wall - self._last_control, 1.0))
        self._last_control = now_wall
        result = local_step(
            self.id,
            {**others, self.id: me},
            vertices,
            velocities,
            kappa,
            feedforward=self.config.feedforward,
            density=extrapolate_density(
                self.density, now_wall - self.domain.stamp, self.config.max_extrapolation
            ),
        )
        # Neighbour bookkeeping runs while waiting too, so subscriptions are warm at start.
        self.one_hop = frozenset(int(rid) for rid in result.neighbors)
        self._check_symmetry(now)
        self._local = len(others)
        if result.mass > 0.0:
            self.reach = cell_reach(float(np.linalg.norm(result.centroid - me)), result.mass)
            self.radius = tile_radius(
                self.reach, self.tile_size, self.radius, self.config.max_tile_radius
            )
        else:
            self.reach = None
        if self.domain.state != "running":
            return Decision(0.0, 0.0, self.domain.state)
        velocity = np.asarray(result.velocity, dtype=float)
        if not np.all(np.isfinite(velocity)):
            raise ValueError(f"non-finite velocity {velocity}")
        heading = np.array([self.pose.theta])
        wheels = wheel_speeds(heading, velocity[None], self.config.robot)
        # What the robot will do, not what was asked: what our AgentState reports for
        # neighbours to dead-reckon with (a saturated command overstates the speed).
        achieved = achieved_velocity(heading, wheels, self.config.robot)[0].tolist()
        left, right = wheels[0].tolist()
        return Decision(left, right, "running", tuple(velocity.tolist()), tuple(achieved))

    # --- output --------------------------------------------------------------------------

    def command(self, decision: Decision, stamp: float) -> protocol.WheelCommand:
        """The wheel command for ``decision``; non-finite speeds become (0, 0)."""
        left, right = decision.left, decision.right
        if not (math.isfinite(left) and math.isfinite(right)):
            left = right = 0.0
        self._seq += 1
        if self.pose is not None:
            # Pose-to-command latency: the robot's pose stamp to this command's stamp (one
            # clock on one machine; across machines it includes their clock offset).
            self._pose_age_ms.add((stamp - self.pose.stamp) * 1e3)
        return protocol.WheelCommand(
            id=self.id,
            left=left,
            right=right,
            stamp=stamp,
            seq=self._seq,
            pose_stamp=self.pose.stamp if self.pose is not None else 0.0,
        )

    def stats(self) -> dict[str, float | int]:
        """Measurements and counters for AgentState.stats (names <= 32 chars)."""
        c = self.counters
        return {
            "rate_hz": round(self._rates[0], 3),
            "step_us_p50": round(self._step_us.get(0.50), 1),
            "step_us_p99": round(self._step_us.get(0.99), 1),
            "rx_per_s": round(self._rates[1], 1),
            "pose_age_ms_p50": round(self._pose_age_ms.get(0.50), 2),
            "pose_age_ms_p99": round(self._pose_age_ms.get(0.99), 2),
            "missed_deadline": round(c.overruns / c.mission_steps, 4) if c.mission_steps else 0.0,
            "rx_total": c.received + c.coalesced,
            "coalesced": c.coalesced,
            **{f"drop_{reason}": n for reason, n in self.drops.counts.items()},
            "stale_dropped": c.stale,
            "step_errors": c.step_errors,
            "candidates": len(self._reckoned),
            "local_set": self._local,
            "neighbors": len(self.one_hop),
            "state_subs": len(self._wanted),
            "tile_radius": self.radius,
        }

    def agent_state(self, stamp: float, stats: bool = True) -> protocol.AgentState | None:
        """Our AgentState (with our stats if ``stats``), or None before our own pose is known."""
        if self.pose is None:
            return None
        # The position dead-reckoned from the pose's stamp to the state's (same robot-side
        # clock on one machine; bounded, in case of skew across machines).
        # The control velocity is unbounded (a fast domain) and the wire's is not: clamped.
        vx, vy = (min(max(v, -protocol.MAX_SPEED), protocol.MAX_SPEED) for v in self.velocity)
        lead = min(max(stamp - self.pose.stamp, 0.0), DEAD_RECKONING_LIMIT)
        x, y = _clamp_position(self.pose.x + lead * vx, self.pose.y + lead * vy)
        # Only first-hand positions are relayed: a relayed one passed on again would be
        # dead-reckoned once more at every hop, and around a cycle of relays forever.
        reckoned = self._reckoned
        relay = [
            (rid, *_clamp_position(*reckoned[rid][:2]), *reckoned[rid][2:])
            for rid in sorted(self.one_hop & self._first_hand)
        ][: protocol.MAX_RELAY]
        return protocol.AgentState(
            id=self.id,
            x=x,
            y=y,
            stamp=stamp,
            neighbors=sorted(self.one_hop),
            stats=self.stats() if stats else None,
            vx=vx,
            vy=vy,
            relay=relay,
        )

    def beacon(self, now: float, stamp: float) -> tuple[tuple[int, int], protocol.Beacon] | None:
        """(tile, Beacon) if one is due at ``now``, else None.

        Due every ``beacon_period``, or BEACON_MIN_PERIOD after the last one once another
        agent's liveliness token appeared (a newcomer, or a whole team starting, must find
        its neighbours, and they it, without waiting for the next routine beacon) or a
        neighbour kept leaving us out of its neighbours (:meth:`_check_symmetry`).

        None while our own pose is stale: a robot that stopped reporting (dead) must not be
        kept alive in the others' diagrams by its brain; and before the domain gives the
        swarm's tile size.
        """
        tile_size = self.tile_size
        if (
            tile_size is None
            or not self.pose_fresh(now)
            or now - self._last_beacon
            < (BEACON_MIN_PERIOD if self._beacon_due else self.config.beacon_period)
        ):
            return None
        self._last_beacon = now
        self._beacon_due = False
        tile = protocol.tile_of(self.pose.x, self.pose.y, tile_size)
        return tile, protocol.Beacon(id=self.id, x=self.pose.x, y=self.pose.y, stamp=stamp)


def _clamp_position(x: float, y: float) -> tuple[float, float]:
    """(x, y) clamped to the wire's coordinate bounds (dead reckoning may overshoot them)."""
    bound = protocol.MAX_COORD
    return min(max(x, -bound), bound), min(max(y, -bound), bound)


_MESSAGE_TYPES: dict[str, type[protocol.Message]] = {
    "pose": protocol.Pose,
    "state": protocol.AgentState,
    "beacon": protocol.Beacon,
    "domain": protocol.Domain,
}
# Decoded messages are immutable and a function of their bytes alone, so the brains of one
# process (covswarm agent --ids) share the decoding: each still receives every sample
# through its own subscriptions, but a pose that five of them follow, or the domain that
# all of them follow, is parsed and validated once. Sized for a tick's worth of distinct
# payloads of a 100-brain process.
DECODE_CACHE = 4096


def decode(kind: str, payload: object) -> protocol.Message:
    """The message of ``kind`` in ``payload``; ProtocolError if invalid (never cached)."""
    if type(payload) is bytes:
        return _decode_bytes(kind, payload)
    return _MESSAGE_TYPES[kind].decode(payload)


@lru_cache(maxsize=DECODE_CACHE)
def _decode_bytes(kind: str, payload: bytes) -> protocol.Message:
    return _MESSAGE_TYPES[kind].decode(payload)


_geometry_of: tuple[protocol.Domain, Density | None] | None = None


def _domain_geometry(domain: protocol.Domain) -> Density | None:
    """Check the domain's polygon and parse its density; ValueError if either is invalid.

    The last valid domain is remembered: the brains of a process receive the same decoded
    Domain object (see decode), and the polygon check costs more than the decoding.
    """
    global _geometry_of
    if _geometry_of is not None and _geometry_of[0] is domain:
        return _geometry_of[1]
    validate_polygon(np.array(domain.vertices))
    density = None if domain.density is None else Density.from_dict(domain.density)
    _geometry_of = (domain, density)
    return density


_HANDLERS: dict[str, Callable[[AgentBrain, object, float], bool]] = {
    "pose": AgentBrain.on_pose,
    "state": AgentBrain.on_agent_state,
    "beacon": AgentBrain.on_beacon,
    "domain": AgentBrain.on_domain,
}


def _linger(since: dict[int, float], current: Iterable[int], now: float, linger: float) -> set[int]:
    """``current`` plus the ids that were in it (``since``: id -> last seen) within ``linger``."""
    for rid in current:
        since[rid] = now
    for rid in [r for r, t in since.items() if now - t > linger]:
        del since[rid]
    return set(since)


def sampled_gain(kappa: float, period: float) -> float:
    """The gain to hold over one control period of ``period`` s in place of ``kappa``.

    Holding kappa (c - p) for a period T moves the robot kappa T of its gap to the
    centroid: past 1 it overshoots, past 2 it diverges (seen: kappa 8 on a starved agent
    at 4 Hz). The gain is capped so that one period never covers more than
    MAX_STEP_FRACTION of the gap; at the rates the agents are meant to run (kappa T well
    below it) kappa is used unchanged.
    """
    if period <= 0.0:
        return kappa
    return min(kappa, MAX_STEP_FRACTION / period)


class Inbox:
    """Newest payload per key from polled Zenoh ring channels, drained by the main loop.

    Every subscriber gets a ring-channel handler that the main loop empties once per tick:
    no Python thread per subscriber (a Python callback gets one, and 1000 agents of ~30
    subscribers each exhaust the kernel's threads) and no GIL taken on Zenoh's threads. A
    newer payload on a key replaces an unprocessed older one (latest-value semantics; the
    replaced ones are counted as coalesced).

    A source subscribed to one key (``wildcard=False``) needs no key handling at all: its
    newest sample is the key's, and the id in its key is known when subscribing. A
    wildcard source (a beacon tile) holds many keys, each parsed once with ``parse``.
    """

    def __init__(self, parse: Callable[[str, str], int] | None = None) -> None:
        self._sources: dict[int, tuple[str, RingSource, int | None, bool]] = {}
        self._parse = parse
        self._ids: dict[str, int | None] = {}  # wildcard sample key -> id (None: malformed)

    def add(
        self, kind: str, source: RingSource, key_id: int | None = None, wildcard: bool = False
    ) -> None:
        """Poll ``source`` (anything with ``try_recv() -> Sample | None``) as ``kind``;
        ``key_id``: the id in its one key (None for the domain)."""
        self._sources[id(source)] = (kind, source, key_id, wildcard)

    def remove(self, source: RingSource) -> None:
        self._sources.pop(id(source), None)

    def subscribe(
        self,
        session: zenoh.Session,
        key: str,
        kind: str,
        capacity: int,
        key_id: int | None = None,
        wildcard: bool = False,
    ) -> zenoh.Subscriber:
        """Declare a ring-channel subscriber on ``key`` and poll it as ``kind``."""
        subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        self.add(kind, subscriber, key_id, wildcard)
        return subscriber

    def drain(self) -> tuple[list[InboxItem], int, int]:
        """([(kind, key id, payload)], payloads coalesced, samples on malformed keys)."""
        out: list[InboxItem] = []
        coalesced = malformed = 0
        for kind, source, key_id, wildcard in self._sources.values():
            if not wildcard:
                last = None
                while (sample := source.try_recv()) is not None:
                    coalesced += last is not None
                    last = sample
                if last is not None:
                    out.append((kind, key_id, last.payload.to_bytes()))
                continue
            latest: dict[str, bytes] = {}
            while (sample := source.try_recv()) is not None:
                key = str(sample.key_expr)
                coalesced += key in latest
                latest[key] = sample.payload.to_bytes()
            for key, payload in latest.items():
                if (rid := self._key_id(kind, key)) is None:
                    malformed += 1
                else:
                    out.append((kind, rid, payload))
        return out, coalesced, malformed

    def _key_id(self, kind: str, key: str) -> int | None:
        if key not in self._ids:
            if len(self._ids) >= DECODE_CACHE:  # bounded: tiles see robots come and go
                self._ids.clear()
            try:
                self._ids[key] = None if self._parse is None else self._parse(key, kind)
            except ValueError:
                self._ids[key] = None
        return self._ids[key]


class Subscriptions:
    """Per-key subscribers of one kind, reconciled with a wanted set of ids (or tiles).

    capacity: samples each ring keeps between ticks (newest first): a pose key gets two
    per 10 Hz tick, a beacon tile one per robot in it per second. ``key_of`` builds the key
    of an id; keys are only built, and subscribers only declared, for what changed.
    """

    def __init__(
        self,
        session: zenoh.Session,
        inbox: Inbox,
        kind: str,
        capacity: int,
        key_of: Callable[[Any], str],
        wildcard: bool = False,
    ) -> None:
        self._session = session
        self._inbox = inbox
        self._kind = kind
        self._capacity = capacity
        self._key_of = key_of
        self._wildcard = wildcard
        self._subscribers: dict[Any, zenoh.Subscriber] = {}

    def update(self, wanted: set[Any]) -> None:
        if wanted == self._subscribers.keys():
            return  # the usual tick: nothing changed
        for item in self._subscribers.keys() - wanted:
            subscriber = self._subscribers.pop(item)
            self._inbox.remove(subscriber)
            subscriber.undeclare()
        for item in wanted - self._subscribers.keys():
            self._subscribers[item] = self._inbox.subscribe(
                self._session,
                self._key_of(item),
                self._kind,
                self._capacity,
                None if self._wildcard else item,
                self._wildcard,
            )

    def __len__(self) -> int:
        return len(self._subscribers)


class AgentLink:
    """The Zenoh side of one agent: its publishers and its changing subscriptions."""

    def __init__(self, session: zenoh.Session, swarm: str, brain: AgentBrain) -> None:
        self.session, self.swarm, self.brain = session, swarm, brain
        self.inbox = Inbox(lambda key, kind: protocol.parse_id(key, swarm, kind))
        drop = zenoh.CongestionControl.DROP
        self.cmd_pub = session.declare_publisher(
            protocol.cmd_key(swarm, brain.id), congestion_control=drop
        )
        self.state_pub = session.declare_publisher(
            protocol.agent_state_key(swarm, brain.id), congestion_control=drop
        )
        self.inbox.subscribe(session, protocol.domain_key(swarm), "domain", RING_PER_KEY)
        self.inbox.subscribe(
            session, protocol.pose_key(swarm, brain.id), "pose", RING_PER_KEY, brain.id
        )
        self.states = Subscriptions(
            session, self.inbox, "state", RING_PER_KEY, lambda r: protocol.agent_state_key(swarm, r)
        )
        self.tiles = Subscriptions(
            session,
            self.inbox,
            "beacon",
            RING_PER_TILE,
            lambda tile: protocol.beacon_tile_selector(swarm, *tile),
            wildcard=True,
        )
        self._next_stats = -math.inf
        # Token changes of every agent and robot: rare events (one sample per process that
        # starts or dies), and they let a dead teammate leave the diagram at once instead of
        # after the staleness timeouts. No history: only changes from now on matter. Polled
        # like the data: a Python callback would get a thread of its own, and those threads
        # (one per brain) take the GIL from the main loop whenever a put releases it: puts
        # then took 0.4 ms on average, 5 to 15 ms at p99 (the GIL switch interval).
        self._delete = zenoh.SampleKind.DELETE
        self._liveliness = session.liveliness().declare_subscriber(
            protocol.alive_selector(swarm), zenoh.handlers.RingChannel(LIVELINESS_RING)
        )
        config = brain.config
        self.impairment = (
            PoseImpairment(
                config.pose_loss,
                config.pose_delay,
                np.random.default_rng([config.pose_seed, brain.id]),
            )
            if config.pose_loss > 0.0 or config.pose_delay > 0.0
            else None
        )

    def receive(self, now: float, wall: float) -> None:
        """Hand everything that arrived since the last tick to the brain."""
        items, coalesced, malformed = self.inbox.drain()
        self.brain.counters.coalesced += coalesced
        for _ in range(malformed):
            self.brain.drops.drop("wrong_id", "a beacon on a malformed key")
        if self.impairment is not None:
            items = self.impairment.filter(items, now)
        for kind, key_id, payload in items:
            self.brain.receive(kind, payload, now, wall, key_id)
        # After the data: a last message from a process that has just died must not revive it.
        while (sample := self._liveliness.try_recv()) is not None:
            try:
                role, rid = protocol.parse_alive_key(str(sample.key_expr), self.swarm)
            except ValueError:
                continue  # not a key of ours; nothing to count it against
            self.brain.on_liveliness(role, rid, sample.kind != self._delete)

    def send_command(self, decision: Decision, wall: float) -> None:
        self.cmd_pub.put(self.brain.command(decision, wall).encode())

    def publish(self, now: float, wall: float) -> None:
        """AgentState every tick while our own pose is fresh (with the stats every
        STATS_PERIOD), a beacon when due."""
        if self.brain.pose_fresh(now):
            with_stats = now >= self._next_stats
            state = self.brain.agent_state(wall, stats=with_stats)
            if state is not None:
                self.state_pub.put(state.encode())
                if with_stats:
                    self._next_stats = now + STATS_PERIOD
        beacon = self.brain.beacon(now, wall)
        if beacon is not None:
            (tx, ty), message = beacon
            key = protocol.beacon_key(self.swarm, tx, ty, self.brain.id)
            self.session.put(key, message.encode(), congestion_control=zenoh.CongestionControl.DROP)

    def resubscribe(self, now: float) -> None:
        """Follow the brain's two-hop set and beacon tiles (only differences are declared)."""
        brain = self.brain
        self.states.update(brain.wanted_state_ids(now))
        self.tiles.update(brain.wanted_tiles())


def run_agents(
    brains: list[AgentBrain],
    swarm: str,
    config: zenoh.Config,
    rate: float,
    time_scale: float = 1.0,
) -> list[Counters]:
    """Zenoh shell around ``brains``: runs until SIGINT/SIGTERM, returns their counters.

    Several brains may share this process and its one Zenoh session (``covswarm agent
    --ids``): one process costs ~80 MB and its own imports, one more brain almost nothing.
    Each brain still has its own AgentLink (publishers, subscriptions), claim and
    liveliness token and talks to the others only through Zenoh, exactly as if it ran
    alone; the brains step one after the other in one loop at ``rate`` Hz of mission time.

    Every id is claimed (protocol.session.claim) before anything is published: an agent for
    an id that is already running refuses to start. A brain's liveliness token (what
    launcher and coordinator wait for) is declared once it hears its own robot, so "every
    agent alive" means "every agent can steer". ``time_scale``: see protocol.session.scaled.
    """
    stop = StopFlag()
    wall_clock = scaled(time.time, time_scale)
    with zenoh.open(config) as session:
        # Tokens must stay referenced: zenoh undeclares a token when it is collected.
        claims: list[zenoh.LivelinessToken] = []
        tokens: dict[int, zenoh.LivelinessToken] = {}
        links: list[AgentLink] = []
        ticker = Ticker(rate, time_scale=time_scale)
        try:
            for brain in brains:
                claims.append(claim_or_refuse(session, swarm, "agent", brain.id))
                links.append(AgentLink(session, swarm, brain))
            while not stop.is_set():
                ticker.wait(stop)
                # The batch starts one brain later every tick: the brains at the end of a
                # long batch step later in the period, and no robot should always be last.
                links.append(links.pop(0))
                for link in links:
                    brain = link.brain
                    # Each brain's own time: the last of a large batch steps tens of ms
                    # after the first, and its neighbours are dead-reckoned to then.
                    now, wall = ticker.now(), wall_clock()
                    link.receive(now, wall)
                    link.send_command(brain.step(now, wall), wall)
                    # A missed deadline: this period's command went out after the period
                    # ended (start-up, while processes are still launching, aside).
                    if brain.running and ticker.now() > ticker.deadline:
                        brain.counters.overruns += 1
                    link.publish(now, wall)
                    link.resubscribe(now)
                    if brain.id not in tokens and brain.pose is not None:
                        alive = protocol.alive_key(swarm, "agent", brain.id)
                        tokens[brain.id] = session.liveliness().declare_token(alive)
                        log.info("agent %d ready in swarm %s", brain.id, swarm)
        finally:
            for link in links:  # stop the robots at once rather than after their timeout
                link.send_command(Decision(0.0, 0.0, "stopped"), wall_clock())
            for token in [*tokens.values(), *claims]:
                token.undeclare()
        for link in links:
            log.info(
                "agent %d stopping: %s, dropped %s, stats %s",
                link.brain.id,
                link.brain.counters,
                link.brain.drops.summary(),
                link.brain.stats(),
            )
        log.info("%d ticks, %d overruns", ticker.ticks, ticker.overruns)
    return [brain.counters for brain in brains]


@click.command("agent")
@click.option("--id", "robot_id", type=click.IntRange(0, protocol.MAX_ID), help="Robot id.")
@click.option("--ids", help="Several brains in this process instead, e.g. 0-9 (one session).")
@click.option(
    "--connect", multiple=True, required=True, help="Router endpoint, e.g. tcp/127.0.0.1:7447."
)
@click.option("--swarm", default="default", show_default=True, help="Swarm (run) name.")
@click.option("--rate", type=click.FloatRange(min=0.5), default=10.0, show_default=True)
@TIME_SCALE_OPTION
@click.option(
    "--kappa",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    help="Gain; default: the kappa broadcast with the domain.",
)
@click.option("--no-feedforward", is_flag=True, help="Drop the dc/dt term (ablation).")
@click.option("--stale-timeout", type=click.FloatRange(min=0.01), default=1.0, show_default=True)
@click.option("--beacon-period", type=click.FloatRange(min=0.05), default=10.0, show_default=True)
@click.option("--beacon-timeout", type=click.FloatRange(min=0.1), default=25.0, show_default=True)
@click.option("--max-tile-radius", type=click.IntRange(1, 10), default=3, show_default=True)
@click.option("--max-extrapolation", type=click.FloatRange(min=0.0), default=1.0, show_default=True)
@click.option("--linger", type=click.FloatRange(min=0.0), default=0.5, show_default=True)
@MAX_CLOCK_SKEW_OPTION
@click.option(
    "--max-wheel-speed",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.8,
    show_default=True,
    help="Rim speed limit (m/s) the commands are saturated to.",
)
@click.option(
    "--drop-poses",
    type=click.FloatRange(0.0, 1.0, max_open=True),
    default=0.0,
    show_default=True,
    help="Fault injection: drop this fraction of received poses.",
)
@click.option(
    "--delay-poses",
    type=click.FloatRange(min=0.0),
    default=0.0,
    show_default=True,
    help="Fault injection: deliver received poses this many s late.",
)
@click.option("--pose-seed", type=int, default=0, show_default=True, help="Seed of the pose drops.")
@SECURE_OPTION
@click.option("--verbose", is_flag=True, help="Log at INFO level.")
def agent_command(
    robot_id: int | None,
    ids: str | None,
    connect: tuple[str, ...],
    swarm: str,
    rate: float,
    time_scale: float,
    kappa: float | None,
    no_feedforward: bool,
    stale_timeout: float,
    beacon_period: float,
    beacon_timeout: float,
    max_tile_radius: int,
    max_extrapolation: float,
    linger: float,
    max_clock_skew: float,
    max_wheel_speed: float,
    drop_poses: float,
    delay_poses: float,
    pose_seed: int,
    secure: Path | None,
    verbose: bool,
) -> None:
    """Run the coverage-control brain of one robot, or of several (local two-hop Voronoi,
    TVD-D1)."""
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING)
    try:
        protocol.check_swarm(swarm)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--swarm") from exc
    robot_ids = id_selection(robot_id, ids)
    config = AgentConfig(
        kappa=kappa,
        feedforward=not no_feedforward,
        stale_timeout=stale_timeout,
        beacon_period=beacon_period,
        beacon_timeout=beacon_timeout,
        max_tile_radius=max_tile_radius,
        max_extrapolation=max_extrapolation,
        linger=linger,
        max_clock_skew=max_clock_skew,
        robot=DiffDrive(max_wheel_speed=max_wheel_speed),
        pose_loss=drop_poses,
        pose_delay=delay_poses,
        pose_seed=pose_seed,
    )
    try:
        zenoh_config = session_config(list(connect), None, "client", secure=secure)
    except ValueError as exc:  # clear endpoints in secured mode, incomplete secure folder
        raise click.UsageError(str(exc)) from exc
    brains = [AgentBrain(i, config) for i in robot_ids]
    run_agents(brains, swarm, zenoh_config, rate, time_scale)
