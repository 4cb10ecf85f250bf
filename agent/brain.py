"""The brain of one agent as a sans-IO state machine: messages and clocks in, actions out.

Feed it raw payloads with :meth:`AgentBrain.receive` (a control period's at once with
:meth:`AgentBrain.receive_all`) and liveliness changes with
:meth:`AgentBrain.on_liveliness`; once per control period :meth:`AgentBrain.tick` returns
everything to do, in order: the wheel command, the AgentState, a beacon when one is due,
the AgentStates and beacon tiles to follow, and the liveliness token to declare once the
agent hears its own robot. No Zenoh, no wall clock of its own: ``now`` arguments are
monotonic seconds (receipt, staleness), ``now_wall`` seconds since the epoch (message
stamps and the commands' timeline), and the step timer is passed in (``clock``). The
shell (:mod:`covswarm.agent.link`) only carries the actions out.

Latency (covswarm.agent.latency): the step controls from its robot's pose *predicted* to
the time of the command (the stamped pose moved along the commands sent since, in exact
arcs), tells its neighbours that same prediction in its AgentState, and dead-reckons
theirs from their stamps (on its own clock within the one-sided bound of each sender's
offset), not from when they arrived; the domain likewise, from its broadcast's stamp and
mission time, and newer means a higher sequence number. Safety (covswarm.tvd.safety): the
velocity is filtered so that this robot's half of every pair's barrier condition holds
against every robot it knows within SAFETY_RADIUS, and against robots it stopped hearing
from (OBSTACLE_MEMORY; a robot whose brain died, for as long as its robot lives). Once it
knows the world (:meth:`AgentBrain.set_world`, from the coordinator's World broadcast),
also against the obstacles and workspace walls within SAFETY_RADIUS, and it refuses a
domain that overlaps an obstacle.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from covswarm import protocol
from covswarm.agent.decoding import Heard, MessageDecoder
from covswarm.agent.faults import InboxItem
from covswarm.agent.latency import HISTORY_SPAN, ClockBound, CommandHistory
from covswarm.agent.metrics import Counters, Percentiles, Rate
from covswarm.agent.neighborhood import (
    DEAD_RECKONING_LIMIT,
    HeardState,
    Neighborhood,
    cell_reach,
    clamp_position,
    tile_radius,
)
from covswarm.protocol.inbound import MAX_CLOCK_SKEW, STAMP_REASONS, DropLog, RateLimit, check_stamp
from covswarm.tvd.control import (
    MAX_AMPLIFICATION,
    AffineField,
    LocalStep,
    LocalView,
    affine_field,
    field_directions,
    local_steps,
)
from covswarm.tvd.density import Density
from covswarm.tvd.drive import (
    KHEPERA_IV,
    SLIDE_AFTER,
    SLIDE_CLEARANCE,
    SLIDE_MIN,
    DiffDrive,
    pass_sides,
    steer_one,
    stopped_beside,
    stopped_dead_one,
    turn_in_place,
    twist_from_wheels,
)
from covswarm.tvd.safety import (
    DEFAULT_GAMMA,
    DEFAULT_MARGIN,
    SAFETY_RADIUS,
    FilterResult,
    barrier_gain,
    body_safe_distance,
    safe_unicycle_velocities,
    safe_velocity,
    unseen_speed_limit,
    wall_distance,
)
from covswarm.world.model import World

DROP_REASONS = (
    *protocol.REASONS,
    *STAMP_REASONS,
    "wrong_id",  # key and message disagree about the robot id, or a malformed key
    "bad_domain",  # valid message, invalid polygon (non-convex, self-intersecting, ...)
    "old_domain",  # older than the domain already held (by sequence number)
    "domain_outside_workspace",  # a vertex outside the workspace the agent knows
    "domain_seq_jump",  # sequence number implausibly far ahead of the held domain's
    "domain_in_obstacle",  # overlaps an obstacle of the world the agent knows
    "bad_world",  # valid message, invalid geometry (a non-convex obstacle, ...)
    "old_world",  # older than the world already held (by sequence number)
    "world_seq_jump",  # sequence number implausibly far ahead of the held world's
)
# Largest fraction of the gap to the centroid one control period may close (sampled_gain).
MAX_STEP_FRACTION = 0.8
# s: the longest control period a step is computed for (its gain, barrier and the time its
# command must cover): a brain stepped less often (a stalled process) steps as if this were
# its period (at the 1 s command timeout of an overloaded run, MAX_DUTY times its hold).
MAX_PERIOD = 4.0
# The largest factor a step's velocity is scaled by for a command that stops early (period
# over hold, AgentBrain._finish): a robot driven for under a quarter of each period is
# compensated no further (its wheels saturate first at such speeds).
MAX_DUTY = 4.0
# rad: a command that, held for as long as its robot may drive it (the robot's command
# timeout: the next turn may come that late), would turn the robot by more than this turns
# it in place instead, at the same rate; it drives from the next step on (AgentBrain.
# _wheels). The safety filter bounds the speed along the heading at the step; a command
# held ~1 s that also turns the robot (up to the whole angle to its aim, covswarm.tvd.drive.
# steer) moves its centre on an arc those rows do not bound. covswarm.deploy.netsim, brains
# stepped every 0.45-1.15 s, robots stopping 1 s after a command, S 8x slower, the start
# held for coordinator.monitor.START_ROUNDS (30 Nov 2026): circle-1000 seed 3, a robot
# 0.140 m from a neighbour it knew exactly, backing at 0.034 m/s while turning 1.2 rad,
# swept to 0.128 m; circle-400 seed 2, backing at 0.029 m/s and turning 1.0 rad, to
# 0.1397 m. With this rule neither (0.140 and 0.1403 m; 22-66 steps turned in place in
# 6000-15000 mission steps); mean e_a over the first 5 s 0.426 m against 0.418 m without
# the rule (seed 3). Judged over the expected hold rather than the timeout, 1 rad left the
# 0.1397 m pair (seed 2: 3 steps turned, that mean 0.298 m against 0.300 m), and 0.5 rad
# removed it but turned 111 steps and raised that mean to 0.316 m.
ARC_TURN = 1.0
# s: the rule above applies only to commands expected to be held longer than this (brains
# stepped at ~3 Hz or slower). Without this bound (the rule judged over the hold) circle-100
# at 10 Hz in netsim, seed 0, turned in place twice and ended 10 s at e_a 0.0074 m against
# 0.0057 m; with it, seeds 0-2 at 10 Hz are unchanged to the bit.
ARC_HOLD = 0.3
# Past ARC_HOLD, a command that does not turn its robot in place has its turn capped over
# the time the robot may drive it (AgentBrain.may_drive: its command timeout, unless our
# process stops it earlier) rather than over the expected hold (AgentBrain._wheels): the
# expected hold is the last gap between our turns, the next may come later, and the robot
# drives the command until then or its timeout. Capped for the hold, the turn carried the
# robot past its aim on an arc the filter's rows, taken along the heading at the step, do
# not bound: deploy.netsim circle-400 seed 1 (scripts/overloaded_start.py), robot 396
# filtered for a 0.549 s hold, its next turn 1.137 s later, swung 0.25 rad past its aim
# towards robot 46 (0.1386 m). Whether it turns in place is still judged on the turn sized
# for the hold: judged on the turn capped over the timeout (commit 701f322, reverted),
# fewer robots turned in place and drove arcs instead, and circle-1000 seed 3 had a pair
# at 0.126 m.
# Seconds between control steps while the mission is not running (neighbour bookkeeping).
IDLE_STEP_PERIOD = 1.0
# s: an early beacon (a teammate appeared) follows the last one after at least this long, so
# a whole team starting at once costs each agent one beacon per second, not per tick.
BEACON_MIN_PERIOD = 1.0
# m: a robot that drives through S rather than with it (AgentBrain._driving_through: its
# cell empty, outside S on its way in, or faster than S moves) beacons whenever it has
# moved this far since its last beacon. A routine beacon every 10 s left such a robot where
# it started in everyone's tables, and nobody followed its AgentStates: robots driving into
# S side by side at the wheels' top speed saw each other there and collided (20 robots
# deployed from a 6 m square into a 1 m S at 10 Hz: two seeds of three, closest 0.110 and
# 0.052 m; scripts/approach_safety.py). It is the position error the speed limit allows
# for (covswarm.tvd.safety.unseen_speed_limit): at 0.08 m that limit is 0.87 m/s at 10 Hz,
# above the wheels' top speed with the period's jitter, so a 10 Hz team without a command
# latency is never slowed by it.
BEACON_MOVE = 0.08
# m/s: a robot driving this much faster than S's fastest point moves among its teammates
# rather than with them (converging on its centroid, a straggler catching up) and beacons
# as it moves (AgentBrain._driving_through); riding S it does not, which would cost a team
# moving at 0.19 m/s a beacon per robot every 0.4 s.
BEACON_SLACK = 0.1
STATS_PERIOD = 1.0  # s between two AgentStates that carry the stats (monitors only read them)
# s: the least time between two AgentStates (AgentConfig.state_period), and between two
# choices of the AgentStates and beacon tiles to follow (AgentBrain.exchange_due). At 10 Hz
# or slower every control step has both; a faster control loop keeps its neighbours' news
# at ~10 Hz, dead-reckoned in between with the velocity each carries. At 30 Hz an AgentState
# per step was two thirds of what each brain received and most of what a packed process
# decoded: 100 robots at 30 Hz then sent 11-12 % of their commands after their period on
# two cores (27 Nov 2026); the control loop itself still runs at the asked rate on its own
# pose.
STATE_PERIOD = 0.1
# s: the largest age a neighbour's AgentState is dead-reckoned over.
MAX_PREDICTION = 1.0
# s: the oldest our own robot's pose (by its stamp, on our clock) may be for a step to
# steer from it: the span of the command history, which predicts the pose exactly over it
# (covswarm.agent.latency). An older pose is not used as if fresh: the robot stops
# (AgentBrain.begin, counted as ``pose_too_old``). Its receipt time does not tell: a pose
# received late but stamped 1-1.5 s ago passes the stamp check (stale timeout plus clock
# skew) and was steered from unpredicted when the prediction stopped at 1 s; the heading
# loop over-steered, and in covswarm.deploy.netsim the 10-robot passage with poses 1.1 s
# late went to e_a 13 m (0.11 m predicted, 28 Nov 2026).
POSE_HORIZON = HISTORY_SPAN
# How long a neighbour's AgentState stays usable when this brain's turns come late
# (AgentBrain.pace): for STALE_TURNS times the time between two of our turns, at least
# stale_timeout and at most STALE_STRETCH times it. A state that old still says where its
# robot is: a robot stops at its command timeout after its brain's last step, and a dead
# brain's token goes at once. At 4 a host that stepped each brain every ~5 s (1000 robots
# on two slow cores, 0.2 Hz held, 30 Nov 2026 18:08 UTC) refused its neighbours' states as
# too old on arrival (4.5 s with the clock skew): every cell swelled over its neighbours'
# and e_a rose to 13 m. covswarm.deploy.netsim, circle-400, brains every 4-6 s, S at 0.02 of
# its speed, 60 s: e_a at the end 0.138 m at 4 (2460 states refused), 0.083 m at 10 (none);
# gaps up to 2 s (STALE_TURNS gaps within 4 timeouts) are judged as before.
STALE_TURNS = 2.0
STALE_STRETCH = 10.0
# s: a domain with a sequence number not above the one held is dropped as a late duplicate,
# unless the held one's coordinator has been silent this long (10 broadcast periods): then
# it is a restarted coordinator, whose numbers start again.
DOMAIN_RESTART_SILENCE = 0.5
# A domain numbered more than this above the held one, while the held one's coordinator
# still talks (within DOMAIN_RESTART_SILENCE), is refused: the coordinator numbers its
# broadcasts one by one at 20 Hz, so a real one advances by ~10 in that time. Without this
# bound one forged Domain numbered 2^62 made every later real one "old" for as long as the
# forger repeated it (issue 21: the team pulled 0.75 m in 8 s). The real coordinator's
# stream stays followed; a forger must now track the real numbers (open mode cannot stop
# that: only the access control of --secure does).
MAX_DOMAIN_SEQ_JUMP = 1000
# m: a domain vertex this far outside the workspace is still inside: the World message rounds
# the workspace inward to the millimetre (covswarm.world.wire), and the coordinator lets S
# leave it by 2e-4 m at most (covswarm.world.sweep).
WORKSPACE_SLACK = 2e-3
# m: a domain that reaches deeper than this into an obstacle is refused. A depth, not an
# area: the wire rounds obstacles outward to the millimetre (up to sqrt(2) mm,
# covswarm.world.wire) and the coordinator lets S come within 1e-4 m of one
# (covswarm.world.sweep), so a legitimate S may overlap the agent's copy by a 1.5 mm sliver
# along a whole edge, and more than a few square millimetres.
DOMAIN_OBSTACLE_SLACK = 2e-3
# s: the coordinator repeats its World every second (late joiners); a held world whose
# sender has been silent this long may be replaced by a lower sequence number (a restarted
# coordinator). A World is taken up to WORLD_MAX_AGE s after its stamp: it is static, and
# one lost repeat must not leave a joiner without it.
WORLD_RESTART_SILENCE = 5.0
WORLD_MAX_AGE = 10.0
# The decay rate of the obstacle and wall rows, as a fraction of the pairs' (barrier_gain's
# 1 / period at 10 Hz). At the full rate a robot may close the whole gap to the wall's reach
# in one period, so any command latency overshoots it: closed loop with an ideal unicycle
# from four starts pulled into a block (tests/test_agent_world.py), the least clearance of
# the body was 0.090 / 0.074 / 0.070 / 0.046 m with a command acting 0 / 0-20 / 0-40 /
# 0-60 ms late (0.07 m is contact). At half, a period closes half the gap: 0.090 / 0.090 /
# 0.089 / 0.085 m, and a command up to a period late still stops short. Robots near a wall
# approach it more slowly; elsewhere nothing changes.
WALL_GAMMA_FRACTION = 0.5
# Unconfirmed beacon-only robots within SAFETY_RADIUS whose AgentStates are followed, the
# nearest first: more robots than this cannot stand that close around one (hexagonal
# packing at the safe distance gives 6 per ring), so more are forgeries.
MAX_UNCONFIRMED_FOLLOWED = 8
# s: a robot we stopped hearing from (frozen brain, stopped robot) stays an obstacle at its
# last known position for the safety filter this long after it left the coverage step; one
# whose agent's token is gone while its robot's is not, for as long as that lasts: a robot
# without a brain stands where its command timeout stopped it, and a static S's neighbours
# drove into it once they forgot it (AgentBrain._still_there).
OBSTACLE_MEMORY = 30.0
# s: the oldest beacon of a robot known only from beacons that the safety filter and the
# local diagram take as a robot there (AgentBrain._safety_inputs, Neighborhood.relevant),
# while its AgentState is awaited. A robot driving through S beacons every
# BEACON_MOVE (0.08 m) of its move: this spans its beacons from 0.16 m/s up. One riding S
# beacons every beacon_period (10 s) and is then up to ~2 m on: its old spot is a phantom
# at rest, which the team behind it ran into. Such a robot is followed (near_ids) and
# enters the filter with its AgentState.
BEACON_TRUST = 0.5
# The local diagram also takes a beacon heard since the brain's previous view of its
# neighbours as a robot there (diagram_trust): news it has not used yet. A brain stepped
# once a second before the mission (or in turn in an overloaded process) otherwise never
# met a neighbour beyond the safety filter's reach known from beacons alone: its beacons
# came once a second, phase-locked to our steps ~0.9 s before each, older than BEACON_TRUST
# at every view; it named no neighbour, its diagram giving it all of S, when the mission
# started (deploy.netsim, passage, six robots, brains 0 and 3 dead: robot 1). A
# beacon's age counts from the turn that took it off the bus, so it is at most the time
# between two views (1.6 s for a brain stepped at 1.25 Hz before the mission, which views
# every other turn): a robot riding S is then ~0.3 m past its beacon, not the ~2 m of the
# beacon_period that BEACON_TRUST keeps out.
# m: the near-identity mapping's projection distance the agents use. The heading loop it
# closes has gain |u| / l (1/s); with a residual, uncompensated latency tau it is stable only
# while tau |u| / l < pi / 2. Measured (scripts/projection_distance.py: deploy.netsim,
# passage, 10 robots, prediction on), e_a's second-half mean with 0 / 0.1 / 0.2 / 0.3 s of
# command latency the agents do not know about: 0.0085 / 0.0091 / 15.3 / 10.9 m at
# l = 0.03 m, 0.0096 / 0.0103 / 0.0122 / 11.7 m at 0.05 m. 0.05 m doubles the latency the
# loop tolerates beyond what the prediction removes, for ~0.001 m of e_a.
AGENT_PROJECTION_DISTANCE = 0.05


@dataclass(frozen=True)
class AgentConfig:
    """Tunables of one agent; times in seconds, distances in metres."""

    kappa: float | None = None  # None: use the kappa broadcast with the domain
    feedforward: bool = True
    law: str = "da"  # covswarm.tvd.control.local_step's: "da" (default) or "d1" (the paper's)
    stale_timeout: float = 1.0
    state_period: float = STATE_PERIOD  # s, see STATE_PERIOD; 0: an AgentState every step
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
    # Latency compensation (covswarm.agent.latency): predict the pose to the command's time.
    # cmd_timeout: the robot's (it stops that long after a command); command_latency: known
    # time from a command's stamp to the wheels acting on it.
    prediction: bool = True
    cmd_timeout: float = 0.5
    # The most a step's velocity is sped up for a command that times out before the next
    # step (MAX_DUTY; 1: not at all, the robot covers hold / period of each move).
    max_duty: float = MAX_DUTY
    command_latency: float = 0.0
    projection_distance: float = AGENT_PROJECTION_DISTANCE
    # Collision avoidance (covswarm.tvd.safety), on the robots' centres.
    safety: bool = True
    safety_margin: float = DEFAULT_MARGIN
    safety_gamma: float = DEFAULT_GAMMA
    # (xmin, xmax, ymin, ymax) m that every domain must lie in (the scenario's workspace;
    # None: not known, no check). Also settable later: AgentBrain.set_workspace.
    workspace: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class Decision:
    """Outcome of one control step: wheel speeds and why."""

    left: float
    right: float
    # "running", "aligning" (turning in place before S starts), "aligned" (facing S's start
    # at the end of a deploy hold) or why it holds still
    reason: str
    velocity: tuple[float, float] = (0.0, 0.0)  # m/s, the control law's (after the filter)
    # m/s: what the (saturated) wheels give the robot's centre, v (cos th, sin th)
    achieved: tuple[float, float] = (0.0, 0.0)


def local_step_of(view: LocalView, config: AgentConfig) -> LocalStep | Exception:
    """The local step of one view by ``config``'s law, or what it raised (for
    AgentBrain.conclude to count: one bad view stops its own robot only)."""
    try:
        return local_steps([view], config.feedforward, MAX_AMPLIFICATION, config.law)[0]
    except Exception as exc:  # noqa: BLE001 -- handed to conclude, which counts it
        return exc


# The safety filter's answer for one robot: velocity [vx, vy] m/s, rows tight, relaxed.
SafeVelocity = tuple[list[float], int, bool]


@dataclass(slots=True)
class Filtering:
    """A control step whose velocity awaits the safety filter (AgentBrain.conclude): the
    inputs of covswarm.tvd.safety.safe_unicycle_velocities for this robot. nominal: (2,)
    m/s; velocity: its last achieved one, (vx, vy) m/s; near: (m, 4) the robots near it (x, y m,
    vx, vy m/s); obstacles: the world's convex polygons near it; workspace: its box or
    None; distances m, gains 1/s; overrun: s the command may be driven when that is longer
    than the drive gamma is sampled for (0: not), and near_gamma: each near row's own gamma
    (None: gamma), both for filter_all's second pass; spent: s of the step timer so far, set
    by conclude once the inputs are built (not frozen: copying it with dataclasses.replace
    cost ~3 us)."""

    begun: Begun
    nominal: np.ndarray
    near: np.ndarray
    safe_distance: float
    gamma: float
    velocity: tuple[float, float]
    obstacles: list[np.ndarray]
    workspace: tuple[float, float, float, float] | None
    obstacle_distance: float
    obstacle_gamma: float
    overrun: float = 0.0
    near_gamma: np.ndarray | None = None  # (m,) 1/s
    spent: float = 0.0


def filter_all(filterings: list[Filtering]) -> list[SafeVelocity]:
    """The safety filter of every step of ``filterings`` in one batch
    (covswarm.tvd.safety.safe_unicycle_velocities: each equal to its own filter).

    A step whose command may be driven longer than its barrier's gain is sampled for
    (Filtering.overrun) is filtered again with the gain sampled over that time on the rows
    of the robots its first answer, so driven, would bring it within the safe distance of
    (:func:`overrun_rows`); its other rows keep their gain. Sampled for the expected hold T
    (gamma T = 1), a row lets its pair use up the whole margin in T, and a command driven on
    to the timeout goes on closing: deploy.netsim circle-1000 seed 3 with the turn capped
    over the timeout (ARC_HOLD; scripts/overloaded_start.py), robot 975, filtered for a
    0.478 s hold and not held back, drove 0.1 m/s towards robot 894, 0.220 m away, and its
    next turn came 1.061 s later: 0.139 m. Sampled over the timeout on every row instead,
    e_a's mean rose 10-24 mm (circle-400, seeds 0-3); on every row whose pair was closing,
    7-20 mm (45 300-45 600 rows a run); on these rows (230-330 a run), 0.1 mm less on
    average (docs/scaling.md, 1 Dec 2026)."""
    safe = _filter(filterings)
    again = []
    for k, f in enumerate(filterings):
        if f.overrun > 0.0 and len(f.near):
            risk = overrun_rows(f, safe[k][0])
            if risk.any():
                f.near_gamma = np.where(risk, barrier_gain(f.gamma, f.overrun), f.gamma)
                again.append(k)
    if again:
        for k, result in zip(again, _filter([filterings[k] for k in again]), strict=True):
            safe[k] = result
    return safe


def overrun_rows(filtering: Filtering, velocity: Sequence[float]) -> np.ndarray:
    """(m,) bool: the near robots ``filtering``'s robot would come within the safe distance
    of, driving the forward speed of ``velocity`` (m/s, the filter's answer) for
    ``filtering.overrun`` s while they drive their last known velocities: along its heading,
    or along its aim (the command turns it towards its aim, at most to it), the nearer."""
    x, y, heading = filtering.begun.pose
    e = np.array([math.cos(heading), math.sin(heading)])
    forward = float(e @ np.asarray(velocity, dtype=float))
    ways = [e]
    aim = np.asarray(filtering.nominal, dtype=float)
    norm = math.hypot(aim[0], aim[1])
    if norm > 0.0:
        ways.append(aim / norm)
    offset = np.array([x, y]) - filtering.near[:, :2]  # from each of them to us
    apart = np.einsum("ij,ij->i", offset, offset) >= filtering.safe_distance**2
    risk = np.zeros(len(offset), dtype=bool)
    for way in ways:
        w = forward * way - filtering.near[:, 2:4]  # our velocity relative to theirs
        ww = np.einsum("ij,ij->i", w, w)
        closing = -np.einsum("ij,ij->i", offset, w)
        s = np.clip(np.divide(closing, ww, out=np.zeros_like(ww), where=ww > 0.0), 0.0, None)
        s = np.minimum(s, filtering.overrun)  # s of the drive at which they are nearest
        reach = offset + s[:, None] * w
        risk |= np.einsum("ij,ij->i", reach, reach) < filtering.safe_distance**2
    return risk & apart  # (a pair already inside: a smaller gain would ask less of it)


def _filter(filterings: list[Filtering]) -> list[SafeVelocity]:
    poses = np.array([f.begun.pose for f in filterings])  # (R, 3): x, y, heading
    # (R, 4): safe distance, gamma, obstacle distance, obstacle gamma
    scalars = np.array(
        [(f.safe_distance, f.gamma, f.obstacle_distance, f.obstacle_gamma) for f in filterings]
    )
    near_gammas = None
    if any(f.near_gamma is not None for f in filterings):
        near_gammas = [f.near_gamma for f in filterings]
    velocities, active, relaxed = safe_unicycle_velocities(
        poses[:, :2],
        np.array([f.nominal for f in filterings]),
        poses[:, 2],
        [f.near[:, :2] for f in filterings],
        scalars[:, 0],
        scalars[:, 1],
        velocities=np.array([f.velocity for f in filterings]),
        neighbor_velocities=[f.near[:, 2:] for f in filterings],
        obstacles=[f.obstacles for f in filterings],
        workspace=[f.workspace for f in filterings],
        obstacle_distance=scalars[:, 2],
        reach=SAFETY_RADIUS,
        obstacle_gamma=scalars[:, 3],
        neighbor_gammas=near_gammas,
    )
    return list(zip(velocities.tolist(), active.tolist(), relaxed.tolist(), strict=True))


def slide_velocity(filtering: Filtering, clearance: float = SLIDE_CLEARANCE) -> FilterResult:
    """``filtering``'s slide: its step filtered for a robot that could move sideways, with
    the safe distances ``clearance`` m larger (covswarm.tvd.safety.safe_velocity without a
    heading: (2,) m/s, rows tight, relaxed); where a robot stopped dead turns to go
    (covswarm.tvd.drive.steer)."""
    x, y, _ = filtering.begun.pose
    return safe_velocity(
        (x, y),
        filtering.nominal,
        filtering.near[:, :2],
        filtering.safe_distance + clearance,
        filtering.gamma,
        velocity=np.asarray(filtering.velocity, dtype=float),
        neighbor_velocities=filtering.near[:, 2:],
        obstacles=filtering.obstacles,
        workspace=filtering.workspace,
        obstacle_distance=filtering.obstacle_distance + clearance,
        reach=SAFETY_RADIUS,
        obstacle_gamma=filtering.obstacle_gamma,
        neighbor_gammas=filtering.near_gamma,
    )


def slide_of(
    filtering: Filtering, side: float, along: np.ndarray | None = None
) -> np.ndarray | None:
    """(2,) m/s: the slide ``filtering``'s robot takes (covswarm.tvd.drive.steer): its
    slide (:func:`slide_velocity`), or, where that is shorter than SLIDE_MIN of its aim (a
    still robot dead ahead), the slide of its aim turned a quarter to ``side`` (+1 left, -1
    right); None where neither is that long (boxed in). How long is judged at the safe
    distance itself (``along``: that slide of its aim, when already known): within
    SLIDE_CLEARANCE of it, the slide of a robot boxed in leads away from every row, and it
    turned round to back out."""
    ax, ay = float(filtering.nominal[0]), float(filtering.nominal[1])
    least = SLIDE_MIN * math.hypot(ax, ay)
    for nominal in (None, (-side * ay, side * ax)):
        aimed = filtering if nominal is None else replace(filtering, nominal=np.array(nominal))
        if nominal is not None or along is None:
            along = slide_velocity(aimed, 0.0).velocity
        if math.hypot(along[0], along[1]) >= least:
            return slide_velocity(aimed).velocity
    return None


def filter_one(filtering: Filtering) -> SafeVelocity | Exception:
    """One step's safety filter, or what it raised (for AgentBrain.drive to count)."""
    try:
        return filter_all([filtering])[0]
    except Exception as exc:  # noqa: BLE001 -- handed to drive, which counts it
        return exc


@dataclass(frozen=True, slots=True)
class Begun:
    """A control step up to its local step (AgentBrain.begin): the local view to step,
    the robot's predicted pose (x m, y m, heading rad) it was built from, the step's
    clocks, and the s of the step timer spent so far."""

    view: LocalView
    pose: tuple[float, float, float]
    now: float
    now_wall: float
    spent: float


# --- actions: what a tick asks the shell to do ---------------------------------------


@dataclass(frozen=True, slots=True)
class SendCommand:
    command: protocol.WheelCommand


@dataclass(frozen=True, slots=True)
class PublishState:
    state: protocol.AgentState


@dataclass(frozen=True, slots=True)
class PublishBeacon:
    tile: tuple[int, int]
    beacon: protocol.Beacon


@dataclass(frozen=True, slots=True)
class FollowStates:
    """Be subscribed to exactly these robots' AgentStates."""

    ids: frozenset[int]


@dataclass(frozen=True, slots=True)
class FollowTiles:
    """Be subscribed to exactly these beacon tiles."""

    tiles: frozenset[tuple[int, int]]


@dataclass(frozen=True, slots=True)
class FollowStranded:
    """Be subscribed to exactly these robots' poses (AgentBrain.stranded)."""

    ids: frozenset[int]


@dataclass(frozen=True)
class DeclareAlive:
    """Declare this agent's liveliness token: it hears its robot and can steer it."""


Action = (
    SendCommand
    | PublishState
    | PublishBeacon
    | FollowStates
    | FollowTiles
    | FollowStranded
    | DeclareAlive
)


def _ms(seconds: float) -> float:
    """Seconds as rounded milliseconds for the stats (NaN, before any sample, as 0)."""
    return round(seconds * 1e3, 2) if math.isfinite(seconds) else 0.0


@functools.lru_cache(maxsize=1024)
def _tile_block(tx: int, ty: int, r: int) -> frozenset[tuple[int, int]]:
    """The (2r+1)^2 tiles around tile (tx, ty): one object per block for all brains (a
    brain's block rarely changes between two ticks, and a pack compares it by identity
    first, covswarm.agent.pack.Pack.follow)."""
    return frozenset((tx + i, ty + j) for i in range(-r, r + 1) for j in range(-r, r + 1))


def diagram_trust(now: float, last_view: float | None) -> float:
    """s: the oldest beacon of a robot known only from beacons, its AgentState awaited, that
    the local diagram takes as a robot there at ``now`` (Neighborhood.relevant's ``trust``):
    BEACON_TRUST, or every beacon heard since the brain's previous view at ``last_view``
    (None: none yet)."""
    if last_view is None:
        return BEACON_TRUST
    return max(BEACON_TRUST, now - last_view)


def sampled_gain(kappa: float, period: float) -> float:
    """The gain to hold over one control period of ``period`` s in place of ``kappa`` (1/s).

    Holding kappa (c - p) for a period T moves the robot kappa T of its gap to the
    centroid: past 1 it overshoots, past 2 it diverges (seen: kappa 8 on a starved agent
    at 4 Hz). The gain is capped so that one period never covers more than
    MAX_STEP_FRACTION of the gap; at the rates the agents are meant to run (kappa T well
    below it) kappa is used unchanged.
    """
    if period <= 0.0:
        return kappa
    return min(kappa, MAX_STEP_FRACTION / period)


class AgentBrain:
    """Decision logic of one agent: feed it messages, ask it for actions. No I/O."""

    def __init__(
        self,
        robot_id: int,
        config: AgentConfig | None = None,
        decoder: MessageDecoder | None = None,
        clock: Callable[[], float] = time.perf_counter,
        log: logging.Logger | None = None,
    ) -> None:
        self.id = protocol.check_id(robot_id)
        self.config = config = config or AgentConfig()
        if not config.max_duty >= 1.0:
            raise ValueError(f"max_duty must be >= 1, got {config.max_duty!r}")
        if not 0.0 <= config.state_period < config.stale_timeout:
            raise ValueError(
                f"state_period {config.state_period} s must be >= 0 and below the stale "
                f"timeout ({config.stale_timeout} s): neighbours would drop us in between"
            )
        self.decoder = decoder or MessageDecoder()
        self._clock = clock  # only times the control step (stats)
        self.log = log or logging.getLogger("covswarm.agent")
        self.pose: protocol.Pose | None = None
        self.pose_received = -math.inf
        self.pose_taken = -math.inf  # our wall time at which self.pose was taken
        self.history = CommandHistory(config.robot, config.cmd_timeout)
        # m: what the safety filter keeps from other robots and from walls (config's, fixed)
        self._safe_distance = body_safe_distance(config.robot.body_diameter, config.safety_margin)
        self._wall_distance = wall_distance(config.robot.body_diameter, config.safety_margin)
        self.robot_clock = ClockBound()  # our clock minus our robot's, bounded from above
        self.peer_clocks: dict[int, ClockBound] = {}  # the same for each neighbour's agent
        # Our clock minus the coordinator's, bounded from above: the held domain's age.
        self.coordinator_clock = ClockBound()
        self._domain_received = -math.inf
        # id -> (x, y, when it vanished, monotonic): robots heard first-hand within
        # SAFETY_RADIUS that then stopped being candidates at all (a frozen brain, a stopped
        # robot): they stay where they were, and the safety filter steers around them.
        self.obstacles: dict[int, tuple[float, float, float]] = {}
        # Whether our robot aims at its slide (covswarm.tvd.drive.steer), and the side it
        # passes on (slide_of): since the safety filter stopped it dead, until the rows no
        # longer bend its aim (_safety_inputs); None: not.
        self._slide_side: float | None = None
        self._stopped_since: float | None = None  # since when the filter stops it dead
        # Stranded robots (:meth:`stranded`): id -> when we first saw it without its agent's
        # token (monotonic); those whose poses we follow; and their last pose (x, y m, when).
        self._orphaned: dict[int, float] = {}
        self._stranded_followed: frozenset[int] = frozenset()
        self._stranded: dict[int, tuple[float, float, float]] = {}
        # The last step's robots within SAFETY_RADIUS: those heard first-hand, and every
        # one's id and row (x, y, vx, vy) of the neighbourhood's table, in table order.
        self._near_first_hand: set[int] = set()
        self._near_last: tuple[list[int], np.ndarray] = ([], np.zeros((0, 4)))
        self.domain: protocol.Domain | None = None
        self.density: Density | None = None  # the domain's density, validated (None: uniform)
        self.neighborhood = Neighborhood(
            self.id, config.stale_timeout, config.beacon_timeout, config.linger
        )
        self.radius = 1
        self.reach: float | None = None  # cell_reach of our last non-empty cell
        self.counters = Counters()
        # s: how old a received message may be, by kind (beacons and worlds: their own)
        self._max_age = {
            **dict.fromkeys(_HANDLERS, config.stale_timeout),
            "beacon": config.beacon_timeout,
            "world": WORLD_MAX_AGE,
        }
        self.drops = DropLog(self.log, f"agent {self.id}", DROP_REASONS)
        self._failure_log = RateLimit()
        self._local = 0  # robots in the last local diagram besides ourselves
        self._last_beacon = -math.inf
        self._beacon_at: tuple[float, float] | None = None  # (x, y) m of our last beacon
        # An early beacon is owed: a teammate appeared, or a neighbour does not know us.
        self._beacon_due = False
        self._last_control: float | None = None  # wall time of the last control step
        # s between this brain's turns (pace; 0: not told): the period the first mission
        # step's command will be held for, before a mission step has measured one.
        self._gap = 0.0
        self._period = 1.0  # s, the last control period (at most MAX_PERIOD)
        self._hold = 0.0  # s, how long the coming command is expected to hold (see _view)
        # s after a step at which our process stops the robot when no newer command came
        # (covswarm.agent.pack.Pack.hold_after, or the command's own hold when longer:
        # runs_on_for); None: nobody does, and the robot drives each command until the next
        # or its timeout (may_drive).
        self.stop_after: float | None = None
        self._was_running = False  # whether the last step that reached _view was a mission's
        self._last_idle_step = -math.inf
        self._last_view: float | None = None  # ``now`` of the last view (diagram_trust)
        # The domain whose start velocities were fitted last, and their field (_standing).
        self._start_field: tuple[protocol.Domain, AffineField] | None = None
        self._next_stats = -math.inf
        self._last_exchange = -math.inf  # ``now`` of the last neighbour exchange (exchange_due)
        self._last_actions = -math.inf  # ``now`` of the last period's actions (exchange_due)
        self._alive = False
        self.velocity: tuple[float, float] = (0.0, 0.0)  # last achieved (saturated) command, m/s
        self._seq = 0
        self._step_us = Percentiles()
        self._pose_age_ms = Percentiles()
        self.safety_active = 0  # mission steps on which the filter changed the velocity
        self.safety_relaxed = 0  # ... on which its rows could not all hold (see safe_velocity)
        self.wheel_max = 0.0  # m/s, largest rim speed commanded during the mission
        self.saturated_s = 0.0  # s of mission under a saturated command
        self._saturated = False
        self._last_running_command: float | None = None
        self._step_rate = Rate()
        self._rx_rate = Rate()
        self._rates = (0.0, 0.0)
        self.workspace: tuple[float, float, float, float] | None = None
        if config.workspace is not None:
            self.set_workspace(config.workspace)
        # The arena (covswarm.world.model): None until a World broadcast (or set_world).
        self.world: World | None = None
        self._world_message: protocol.World | None = None  # the message it came from
        self._world_received = -math.inf

    def set_workspace(self, box: tuple[float, float, float, float] | None) -> None:
        """The box (xmin, xmax, ymin, ymax) m every domain must lie in from now on (None:
        none): from the scenario (AgentConfig.workspace) or a world broadcast. A held
        domain outside it is dropped too. ValueError for a box that is not finite with
        xmin < xmax, ymin < ymax."""
        if box is not None:
            xmin, xmax, ymin, ymax = (float(v) for v in box)
            if not (math.isfinite(xmin + xmax + ymin + ymax) and xmin < xmax and ymin < ymax):
                raise ValueError(f"workspace {box}: need finite xmin < xmax, ymin < ymax")
            box = (xmin, xmax, ymin, ymax)
        self.workspace = box
        if self.domain is not None and not self._inside_workspace(self.domain):
            self.drops.drop("domain_outside_workspace", "held domain outside the new workspace")
            self.domain = self.density = None

    def set_world(self, world: World | None) -> None:
        """The arena from now on (None: none known, the filter sees robots only): its
        obstacles and workspace walls within SAFETY_RADIUS enter the safety filter every
        step, a domain overlapping an obstacle is refused, and its workspace (if it has one)
        replaces the one held (:meth:`set_workspace`). A held domain that now overlaps an
        obstacle or leaves the workspace is dropped and counted."""
        if world is not None and not isinstance(world, World):
            raise TypeError(f"world must be a covswarm.world.model.World, got {world!r}")
        self.world = world
        if world is not None and world.workspace is not None:
            self.set_workspace(world.workspace)
        if self.domain is not None and self._in_obstacle(self.domain):
            self.drops.drop("domain_in_obstacle", "held domain overlaps the new world's obstacles")
            self.domain = self.density = None

    def _follows_sequence(self, kind: str, seq: int, held: int) -> bool:
        """Whether a ``kind`` ("domain" or "world") numbered ``seq`` may replace the held
        one numbered ``held`` whose sender still talks: not if it is not newer
        ("old_<kind>") or jumps more than MAX_DOMAIN_SEQ_JUMP ahead ("<kind>_seq_jump");
        each dropped and counted."""
        if seq <= held:
            self.drops.drop(f"old_{kind}", f"{kind} seq {seq} <= {held}")
            return False
        if seq - held > MAX_DOMAIN_SEQ_JUMP:
            self.drops.drop(f"{kind}_seq_jump", f"{kind} seq {seq} jumps from {held}")
            return False
        return True

    def on_world(self, message: protocol.World, now: float) -> bool:
        """Hold a newer World (the coordinator's, repeated every second) and steer by it
        (:meth:`set_world`). A repeat of the held one only refreshes it. Doubted like a
        domain: a lower or equal sequence number for a different world while the held one's
        sender still talks (within WORLD_RESTART_SILENCE) is "old_world", one more than
        MAX_DOMAIN_SEQ_JUMP above it "world_seq_jump", geometry the model refuses
        "bad_world"; each dropped and counted."""
        held = self._world_message
        if held is not None and message.same_world(held):
            self._world_received = now
            return True
        if held is not None and now - self._world_received < WORLD_RESTART_SILENCE:
            if not self._follows_sequence("world", message.seq, held.seq):
                return False
        try:
            world = self.decoder.world_model(message)
        except ValueError as exc:
            self.drops.drop("bad_world", f"world: {exc}")
            return False
        self.set_world(world)
        self._world_message, self._world_received = message, now
        return True

    def _in_obstacle(self, domain: protocol.Domain) -> bool:
        """Whether ``domain`` (a valid convex polygon) overlaps one of the world's obstacles
        deeper than DOMAIN_OBSTACLE_SLACK m (False without a world)."""
        if self.world is None or not self.world.obstacles:
            return False
        return self.decoder.domain_penetration(domain, self.world) > DOMAIN_OBSTACLE_SLACK

    def _inside_workspace(self, domain: protocol.Domain) -> bool:
        """Whether every vertex of ``domain`` lies in the workspace (True if none known)."""
        if self.workspace is None:
            return True
        xmin, xmax, ymin, ymax = self.workspace
        eps = WORKSPACE_SLACK
        return all(
            xmin - eps <= x <= xmax + eps and ymin - eps <= y <= ymax + eps
            for x, y in domain.vertices
        )

    # --- input -------------------------------------------------------------------------

    def receive(
        self, kind: str, payload: bytes, now: float, now_wall: float, key_id: int | None = None
    ) -> bool:
        """Decode, check and apply a raw payload of ``kind`` ("pose" | "state" | "beacon" |
        "domain" | "world"); ``key_id`` is the id in the key it arrived on. False if
        dropped."""
        return self.receive_all(((kind, key_id, payload),), now, now_wall) == 1

    def receive_all(self, items: Sequence[InboxItem], now: float, now_wall: float) -> int:
        """:meth:`receive` each of ``items`` (kind, the id in its key or None, payload), in
        order, received at ``now``, ``now_wall``; the number accepted. One call for a
        packed brain's turn (covswarm.agent.pack): ~8 payloads a control period, most of
        them neighbours' AgentStates, each handed to the neighbourhood with what the
        process derived from it once (covswarm.agent.neighborhood.state_facts). A payload
        may be a Heard (covswarm.agent.decoding): decoded already, by the process that
        drained it."""
        decoded, me = self.decoder.decoded, self.id
        max_age, skew, peer_clocks = self._max_age, self.config.max_clock_skew, self.peer_clocks
        states: list[HeardState] = []  # the current run of AgentStates, applied at its end
        accepted = 0
        self.counters.received += len(items)
        for kind, key_id, payload in items:
            if states and kind != "state":
                self.neighborhood.on_agent_states(states)
                states = []
            # A packed process's payloads come decoded (Heard), once for all their brains.
            message, facts, error = (
                payload.decoded if type(payload) is Heard else decoded(kind, payload)
            )
            if error is None:
                try:
                    check_stamp(stamp := message.stamp, now_wall, max_age[kind], skew)
                except protocol.ProtocolError as exc:
                    error = exc
            if error is not None:
                self.drops.drop(error.reason, f"{kind}: {error}")
                continue
            if key_id is not None and message.id != key_id:
                self.drops.drop("wrong_id", f"{kind} from id {message.id} on the key of {key_id}")
                continue
            if kind == "state" or kind == "beacon":
                # Dated from when it was stamped, not from when it arrived: on our clock,
                # within the bound on its sender's offset (a state counts towards the bound;
                # a beacon only reads it). Dead reckoning counts from there, and the beacon
                # sent in the turn of a state is as old as that state, not newer news, one
                # that waited in an overloaded process for our turn as old as it is.
                rid = message.id
                clock = peer_clocks.get(rid)
                if kind == "state":
                    if clock is None:
                        clock = peer_clocks[rid] = ClockBound()
                    local = clock.add(now, now_wall, stamp)
                else:
                    local = stamp if clock is None else clock.to_local(stamp)
                lag = now_wall - local  # clamped to [0, MAX_PREDICTION] (NaN stays)
                if lag > MAX_PREDICTION:
                    lag = MAX_PREDICTION
                elif lag < 0.0:
                    lag = 0.0
                if kind == "beacon":
                    accepted += self.on_beacon(message, now - lag)
                elif rid != me:  # else our own state (on_agent_state)
                    states.append((message, facts, now - lag))
                    accepted += 1
                continue
            if kind == "pose" and message.id == me:
                self.robot_clock.add(now, now_wall, stamp)
            if _HANDLERS[kind](self, message, now):
                accepted += 1
                if kind == "domain":
                    self.coordinator_clock.add(now, now_wall, stamp)
        if states:
            self.neighborhood.on_agent_states(states)
        return accepted

    def pace(self, gap: float) -> None:
        """``gap``: s since this brain's previous turn (a packed process's, covswarm.agent.pack).

        A process that cannot hold its rate steps each brain every ``gap`` s, and its
        neighbours' brains publish their AgentStates at about that pace too: their newest
        state is then up to a gap old at our turn. Judged against ``stale_timeout`` alone,
        every neighbour would drop out of the local diagram between two of its states (or
        be refused at receipt as too old), our cell would swell over theirs and the robot
        drive into them: 1000 robots on two cores holding 0.7 of 10 Hz ended with e_a at
        17.5 m from 0.73 and 59 close approaches, each agent dropping ~300 neighbours as
        stale (27 Nov 2026). So their states stay usable for STALE_TURNS gaps, within
        [stale_timeout, STALE_STRETCH x stale_timeout]; steps so judged are counted
        (``stale_stretched``). At the asked rate (a gap of one period, below half the stale
        timeout) nothing changes.

        Their velocities are followed as long as their robots drive them: a command stays
        in force for the gap, up to the robot's command timeout (the neighbours' brains
        are paced as ours). DEAD_RECKONING_LIMIT (0.5 s) alone left every neighbour short
        of where it was by the rest of its move (an AgentState reports the sped-up
        velocity its robot drives for the hold, :meth:`_finish`), and the robots behind
        their neighbours at S's trailing edge fell out of S (1000 robots at 0.5 Hz, 28 Nov
        2026). When the gap is longer than the command timeout, a neighbour heard longer
        ago than that has stopped: its velocity is 0 to the safety filter, which otherwise
        let a robot close in on one it took for moving away (docs/scaling.md)."""
        self._gap = gap
        stale = self.config.stale_timeout
        horizon = min(max(stale, STALE_TURNS * gap), STALE_STRETCH * stale)
        self.neighborhood.stale_timeout = self._max_age["state"] = horizon
        timeout = self.config.cmd_timeout
        self.neighborhood.reckoning_limit = max(DEAD_RECKONING_LIMIT, min(gap, timeout))
        self.neighborhood.at_rest_after = timeout if gap > timeout else math.inf
        self.counters.stale_stretched += horizon > stale and self.running

    def on_pose(self, pose: protocol.Pose, now: float) -> bool:
        if pose.id == self.id:
            if self.pose is not None and pose.stamp < self.pose.stamp and self.pose_fresh(now):
                return False  # overtaken by a newer one (same robot clock): keep the newer
            self.pose, self.pose_received = pose, now
            self.pose_taken = self.robot_clock.to_local(pose.stamp)
        else:
            self.neighborhood.on_pose(pose, now)
        return True

    def on_stranded(self, pose: protocol.Pose, now: float) -> bool:
        """A pose of a stranded robot we follow (:meth:`stranded`): where it stands."""
        if pose.id not in self._stranded_followed:
            return False  # unfollowed since it was queued
        self._stranded[pose.id] = (pose.x, pose.y, now)
        return True

    def on_agent_state(self, state: protocol.AgentState, now: float) -> bool:
        if state.id == self.id:
            return False
        self.neighborhood.on_agent_state(state, now)
        return True

    def on_beacon(self, beacon: protocol.Beacon, now: float) -> bool:
        if beacon.id == self.id:
            return False  # our own beacon, heard through our own tile subscription
        self.neighborhood.on_beacon(beacon, now)
        return True

    def on_liveliness(self, role: str, rid: int, alive: bool) -> None:
        """Another robot's agent or robot token appeared or vanished (see
        Neighborhood.on_liveliness); a newcomer is owed an early beacon."""
        if self.neighborhood.on_liveliness(role, rid, alive):
            self._beacon_due = True  # a newcomer: let it find us without waiting

    def catch_up(self) -> None:
        """The token changes its process recorded since this brain's last turn apply from
        now on (covswarm.agent.pack: each is recorded once for the process, after the
        brain's data of the turn, as :meth:`on_liveliness` would have been called)."""
        if self.neighborhood.catch_up():
            self._beacon_due = True

    def on_domain(self, domain: protocol.Domain, now: float) -> bool:
        """Hold a newer domain: a higher sequence number than the held one (stamps come
        from the coordinator's clock and would drop a restarted coordinator on a host whose
        clock is behind), or any number once the held one's sender has been silent for
        DOMAIN_RESTART_SILENCE (a restarted coordinator numbers from 0 again).

        Doubted: one numbered more than MAX_DOMAIN_SEQ_JUMP above a held one whose sender
        still talks ("domain_seq_jump"), one with a vertex outside the workspace
        ("domain_outside_workspace"), and one overlapping an obstacle of the world
        ("domain_in_obstacle"), are dropped and counted."""
        held = self.domain
        if held is not None and now - self._domain_received < DOMAIN_RESTART_SILENCE:
            if not self._follows_sequence("domain", domain.seq, held.seq):
                return False
        if not self._inside_workspace(domain):
            self.drops.drop("domain_outside_workspace", f"domain {domain.vertices}")
            return False
        try:
            density = self.decoder.domain_geometry(domain)
        except ValueError as exc:
            self.drops.drop("bad_domain", f"domain: {exc}")
            return False
        if self._in_obstacle(domain):
            self.drops.drop("domain_in_obstacle", f"domain {domain.vertices}")
            return False
        if held is not None and domain.seq < held.seq:
            self.coordinator_clock.clear()  # a restarted coordinator, maybe on another host
        self.domain = domain
        self.density = density
        self._domain_received = now
        return True

    @property
    def running(self) -> bool:
        """Whether the mission runs (by the last domain received)."""
        return self.domain is not None and self.domain.state == "running"

    @property
    def command_hold(self) -> float:
        """s the last command was computed to stay in force (0: no cap known): the period
        measured between this brain's last two mission steps, up to its robot's command
        timeout. Its gain and its barrier's decay rate are sampled for it, and its turn
        cap (past ARC_HOLD a turn not made in place is capped over the command timeout), so
        a packed process that stops the robot earlier (covswarm.agent.pack) drives it less
        far than the step meant."""
        return self._hold

    def runs_on_for(self, stop_after: float) -> float:
        """s after our last step that our robot drives its command while our turns are late,
        when our process stops it ``stop_after`` s after a step (covswarm.agent.pack.Pack._hold,
        deploy.netsim's hold_after): that, or the hold the command was computed for
        (:attr:`command_hold`) when longer, so a command is never cut short of its own hold."""
        return max(stop_after, self._hold)

    @property
    def may_drive(self) -> float:
        """s the robot may drive the coming command if our next turn is late: until our
        process stops it (``runs_on_for(stop_after)``), at most its command
        timeout; without such a stop, the timeout. Past ARC_HOLD the turn is capped over it
        and the barrier's gain sampled over it on the rows at risk (filter_all)."""
        timeout = self.config.cmd_timeout
        if self.stop_after is None:
            return timeout
        return min(timeout, self.runs_on_for(self.stop_after))

    def pose_fresh(self, now: float) -> bool:
        """Whether our own robot's pose is known and younger than ``stale_timeout``."""
        return self.pose is not None and now - self.pose_received <= self.config.stale_timeout

    @property
    def tile_size(self) -> float | None:
        """The swarm's beacon tile size, from the domain broadcast (None before one)."""
        if self.domain is None:
            return None
        return self.domain.tile_size or protocol.DEFAULT_TILE_SIZE

    def wanted_tiles(self) -> frozenset[tuple[int, int]]:
        """Beacon tiles to subscribe to: (2r+1)^2 around our own tile (none without a pose
        or before the domain says the swarm's tile size)."""
        tile_size = self.tile_size
        if self.pose is None or tile_size is None:
            return frozenset()
        return _tile_block(*protocol.tile_of(self.pose.x, self.pose.y, tile_size), self.radius)

    # --- the tick ------------------------------------------------------------------------

    def tick(self, now: float, now_wall: float) -> list[Action]:
        """Everything to do this control period, in the order to do it: the phases of
        :meth:`begin`, one local step and :meth:`conclude` (what a packed process does for
        many brains at once, covswarm.agent.pack), then :meth:`actions`."""
        return self.actions(self.step(now, now_wall), now, now_wall)

    def actions(self, decision: Decision, now: float, now_wall: float) -> list[Action]:
        """The actions of a period whose step decided ``decision``, in the order to do them."""
        actions: list[Action] = [SendCommand(self.command(decision, now_wall))]
        exchange = self.exchange_due(now)
        self._last_actions = now
        if exchange:
            self._last_exchange = now
            if self.pose_fresh(now):
                with_stats = now >= self._next_stats
                state = self.agent_state(now_wall, stats=with_stats)
                if state is not None:
                    actions.append(PublishState(state))
                    if with_stats:
                        self._next_stats = now + STATS_PERIOD
        beacon = self.beacon(now, now_wall)
        if beacon is not None:
            actions.append(PublishBeacon(*beacon))
        if exchange:
            near, kept = self.near_ids() if self.config.safety else (set(), set())
            wanted = self.neighborhood.wanted_state_ids(now, near) | kept
            self.neighborhood.ask(wanted, now)  # robots known from beacons must now confirm
            actions.append(FollowStates(frozenset(wanted)))
            actions.append(FollowTiles(self.wanted_tiles()))
            stranded = self.stranded(now)
            if stranded != self._stranded_followed:
                self.counters.stranded_followed += len(stranded - self._stranded_followed)
                self._stranded_followed = stranded
                for rid in self._stranded.keys() - stranded:
                    del self._stranded[rid]
                actions.append(FollowStranded(stranded))
        if not self._alive and self.pose is not None:
            self._alive = True
            actions.append(DeclareAlive())
        return actions

    def exchange_due(self, now: float) -> bool:
        """Whether this period's actions (at ``now``) are a round of the neighbour exchange:
        our AgentState out, and the AgentStates and beacon tiles to follow chosen again.
        Once ``state_period`` s have passed since the last round, give or take half a
        control period (the gap since the last period's actions), so that a 10 Hz loop
        has one every step despite its jitter and a 30 Hz one every third step (what it
        follows changes no faster than the states it hears)."""
        gap = now - self._last_actions
        half = 0.5 * gap if math.isfinite(gap) else 0.0
        return now - self._last_exchange + half >= self.config.state_period

    def stop(self, now_wall: float) -> SendCommand:
        """The last command, when the process stops: the robot stops at once rather than
        after its command timeout."""
        return SendCommand(self.command(Decision(0.0, 0.0, "stopped"), now_wall))

    def hold(self, now: float, now_wall: float) -> list[Action]:
        """A zero command for a control period this brain could not step in time (an
        overloaded process, covswarm.agent.pack): its robot stops rather than run on the
        last command, computed from inputs that are now a period old; and our AgentState
        saying so (velocity 0), or neighbours would dead-reckon the robot on at its last
        velocity until our next step."""
        self.velocity = (0.0, 0.0)
        actions: list[Action] = [SendCommand(self.command(Decision(0.0, 0.0, "late"), now_wall))]
        state = self.agent_state(now_wall, stats=False) if self.pose_fresh(now) else None
        if state is not None:
            actions.append(PublishState(state))
        return actions

    # --- control -------------------------------------------------------------------------

    def step(self, now: float, now_wall: float) -> Decision:
        """One control step: the wheel speeds to send now, (0, 0) whenever unsure."""
        begun = self.begin(now, now_wall)
        if isinstance(begun, Decision):
            return self.settle(begun)
        started = self._clock()
        result = local_step_of(begun.view, self.config)
        concluded = self.conclude(begun, result, self._clock() - started)
        if isinstance(concluded, Decision):
            return concluded
        started = self._clock()
        safe = filter_one(concluded)
        return self.drive(concluded, safe, self._clock() - started)

    def settle(self, decision: Decision) -> Decision:
        """``decision`` as this period's: the velocity our AgentState reports from now on."""
        self.velocity = decision.achieved
        return decision

    def begin(self, now: float, now_wall: float) -> Decision | Begun:
        """A step up to its local step: the decision itself when the step ends early
        (no pose, no domain, the mission not running yet, an error), else the local view
        to step (:class:`Begun`) for :meth:`conclude`."""
        self.counters.steps += 1
        self.counters.mission_steps += self.running
        self._rates = (
            self._step_rate.add(now, self.counters.steps),
            self._rx_rate.add(now, self.counters.received + self.counters.coalesced),
        )
        self.neighborhood.refresh(now)
        if not self.pose_fresh(now):
            return Decision(0.0, 0.0, "no-pose")
        if self.domain is None:
            return Decision(0.0, 0.0, "no-domain")
        if self.domain.state == "running" and self.domain.start_velocities is not None:
            # S holds still at the end of a deploy hold, announcing its start: face it, and
            # take the first step after as the mission's first (no period measured yet).
            self._was_running, self._last_control = False, None
            return self._standing(now_wall)
        if self.domain.state != "running" and now - self._last_idle_step < IDLE_STEP_PERIOD:
            # Before the mission the step only keeps the neighbour sets warm: at 10 Hz,
            # agents already up would starve the ones still starting on a loaded machine.
            return self._standing(now_wall)
        self._last_idle_step = now
        if not now_wall + self.config.command_latency - self.pose_taken <= POSE_HORIZON:
            self.counters.pose_too_old += self.running
            return Decision(0.0, 0.0, "pose-too-old")
        started = self._clock()
        assert self.pose is not None
        try:
            # Our pose and S are predicted to when the command will act (command_latency):
            # so are the others, or each robot sees the one ahead of it that much closer and
            # the one behind as much farther (a column S set moving lost its order).
            relevant = self.neighborhood.relevant(
                now,
                (self.pose.x, self.pose.y),
                self.reach,
                self.config.command_latency,
                diagram_trust(now, self._last_view),
            )
            self._last_view = now
            return self._view(relevant, now, now_wall, started)
        except Exception as exc:  # noqa: BLE001 -- see _failed
            return self._failed(exc)

    def _view(
        self, others: dict[int, tuple[float, float]], now: float, now_wall: float, started: float
    ) -> Begun:
        assert self.pose is not None and self.domain is not None
        config = self.config
        pose = self.predicted_pose(now_wall + config.command_latency)
        # The domain's age since its stamp on our clock (within the bound on the
        # coordinator's offset, as a neighbour's state), not since we took it: a packed
        # process takes it at its tick, a constant 0-50 ms after a 20 Hz broadcast, which a
        # windowed minimum of receipt delays never removed (10 robots: S 1.6 mm behind each,
        # e_a's second half 0.0078 m against 0.0045 m with the stamp). Mission time stands
        # still until the mission runs.
        elapsed = 0.0
        if self.domain.state == "running":
            stamped = self.coordinator_clock.to_local(self.domain.stamp)
            elapsed = max(now_wall - stamped, 0.0)
        elapsed += config.command_latency
        # Shared by the brains of a process that step at the same time (the decoder's).
        vertices, velocities, density = self.decoder.extrapolated(
            self.domain, self.density, elapsed, config.max_extrapolation
        )
        me = pose[:2]
        kappa = config.kappa if config.kappa is not None else self.domain.kappa
        period = (
            1.0 if self._last_control is None else min(now_wall - self._last_control, MAX_PERIOD)
        )
        first = not self._was_running and self.running and self._gap > 0.0
        if first:
            # The first mission step follows an idle one, up to IDLE_STEP_PERIOD ago (or a
            # deploy hold's end): that is not the period its command will be held for. Taken
            # for it, every robot's first command had the gain sampled down to 0.8/s, the
            # barrier to ~1/s and no turn cap, and the team started most of a period late
            # (deploy.netsim circle-400, seeds 0-2: e_a at 0.2 s 0.49/0.45 against covswarm
            # sim's 0.41/0.39 from the same poses facing S; mean over 1-5 s 0.130/0.171/0.127
            # -> 0.103/0.139/0.100, the simulator's 0.095/0.118/0.102). The time between
            # our turns is the period it will be held for, as for every later step. (Also
            # when the idle step was our last turn: the period measured on the wall clock is
            # then the gap, a hair shorter or longer; a step that took it for longer than
            # the gap went without a hold, so without the turn cap, the unseen-speed limit
            # or ARC_TURN, and at ~1.25 Hz a robot backing from a neighbour 0.140 m away
            # swung round 1.2 rad to 0.128 m: circle-1000, netsim, seed 3, ARC_TURN.)
            period = min(self._gap, MAX_PERIOD)
        if self._last_control is not None:
            kappa = sampled_gain(kappa, period)
        self._last_control = now_wall
        self._period = period
        # s the coming command is expected to stay in force (covswarm.tvd.drive.steer): the
        # period measured between two mission steps, up to the robot's command timeout; on
        # the first mission step, the time between our turns (above). Neither known (a
        # brain not paced): 0, no cap, rather than a first command that drives off along
        # the start heading and barely turns (a cap for a 0.5 s hold).
        self._hold = min(period, config.cmd_timeout) if self._was_running or first else 0.0
        self._was_running = self.running
        others[self.id] = me
        still = self._still_generators(others)
        view = LocalView(self.id, others, vertices, velocities, kappa, density, still)
        return Begun(view, pose, now, now_wall, self._clock() - started)

    def _still_generators(self, others: dict[int, tuple[float, float]]) -> frozenset[int]:
        """The stranded robots (:meth:`stranded`), put into ``others`` where their own poses
        say they stand, as the local diagram's still generators (covswarm.tvd.control's
        ``still``): their cells bound ours, so our centroid never falls on one. Left out of
        it, a robot whose centroid fell on a dead brain's robot inside S stood at the safe
        distance from it for the rest of the mission (docs/real-robots.md, "Robots queued
        behind dead ones"). Every brain follows every stranded robot, so neighbours agree
        on them as on the rest of the two-hop set."""
        if not self._stranded:
            return frozenset()
        orphans = self.neighborhood.liveliness.orphans  # (not one whose token changed since)
        first_hand = self.neighborhood.first_hand
        still = []
        for rid, (sx, sy, _) in self._stranded.items():
            if rid in orphans and rid not in first_hand:
                others[rid] = (sx, sy)
                still.append(rid)
        return frozenset(still)

    def conclude(
        self, begun: Begun, result: LocalStep | Exception, shared: float
    ) -> Decision | Filtering:
        """The step after its local step ``result`` (or the exception it raised): the
        neighbour and reach bookkeeping, then the decision, or, with the safety filter on
        and the mission running, the filter's inputs (:class:`Filtering`) for
        :meth:`drive`. ``shared``: s of the clock spent on this brain's share of the local
        steps (the step timer)."""
        started = self._clock()
        try:
            if isinstance(result, Exception):
                raise result
            outcome = self._finish(begun, result)
        except Exception as exc:  # noqa: BLE001 -- see _failed
            return self.settle(self._failed(exc))
        spent = begun.spent + shared + self._clock() - started
        if isinstance(outcome, Filtering):
            outcome.spent = spent
            return outcome
        self._step_us.add(spent * 1e6)
        return self.settle(outcome)

    def drive(
        self, filtering: Filtering, safe: SafeVelocity | Exception, shared: float
    ) -> Decision:
        """The step after its safety filter ``safe`` (filtered velocity (2,) m/s, rows
        tight, relaxed; or the exception it raised): the wheel speeds. ``shared``: s of the
        clock spent on this brain's share of the filter."""
        started = self._clock()
        try:
            if isinstance(safe, Exception):
                raise safe
            velocity, active, relaxed = safe
            self.safety_active += active > 0
            self.safety_relaxed += bool(relaxed)
            if filtering.near_gamma is not None and self.running:
                self.counters.overrun_gained += int(np.sum(filtering.near_gamma < filtering.gamma))
            vx, vy = velocity
            aim = filtering.nominal.tolist()  # where it wants to go: the turn's cap and veer
            x, y, heading = filtering.begun.pose
            # Held back (only by an active row: else it drives its aim), it passes on the
            # side away from the robot that holds it back; stopped dead, it turns toward
            # its slide (covswarm.tvd.drive.steer), unless its turns come later than
            # ARC_HOLD: a command driven up to the timeout would slide on past where the
            # rows bent its aim (deploy.netsim's overloaded circle-400, brains every
            # 0.45-1.15 s: e_a at the end +15 mm on average over seeds 0-3, 1 Dec 2026).
            side, slide = 1.0, None
            if active:
                near = filtering.near[:, :2]
                side = float(pass_sides((x, y), filtering.nominal, near, SAFETY_RADIUS)[0])
            now = filtering.begun.now
            if not (active and stopped_dead_one(heading, vx, vy, (aim[0], aim[1]))):
                self._stopped_since = None
            elif self._stopped_since is None:
                self._stopped_since = now
            if (
                self._stopped_since is not None
                and self._slide_side is None
                and self._hold <= ARC_HOLD
                and (
                    now - self._stopped_since >= SLIDE_AFTER
                    or stopped_beside((x, y), heading, filtering.near, self._safe_distance)
                )
            ):
                # From the next step on it aims at its slide until the way is clear
                # (_safety_inputs), not back at the robot that stopped it; dead ahead, on
                # the side it passes on, kept until then.
                taken = slide_of(filtering, side)
                if taken is not None:
                    slide = (float(taken[0]), float(taken[1]))
                    self._slide_side = side
                    self.counters.slid += self.running
            decision = self._wheels(vx, vy, heading, (aim[0], aim[1]), side, slide)
        except Exception as exc:  # noqa: BLE001 -- see _failed
            return self.settle(self._failed(exc))
        self._step_us.add((filtering.spent + shared + self._clock() - started) * 1e6)
        return self.settle(decision)

    def _failed(self, exc: Exception) -> Decision:
        """Any failure of the geometry (degenerate input the math rejects, or a bug) must
        stop this robot, not kill the process and leave the robot on its last command."""
        self.counters.step_errors += 1
        if self._failure_log.ready():  # at most one line per LOG_INTERVAL, not per tick
            self.log.warning(
                "agent %d: control step failed (%d so far), robot stopped: %r",
                self.id,
                self.counters.step_errors,
                exc,
            )
        return Decision(0.0, 0.0, "error")

    def _finish(self, begun: Begun, result: LocalStep) -> Decision | Filtering:
        assert self.domain is not None
        config = self.config
        now = begun.now
        x, y, heading = begun.pose
        self.counters.guarded += int(result.guarded and self.running)
        self.counters.cell_empty += int(result.mass <= 0.0 and self.running)
        # Neighbour bookkeeping runs while waiting too, so subscriptions are warm at start.
        # The view's own ids (ints), as one frozenset: taken as it is, not copied.
        # Without the still generators: no brain of theirs answers, states or beacons.
        still = begun.view.still
        self.neighborhood.one_hop = (
            frozenset(result.neighbors) - still if still else frozenset(result.neighbors)
        )
        if self.neighborhood.unrequited(now):
            self._beacon_due = True
        self._local = len(begun.view.positions) - 1
        if result.mass > 0.0:
            # The area, not the mass: a density's mass overstates the cell's size (by the
            # bump's peak over the floor under a bump), and with it the local set.
            cx, cy = result.centroid.tolist()
            self.reach = cell_reach(math.hypot(cx - x, cy - y), result.area)
            self.radius = tile_radius(
                self.reach, self.tile_size, self.radius, self.config.max_tile_radius
            )
        else:
            self.reach = None
        if self.domain.state != "running":
            return self._standing(begun.now_wall)
        velocity = np.asarray(result.velocity, dtype=float)
        if self._period > self._hold > 0.0 and self.config.max_duty > 1.0:
            # The law's velocity is what to hold for the period; a robot that stops after
            # the hold would cover hold / period of its move (its feedforward as well: a
            # team whose robots stop halfway through each period lags S by half its
            # motion, and trailing robots leave S). Driven period / hold as fast, it covers
            # the period's move in the hold; the safety filter bounds the faster velocity
            # and the wheels saturate as ever. At the asked rate the duty is 1.
            velocity = velocity * min(self._period / self._hold, self.config.max_duty)
            self.counters.duty_scaled += self.running
        if config.safety and self._hold > 0.0:
            # No faster than the robots we do not filter against yet can be avoided at:
            # the wheels' top speed at 10 Hz, less for longer steps or a command latency.
            limit = unseen_speed_limit(
                SAFETY_RADIUS,
                self._safe_distance,
                BEACON_MOVE,
                self._hold,
                config.command_latency,
            )
            # (above the wheels' top speed they saturate first, in the same direction: at
            # 10 Hz without a latency, every step)
            if limit < config.robot.max_wheel_speed:
                speed = math.hypot(*velocity.tolist())
                if speed > limit:
                    velocity = velocity * (limit / speed)
                    self.counters.speed_limited += self.running
        vx, vy = velocity.tolist()
        if not (math.isfinite(vx) and math.isfinite(vy)):
            raise ValueError(f"non-finite velocity {velocity}")
        if config.safety:
            return self._safety_inputs(begun, velocity, x, y)
        return self._wheels(vx, vy, heading)

    def _standing(self, now_wall: float) -> Decision:
        """The decision of a step while the mission does not run, or S holds still at the
        end of a deploy hold (covswarm.coordinator.pace.DEPLOY_ALIGN): hold still, but while
        it waits for a start that moves S, turn in place to face where S will carry the robot
        (the domain's start velocities' affine field at its position, as TVD-DA's
        feedforward guesses it): a robot that can only drive forwards and starts facing
        away falls behind while it turns, and a team's trailing edge then starts outside S
        and stays there, held off by the safety filter (100 robots on the circle in
        covswarm.deploy.netsim, seed 0: e_a's second half 0.011 m against 0.059 m as placed,
        docs/scaling.md). Not from a pose older than the prediction holds."""
        domain = self.domain
        assert domain is not None
        start = domain.start_velocities
        latency = self.config.command_latency
        # A still running S is waited for too ("aligned", not a running step's command).
        waited = "aligned" if domain.state == "running" else domain.state
        if (
            domain.state == "done"
            or start is None
            or self.pose is None
            or not now_wall + latency - self.pose_taken <= POSE_HORIZON
        ):
            return Decision(0.0, 0.0, waited)
        field = self._start_field
        if field is None or field[0] is not domain:
            field = self._start_field = (domain, affine_field(domain.vertices, start))
        x, y, heading = self.predicted_pose(now_wall + latency)
        direction = float(field_directions(field[1], np.array(((x, y),)))[0])
        config = self.config
        # (0, 0) facing it already, or where S barely moves (NaN)
        left, right = turn_in_place(heading, direction, config.cmd_timeout, config.robot)
        if left == right:
            return Decision(0.0, 0.0, waited)
        self.counters.aligning += 1
        return Decision(left, right, "aligning")

    def _wheels(
        self,
        vx: float,
        vy: float,
        heading: float,
        aim: tuple[float, float] | None = None,
        side: float = 1.0,
        slide: tuple[float, float] | None = None,
    ) -> Decision:
        """The running decision for the velocity (vx, vy) m/s from ``heading`` rad, turning
        toward ``aim`` (the velocity before the safety filter, faced, or passed on ``side``
        while the filter holds the robot back: covswarm.tvd.drive.steer; None: (vx, vy)),
        or toward ``slide`` when the filter stopped it dead."""
        config = self.config
        robot = config.robot
        left, right, capped = steer_one(
            heading, vx, vy, robot, config.projection_distance, self._hold, aim, side, slide
        )

        if self._hold > ARC_HOLD:
            turn = (right - left) / robot.wheel_separation * config.cmd_timeout
            if abs(turn) > ARC_TURN:  # turn in place at the same rate, drive from the next step
                left, right = 0.5 * (left - right), 0.5 * (right - left)
                self.counters.arc_turned += 1
            elif (may_drive := self.may_drive) > self._hold:
                # Driven on an arc: no further than its aim however long the robot drives
                # the command, until our next one or its stop (see ARC_HOLD).
                left, right, capped = steer_one(
                    heading, vx, vy, robot, config.projection_distance, may_drive, aim, side, slide
                )
        self.counters.turn_capped += capped
        # What the robot's centre will do, not what was asked: what our AgentState reports
        # for neighbours to dead-reckon our position with (a saturated command overstates
        # the speed, and the steered point is not the centre).
        forward, _ = twist_from_wheels(left, right, robot.wheel_separation)
        achieved = (forward * math.cos(heading), forward * math.sin(heading))
        return Decision(left, right, "running", (vx, vy), achieved)

    def predicted_pose(self, target_wall: float) -> tuple[float, float, float]:
        """(x m, y m, heading rad) of our robot at our wall time ``target_wall``: its last
        pose moved along the commands sent since it was taken (covswarm.agent.latency), or
        as taken when prediction is off or the pose is older than POSE_HORIZON (a step
        does not steer from such a pose: :meth:`begin`). Plain floats: the step reads them
        one by one, and numpy converts them once per batch."""
        pose = self.pose
        assert pose is not None
        horizon = target_wall - self.pose_taken
        if not self.config.prediction or not 0.0 < horizon <= POSE_HORIZON:
            return pose.x, pose.y, pose.theta
        return self.history.move(pose.x, pose.y, pose.theta, self.pose_taken, target_wall)

    def stranded(self, now: float) -> frozenset[int]:
        """The robots whose poses we follow as obstacles: those whose robot's token has
        lived without their agent's for longer than the command timeout while the mission
        runs (covswarm.agent.neighborhood.Liveliness.orphans). Such a robot stands where its
        timeout stopped it and no brain will move it; neighbours that knew it keep it
        (:meth:`_still_there`), but a robot that arrives later has heard no state of it.
        Its own robot publishes its pose to anyone (reading is open to every role): the
        local diagram takes it as a still generator (:meth:`_still_generators`), the safety
        filter as a still row (:meth:`_safety_inputs`)."""
        orphans, since = self.neighborhood.liveliness.orphans, self._orphaned
        if not orphans and not since:
            return frozenset()  # (every step of a healthy team)
        for rid in [rid for rid in since if rid not in orphans]:
            del since[rid]
        if not self.running:
            return frozenset()
        timeout = self.config.cmd_timeout
        for rid in orphans:
            since.setdefault(rid, now)
        return frozenset(
            rid for rid, first in since.items() if rid != self.id and now - first > timeout
        )

    def near_ids(self) -> tuple[set[int], set[int]]:
        """The robots whose AgentStates the safety filter needs, as (near, kept).

        ``near``: the robots known within SAFETY_RADIUS of ours, Voronoi neighbours or not:
        followed unless a fresh relay carries them (Neighborhood.wanted_state_ids).
        ``kept``: followed whatever carries them. Those there known only from beacons and
        left out for want of confirmation: a real one's AgentState then confirms it
        (covswarm.agent.neighborhood.BEACON_CONFIRMATION). And the robots held as
        obstacles: one alive that moved on leaves the obstacle set with its next state.
        Unfollowed, it stayed a phantom where last heard for OBSTACLE_MEMORY: a robot left
        behind outside S (empty cell, no neighbours, no subscriptions) was fenced in by its
        former neighbours' phantoms, wheels saturated against them, for the rest of the
        mission (100-robot circle on a loaded machine: 13-19 robots, e_a 2.9 m)."""
        kept = set(self.obstacles)
        if self.pose is None:
            return set(), kept
        x, y = self.pose.x, self.pose.y
        neighborhood = self.neighborhood
        if neighborhood.unconfirmed:
            distance = {
                rid: math.hypot(ux - x, uy - y)
                for rid, (ux, uy) in neighborhood.unconfirmed.items()
            }
            # The nearest few only: forged ids must not cost a subscription each.
            nearest = sorted((d, rid) for rid, d in distance.items() if d <= SAFETY_RADIUS)
            kept.update(rid for _, rid in nearest[:MAX_UNCONFIRMED_FOLLOWED])
        near = set(neighborhood.table_ids[neighborhood.within(x, y, SAFETY_RADIUS)].tolist())
        return near, kept

    def _still_there(self, rid: int, held: float) -> bool:
        """Whether robot ``rid``, held as an obstacle for ``held`` s, is still taken to stand
        where it stopped: for OBSTACLE_MEMORY s; for as long as its robot lives once its
        agent's token is gone (an orphan: stopped by its command timeout, with no brain to
        move it again); not once its robot's token is gone."""
        roles = self.neighborhood.dead.get(rid, ())
        if "robot" in roles:
            return False
        return held <= OBSTACLE_MEMORY or "agent" in roles

    def _safety_inputs(self, begun: Begun, velocity: np.ndarray, x: float, y: float) -> Filtering:
        """What the safety filter (covswarm.tvd.safety) needs to filter ``velocity`` (2,)
        m/s from (x, y) m (begun's pose): the robots near us, i.e. the candidates
        (dead-reckoned, with their reported velocities) and the obstacles we stopped hearing
        from (at rest where last known); with a world, its obstacles and workspace walls
        near us too (a body radius plus the margin)."""
        config = self.config
        now = begun.now
        neighborhood = self.neighborhood
        within = neighborhood.within(x, y, SAFETY_RADIUS)
        inside = neighborhood.fresh_rows(within, now, BEACON_TRUST)
        if len(inside) < len(within) and self.running:
            self.counters.beacon_doubted += len(within) - len(inside)
        near = neighborhood.table[inside]
        # Only a robot we heard first-hand nearby and then not at all is an obstacle: one
        # that merely left our candidates as the team moved on (its relays and states went
        # to others) would be a phantom where it was, and phantoms across a moving team's
        # path held robots back until they lost the domain (100-robot circle: e_a 5.7 m).
        # And one whose states we followed and that is no longer first-hand, however else
        # it is named: a stalled brain's state ages out of our candidates (pace's horizon)
        # while a neighbour's relay of it, or its last beacon (sent in the turn of its last
        # state, and then its newest news: a state's receipt is backdated to its stamp, a
        # beacon's is not), still names it; the relay goes a turn later, and an old beacon
        # is no row while its state is awaited (BEACON_TRUST). Keyed on the robot vanishing
        # from the candidates, the follower of a robot stopped 0.18 m ahead saw none of it
        # for a step and drove at the unseen speed limit into it: one process's brains
        # starved for 2.5 s among brains stepped every 0.8-1.2 s (deploy.netsim circle-400,
        # S 8x slower, seeds 0-3: 1-5 pairs within a diameter each, closest 0.104-0.128 m;
        # with this rule none), as in the live circle-1000 at ~1 Hz (0.115 and 0.124 m, 30
        # Nov 2026). Not one we stopped following (a relay carries it: Neighborhood.
        # wanted_state_ids): its own state ages as meant, and as an obstacle it was a
        # phantom where last heard (netsim circle-100 at 10 Hz, seed 0: e_a at 10 s 0.029 m
        # against 0.006; as it is, seeds 0-2 at 10 Hz are unchanged to the last digit of
        # e_a, and unstalled ~1 Hz circle-400 runs, seeds 0-1, in e_a and every counter).
        # Such an obstacle goes when its state comes again (its states are followed:
        # near_ids), not when a relay or a beacon names it.
        # (Set operations in C: the rows are turned into floats only for the rare robot
        # that vanished, not for every near robot every step.)
        first_hand = neighborhood.first_hand
        gone = self._near_first_hand - first_hand  # (mostly empty)
        if gone:
            reckoned, followed = neighborhood.reckoned, neighborhood.wanted
            gone = {r for r in gone if r not in reckoned or r in followed}
        if gone:
            self.counters.obstacles_kept += len(gone)
            # Where its robot stops: on its last command until its command timeout (ours, as
            # pace assumes of every neighbour's robot), which our last step's reckoning can
            # fall short of (DEAD_RECKONING_LIMIT, a gap shorter than the timeout).
            last_ids, last_near = self._near_last
            timeout = config.cmd_timeout
            for rid, (last_x, last_y, _, _) in zip(last_ids, last_near.tolist(), strict=True):
                if rid in gone:
                    stop = neighborhood.stop_point(rid, timeout) or (last_x, last_y)
                    self.obstacles[rid] = (*stop, now)
        ids = neighborhood.table_ids[inside].tolist()
        self._near_first_hand = first_hand.intersection(ids)
        self._near_last = (ids, near)
        latency = config.command_latency
        if latency:  # where they will be when our command acts, as our own pose (begin)
            near = near.copy()
            near[:, :2] += latency * near[:, 2:4]
        if self.obstacles:  # (seldom any: no scan of an empty table every step)
            for rid in [
                r
                for r, (_, _, since) in self.obstacles.items()
                if r in first_hand or not self._still_there(r, now - since)
            ]:
                del self.obstacles[rid]
        if self.obstacles:  # none is a candidate
            rows = np.array([(x, y, 0.0, 0.0) for x, y, _ in self.obstacles.values()])
            near = np.concatenate(
                [near, rows[np.hypot(rows[:, 0] - x, rows[:, 1] - y) <= SAFETY_RADIUS]]
            )
        if self._stranded:  # a stranded robot, where its own pose puts it (stranded)
            orphans = neighborhood.liveliness.orphans  # (not one whose token changed since)
            rows = np.array(
                [
                    (sx, sy, 0.0, 0.0)
                    for rid, (sx, sy, _) in self._stranded.items()
                    if rid in orphans and rid not in self.obstacles and rid not in first_hand
                ]
            ).reshape(-1, 4)
            near = np.concatenate(
                [near, rows[np.hypot(rows[:, 0] - x, rows[:, 1] - y) <= SAFETY_RADIUS]]
            )
        # The world's obstacles and walls within SAFETY_RADIUS: a row each (none without a
        # world, so the filter is then exactly the robots' alone). Those whose bounding box
        # is that near are handed over and the filter keeps the ones within its reach: the
        # same rows as World.nearby's, without computing every distance twice (~90 us).
        # Sampled for the time the velocity is driven: the period, or the hold when the
        # robot stops before our next step (the velocity is then driven faster, _finish).
        driven = self._hold if 0.0 < self._hold < self._period else self._period
        # Over the span from what we know to the end of that drive: a command acts
        # command_latency s after it is computed, and what the others decided meanwhile is
        # not in the shares of the pairs' conditions, which can then disagree.
        gamma = barrier_gain(config.safety_gamma, driven + latency)
        # Past ARC_HOLD our next turn may come later than the last gap, and the robot then
        # drives the command to its timeout: filter_all samples the gain over that on the
        # rows of the robots the command so driven would bring within the safe distance.
        overrun = 0.0
        if self._hold > ARC_HOLD and len(near) and (may_drive := self.may_drive) > driven:
            overrun = may_drive + latency
        world = self.world
        obstacles: list[np.ndarray] = []
        if world is not None and world.obstacles:  # a workspace alone: walls, no search
            nearby = world.candidates((x, x, y, y), SAFETY_RADIUS)
            obstacles = [world.obstacles[j].vertices for j in nearby]
        filtering = Filtering(
            begun=begun,
            nominal=velocity,
            near=near,
            safe_distance=self._safe_distance,
            gamma=gamma,
            velocity=self.velocity,
            obstacles=obstacles,
            workspace=self.workspace if world is not None else None,
            obstacle_distance=self._wall_distance,
            obstacle_gamma=WALL_GAMMA_FRACTION * gamma,
            overrun=overrun,
        )
        if self._slide_side is not None:
            # Aiming at its slide since the filter stopped it dead (drive), until the rows
            # no longer bend its aim. Facing its aim again while they did (at once, or
            # once its aim was no longer stopped dead), it turned back into the robot that
            # had stopped it, on an arc the filter (which bounds the forward speed along
            # the heading it starts from) does not see: to 0.149 m of a still robot 10
            # degrees off its aim (tests/test_slide.py), and stopped dead again. (Bent at
            # the safe distance: at the slide's, the robots of a dense team stayed in it.)
            along = slide_velocity(filtering, 0.0)
            taken = None
            if along.active > 0 and self.running and self._hold <= ARC_HOLD:
                taken = slide_of(filtering, self._slide_side, along.velocity)
            if taken is None:
                self._slide_side = None
            else:
                filtering.nominal = taken
                self.counters.slid += 1
        return filtering

    # --- output --------------------------------------------------------------------------

    def command(self, decision: Decision, stamp: float) -> protocol.WheelCommand:
        """The wheel command for ``decision``; non-finite speeds become (0, 0)."""
        left, right = decision.left, decision.right
        if not (math.isfinite(left) and math.isfinite(right)):
            left = right = 0.0
        self._seq += 1
        self.history.add(stamp + self.config.command_latency, left, right)
        if self.pose is not None and decision.reason == "running":
            # Pose-to-command latency: when the pose was taken (on our clock, within the
            # bound on our robot's offset: covswarm.agent.latency) to this command's stamp.
            # Of commands steered from the pose only: a late brain's stop (covswarm.agent.
            # pack) goes out up to a gap after its last pose, and counted, half the commands
            # of 1000 robots on two cores read as ~1 s old poses, where the router delivered
            # poses in 13 ms (p50) and the brains steered from them 25-80 ms after their
            # stamps (scripts/transport_delays.py, 28 Nov 2026).
            self._pose_age_ms.add((stamp - self.pose_taken) * 1e3)
        if decision.reason == "running":
            if self._last_running_command is not None and self._saturated:
                self.saturated_s += min(stamp - self._last_running_command, 1.0)
            peak = max(abs(left), abs(right))
            self.wheel_max = max(self.wheel_max, peak)
            self._saturated = peak >= self.config.robot.max_wheel_speed * (1.0 - 1e-9)
            self._last_running_command = stamp
        else:
            self._last_running_command = None
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
        step_p50, step_p99 = self._step_us.get(0.50, 0.99)
        age_p50, age_p99 = self._pose_age_ms.get(0.50, 0.99)
        return {
            "rate_hz": round(self._rates[0], 3),
            "step_us_p50": round(step_p50, 1),
            "step_us_p99": round(step_p99, 1),
            "rx_per_s": round(self._rates[1], 1),
            "pose_age_ms_p50": round(age_p50, 2),
            "pose_age_ms_p99": round(age_p99, 2),
            # our clock minus our robot's is at most this (includes the fastest transit)
            "robot_clock_bound_ms": _ms(self.robot_clock.bound),
            "safety_active": self.safety_active,
            "safety_relaxed": self.safety_relaxed,
            "wheel_max": round(self.wheel_max, 4),
            "saturated_s": round(self.saturated_s, 3),
            "missed_deadline": round(c.overruns / c.mission_steps, 4) if c.mission_steps else 0.0,
            # fraction of the mission's periods held instead of stepped (Counters.late)
            "late_held": round(c.late / (c.late + c.mission_steps), 4) if c.late else 0.0,
            "rx_total": c.received + c.coalesced,
            "coalesced": c.coalesced,
            **{f"drop_{reason}": n for reason, n in self.drops.counts.items()},
            "stale_dropped": self.neighborhood.stale_dropped,
            "beacon_unconfirmed": self.neighborhood.unconfirmed_total,
            "step_errors": c.step_errors,
            "batch_fallbacks": c.batch_fallbacks,
            "turn_capped": c.turn_capped,
            "arc_turned": c.arc_turned,
            "overrun_gained": c.overrun_gained,
            "slid": c.slid,
            "stranded_followed": c.stranded_followed,
            "cell_empty": c.cell_empty,
            "stale_stretched": c.stale_stretched,
            "pose_too_old": c.pose_too_old,
            "duty_scaled": c.duty_scaled,
            "speed_limited": c.speed_limited,
            "beacon_doubted": c.beacon_doubted,
            "obstacles_kept": c.obstacles_kept,
            "aligning": c.aligning,
            "mission_steps": c.mission_steps,
            "guarded": c.guarded,
            "candidates": len(self.neighborhood.reckoned),
            "local_set": self._local,
            "neighbors": len(self.neighborhood.one_hop),
            "state_subs": len(self.neighborhood.wanted),
            "tile_radius": self.radius,
        }

    def agent_state(self, stamp: float, stats: bool = True) -> protocol.AgentState | None:
        """Our AgentState (with our stats if ``stats``), or None before our own pose is known."""
        if self.pose is None:
            return None
        # Where the robot is at the state's stamp by the same prediction the control step
        # uses, so that neighbours and we agree on it; they dead-reckon from the stamp on with
        # the velocity (clamped: the control's is unbounded, the wire's is not).
        # Plain floats (not numpy's), which AgentState takes without a checker call each.
        vx, vy = self.velocity
        bound = protocol.MAX_SPEED
        vx, vy = min(max(vx, -bound), bound), min(max(vy, -bound), bound)
        x, y, _ = self.predicted_pose(stamp)
        x, y = clamp_position(x, y)
        # Our neighbours of the last step that reckoned them; never one whose token has
        # vanished since: a step that ends early (or a hold) leaves the set as it was, and
        # a brain starved for a second or two went on naming a dead robot to the team.
        one_hop, dead = self.neighborhood.one_hop, self.neighborhood.dead_now()
        return protocol.AgentState(
            id=self.id,
            x=x,
            y=y,
            stamp=stamp,
            neighbors=sorted(one_hop - dead.keys() if dead else one_hop),
            stats=self.stats() if stats else None,
            vx=vx,
            vy=vy,
            relay=self.neighborhood.relay(),
        )

    def _driving_through(self) -> bool:
        """Whether our robot drives other than S carries it: its cell is empty (outside S,
        on its way in), or it drives faster than any point of S moves by BEACON_SLACK
        (S's motion is affine: its fastest point is a vertex). Its teammates' tables then
        lose track of it between routine beacons; riding S with its neighbours, it keeps
        its place among them."""
        if self.reach is None:
            return True
        assert self.domain is not None  # a beacon needs its tile size
        carried = max((math.hypot(vx, vy) for vx, vy in self.domain.velocities), default=0.0)
        return math.hypot(*self.velocity) > carried + BEACON_SLACK

    def beacon(self, now: float, stamp: float) -> tuple[tuple[int, int], protocol.Beacon] | None:
        """(tile, Beacon) if one is due at ``now``, else None.

        Due every ``beacon_period``, or BEACON_MIN_PERIOD after the last one once another
        agent's liveliness token appeared (a newcomer, or a whole team starting, must find
        its neighbours, and they it, without waiting for the next routine beacon) or a
        neighbour kept leaving us out of its neighbours (Neighborhood.unrequited); and
        whenever the robot has moved BEACON_MOVE since the last while it drives through S
        rather than with it (:meth:`_driving_through`).

        None while our own pose is stale: a robot that stopped reporting (dead) must not be
        kept alive in the others' diagrams by its brain; and before the domain gives the
        swarm's tile size.

        Where the robot is at ``stamp``, by the prediction our AgentState and control step
        use (:meth:`predicted_pose`), and so is the move: the received pose is where it was
        when the pose was taken. With poses 1.2 s late (covswarm.deploy.netsim, the 6-robot
        passage, seeds 0-9) a beacon stamped now said where its robot had been 1.2 s before,
        and a robot driving off at the start beaconed only once its late pose had moved;
        its neighbours, whose AgentStates of it were as late and from before the start (at
        rest), saw it where it started: four seeds of ten had pairs closer than a diameter
        (0.027 m at worst, seed 8), none with the prediction.
        """
        tile_size, pose, last = self.tile_size, self.pose, self._beacon_at
        if tile_size is None or pose is None or not self.pose_fresh(now):
            return None
        due = now - self._last_beacon >= (
            BEACON_MIN_PERIOD if self._beacon_due else self.config.beacon_period
        )
        if not due and (last is None or not self._driving_through()):
            return None
        x, y, _ = self.predicted_pose(stamp)
        if not due and math.hypot(x - last[0], y - last[1]) < BEACON_MOVE:
            return None
        self._last_beacon = now
        self._beacon_due = False
        self._beacon_at = (x, y)
        x, y = clamp_position(x, y)
        tile = protocol.tile_of(x, y, tile_size)
        return tile, protocol.Beacon(id=self.id, x=x, y=y, stamp=stamp)


_HANDLERS: dict[str, Callable[[AgentBrain, object, float], bool]] = {
    "pose": AgentBrain.on_pose,
    "stranded": AgentBrain.on_stranded,
    "state": AgentBrain.on_agent_state,
    "beacon": AgentBrain.on_beacon,
    "domain": AgentBrain.on_domain,
    "world": AgentBrain.on_world,
}
