"""The distributed run in one process, on a simulated clock: real brains, real robots, no Zenoh.

``covswarm run`` with the network replaced by a deterministic in-memory bus: every agent is
an :class:`covswarm.agent.brain.AgentBrain` fed the same encoded payloads a Zenoh
subscriber would hand it (newest per key per tick, its pose loss and delay applied by the
same :class:`covswarm.agent.faults.PoseImpairment`), every robot a
:class:`covswarm.sim_robot.process.RobotSim`, and the coordinator's Domain broadcasts are
built as the coordinator builds them. Robots and the coordinator tick at 20 Hz, agents at
their rate with a random phase each; a message is delivered ``transit`` s after it was
sent. Wall and monotonic clocks are one simulated clock (``clock_skew`` shifts the robots'
stamps to emulate another host).

Delivery is Zenoh's pub/sub without history, on the keys a live agent subscribes to
(covswarm.agent.pack): its robot's pose, the domain, the AgentStates of the robots its
brain follows (FollowStates) and the beacon tiles it follows (FollowTiles; a beacon goes
out on its sender's tile, and comes back to the sender if it follows that tile). A
message reaches the agents that follow its key when it arrives, ``transit`` s after it
was put; a follow or unfollow takes effect when the brain asks, right after its step, as
a live process (un)declares its subscriber then. So a newly followed robot is known
first-hand only from its next AgentState, and what an agent had not read of a key when it
stopped following it is lost, as an undeclared subscriber's ring is (Pack._unfollow). A
subscriber's declaration is taken to reach the publishers at once: a message put up to
``transit`` s before an agent followed its key, still on its way, reaches it. Liveliness
tokens likewise: the robots' live from the start, an agent's from when its brain declares
it (DeclareAlive, once it has its robot's pose), and every agent takes the token change
``transit`` s later, after its turn's data. A brain beacons early for an agent it does
not know yet: with every token there from the start, those beacons would go out before
anyone followed a tile, and a team would meet its neighbours only at the routine beacons.

What it is for: measuring how latency, loss and the agents' options change e_a in seconds
of CPU rather than a minute of a loaded machine per run, deterministically, to choose
parameters (see covswarm.agent.latency and scripts/latency_table.py). What it is not: a
substitute for the e2e tests, which run real processes over real Zenoh sessions.
"""

from __future__ import annotations

import heapq
import math
from collections import defaultdict
from collections.abc import Collection, Iterable
from dataclasses import dataclass, field

import numpy as np

from covswarm import protocol
from covswarm.agent.brain import (
    Action,
    AgentBrain,
    AgentConfig,
    DeclareAlive,
    FollowStates,
    FollowStranded,
    FollowTiles,
    PublishBeacon,
    PublishState,
    SendCommand,
)
from covswarm.agent.decoding import MessageDecoder
from covswarm.agent.faults import PoseImpairment
from covswarm.coordinator.monitor import (
    DISCOVERY_EDGE,
    DISCOVERY_PERIOD,
    DISCOVERY_REACH,
    DISCOVERY_WAIT,
    MAX_START_SETTLE,
    ExchangeGaps,
    discovery_gaps,
    start_settle,
)
from covswarm.coordinator.pace import broadcast_motion
from covswarm.mission.scenarios import Scenario
from covswarm.tvd.drive import DiffDrive

ROBOT_RATE = 20.0  # Hz, poses (as covswarm robot)
DOMAIN_RATE = 20.0  # Hz (as covswarm coordinator)
SAMPLE_PERIOD = 0.1  # s between e_a samples
START_WALL = 1.7e9  # s: the simulated epoch (stamps must look like wall time)

# A key an agent subscribes to: ("pose", robot id), ("domain", None), ("state", robot id),
# ("beacon", (tx, ty)), a beacon tile (every robot's key in it), or ("alive", None), the
# agents' liveliness tokens.
Topic = tuple[str, object]
# Where a message waits for its agent's turn: (kind, the id in its key, its topic), one per
# key (per key and sender in a beacon tile), as a live subscriber's newest sample per key.
Slot = tuple[str, int | None, Topic]


@dataclass(frozen=True)
class BrainWindow:
    """Brains ``ids`` from ``start`` s of the simulated clock for ``length`` s."""

    ids: frozenset[int]
    start: float
    length: float

    def __init__(self, ids: Collection[int], start: float, length: float) -> None:
        object.__setattr__(self, "ids", frozenset(ids))
        object.__setattr__(self, "start", float(start))
        object.__setattr__(self, "length", float(length))
        if not (self.start >= 0.0 and self.length > 0.0):
            raise ValueError(f"{type(self).__name__}: needs start >= 0 and length > 0")

    def covers(self, index: int, t: float) -> bool:
        """Whether brain ``index`` is in the window at ``t``."""
        return index in self.ids and self.start <= t < self.start + self.length


class Stall(BrainWindow):
    """Brains ``ids`` take no turn from ``start`` s of the simulated clock for ``length`` s:
    an agent process that stops stepping for a while (a packed process's brains on a host
    busy elsewhere), their robots running on their last commands until their command
    timeout."""

    def resume(self, index: int, t: float) -> float:
        """When brain ``index``, due at ``t``, takes its turn."""
        return self.start + self.length if self.covers(index, t) else t


class Mute(BrainWindow):
    """The AgentStates and beacons of brains ``ids`` are lost from ``start`` s of the
    simulated clock for ``length`` s, to the other agents and the coordinator alike (a link
    or router that drops them): nobody learns where those robots are but the coordinator,
    from their poses. Their brains run, and hear the others (:meth:`covers`: whether one
    sent at ``t`` is lost)."""


@dataclass
class NetsimResult:
    """t (T,), e_a (T,), trajectories (T, n, 2), wheels (T, n, 2) (the commands held at each
    sample), headings (T, n) rad, the agents' last stats, and when the mission started (s of
    the simulated clock: the warmup's end, or later when the coordinator would wait longer)."""

    t: np.ndarray
    error: np.ndarray
    trajectories: np.ndarray
    wheels: np.ndarray
    headings: np.ndarray
    stats: dict[int, dict] = field(default_factory=dict)
    started: float = math.nan  # s of the simulated clock at which the mission started
    # what was missing from the team's neighbour discovery when it started without it
    # (covswarm.coordinator.monitor.discovery_gaps; empty: nothing known)
    undiscovered: list[str] = field(default_factory=list)
    # id -> the neighbours its agent's last AgentState before the start named
    listed: dict[int, frozenset[int]] = field(default_factory=dict)


def run_netsim(
    scenario: Scenario,
    *,
    agents: int | None = None,
    seed: int = 0,
    duration: float | None = None,
    config: AgentConfig | None = None,
    rate: float = 10.0,
    transit: float = 0.001,
    clock_skew: float = 0.0,
    cmd_timeout: float = 0.5,
    warmup: float = 2.0,
    robot_model: DiffDrive | None = None,
    command_delay: float = 0.0,
    announce_start: bool = True,
    poses: np.ndarray | None = None,
    settle: bool = True,
    pace: float = 1.0,
    turn_gaps: tuple[float, float] | None = None,
    stall: Stall | None = None,
    mute: Mute | None = None,
    hold_after: float | None = None,
    dead: Collection[int] = (),
) -> NetsimResult:
    """Run the mission; ``config`` is every agent's (pose_loss/pose_delay included).

    announce_start: the waiting Domains carry S's start velocities, as the coordinator's do,
    and the robots turn to face S's motion before it starts (False: a coordinator that does
    not say, the robots start as placed).

    The mission starts after ``warmup`` s of "waiting" broadcasts (neighbour discovery, as in
    a real start), and with ``settle`` not before the coordinator would start it: every
    agent's token taken, then held for covswarm.coordinator.monitor.start_settle of the
    slowest agent's time between AgentStates (at 10 Hz 1.5 s, within the 2 s warmup; brains
    stepped at ~1.25 Hz wait longer), and then until the AgentStates heard show no gap in
    the team's neighbour discovery (covswarm.coordinator.monitor.discovery_gaps over the
    robots' true poses), at most DISCOVERY_WAIT s longer (what was still missing then:
    ``undiscovered``; what each agent named: ``listed``). A team some agent of which has
    not declared itself alive starts MAX_START_SETTLE s after the warmup. clock_skew: s
    added to the robots' pose stamps (their host's clock ahead).
    robot_model: the robots' true geometry when it differs from what the agents assume
    (``config.robot``), to measure how model error degrades the agents' prediction.
    command_delay: s between a command's stamp and when the robot acts on it, on top of
    ``transit`` (a slow actuator or command link, which the agents do not see).
    poses: the robots' start poses, (n, 3) x, y (m), heading (rad); None: the scenario's,
    as ``covswarm run`` places them (covswarm.deploy.plan.initial_poses).

    An overloaded host, as a live run on one (docs/scaling.md, "the overloaded start"):
    pace: S runs at this fraction of its script's speed, as the coordinator slows it for a
    team that holds a fraction of its rate (covswarm.coordinator.pace); turn_gaps: (lo, hi)
    s, each brain's next turn comes a gap drawn uniformly in [lo, hi] after its last (its
    first within hi of the start), and each brain is told the gap since its previous turn
    (AgentBrain.pace), as a packed process that cannot hold ``rate`` steps its brains in
    turn; None: every 1 / ``rate`` s; stall: brains that take no turn for a while; mute:
    brains whose AgentStates and beacons are lost for a while (:class:`Mute`).
    hold_after: with ``turn_gaps``, a running brain whose next turn comes more than
    max(``hold_after``, its AgentBrain.command_hold) s after its last stops its robot then
    (AgentBrain.hold), as a packed process does for a brain whose turn is late
    (covswarm.agent.pack.Pack._hold; ``covswarm agent`` holds after 3 periods), but not
    while a ``stall`` has its process stopped; None: the robots drive each command until
    the next or its timeout.

    dead: indices of brains that never run (their agents died before the start): their
    robots stand where placed, their agents' tokens never appear, and the others take them
    as stranded robots (covswarm.agent.brain.AgentBrain.stranded); e_a is the rest's, the
    dead robots still generators of its diagram, as the coordinator takes them.
    """
    from covswarm.deploy.plan import initial_poses
    from covswarm.sim_robot.process import RobotSim
    from covswarm.tvd.coverage import aggregate_error, neighbour_pairs

    n = scenario.agents if agents is None else agents
    standing = np.zeros(n, dtype=bool)
    for index in dead:
        if not (type(index) is int and 0 <= index < n):
            raise ValueError(f"dead: brain indices are integers from 0 to {n - 1}, not {index!r}")
        standing[index] = True
    if standing.all():
        raise ValueError("dead: every brain would be dead; at least one must run")
    if not pace > 0.0:
        raise ValueError(f"pace must be positive, got {pace!r}")
    if turn_gaps is not None and not 0.0 < turn_gaps[0] <= turn_gaps[1]:
        raise ValueError(f"turn_gaps must be 0 < lo <= hi, got {turn_gaps!r}")
    if hold_after is not None and not hold_after > 0.0:
        raise ValueError(f"hold_after must be positive, got {hold_after!r}")
    duration = scenario.duration if duration is None else duration
    config = config or AgentConfig()
    if poses is None:
        poses = initial_poses(scenario, n, seed)
    elif np.shape(poses) != (n, 3):
        raise ValueError(f"poses must be ({n}, 3) x, y, heading, not {np.shape(poses)}")
    decoder = MessageDecoder()
    robots = [
        RobotSim(
            i, tuple(poses[i]), robot=robot_model or config.robot, cmd_timeout=cmd_timeout, now=0.0
        )
        for i in range(n)
    ]
    brains = [AgentBrain(i, config, decoder, clock=lambda: 0.0) for i in range(n)]
    if turn_gaps is not None and hold_after is not None:
        for brain in brains:  # its commands are planned for the stop, as in a pack
            brain.stop_after = hold_after
    impair = [
        PoseImpairment(
            config.pose_loss, config.pose_delay, np.random.default_rng([config.pose_seed, i])
        )
        if config.pose_loss > 0.0 or config.pose_delay > 0.0
        else None
        for i in range(n)
    ]
    # The robots' tokens live from the start; an agent's from when its brain declares it.
    for brain in brains:
        for other in range(n):
            if other != brain.id:
                brain.on_liveliness("robot", other, True)
    # Who follows each topic, and what each agent follows ("state": ids, "beacon": tiles,
    # "stranded": ids whose robots' poses it follows).
    subscribers: dict[Topic, set[int]] = {
        ("domain", None): set(range(n)),
        ("alive", None): set(range(n)),
    }
    for i in range(n):
        subscribers[("pose", i)] = {i}
    follows: list[dict[str, frozenset]] = [
        {"state": frozenset(), "beacon": frozenset(), "stranded": frozenset()} for _ in range(n)
    ]
    # Per agent: the newest unread payload per slot, and the agents whose tokens appeared.
    inbox: list[dict[Slot, bytes]] = [{} for _ in range(n)]
    appeared: list[list[int]] = [[] for _ in range(n)]
    pending: list[tuple[float, int, Topic, str, int | None, bytes]] = []  # (due, order, ...)
    order = 0
    commands: list[tuple[float, int, int, bytes]] = []  # (due, order, robot, payload)

    def send(due: float, topic: Topic, kind: str, key_id: int | None, payload: bytes) -> None:
        nonlocal order
        heapq.heappush(pending, (due, order, topic, kind, key_id, payload))
        order += 1

    def follow(index: int, kind: str, wanted: frozenset) -> None:
        """Agent ``index`` follows exactly ``wanted`` of ``kind`` from now on; the unread
        payloads of the topics it leaves are dropped."""
        held = follows[index][kind]
        if wanted == held:
            return
        box = inbox[index]
        for item in held - wanted:
            topic = (kind, item)
            followers = subscribers[topic]
            followers.discard(index)
            if not followers:
                del subscribers[topic]
            for slot in [slot for slot in box if slot[2] == topic]:
                del box[slot]
        for item in wanted - held:
            subscribers.setdefault((kind, item), set()).add(index)
        follows[index][kind] = wanted

    def carry_out(index: int, actions: Iterable[Action], now: float) -> None:
        """What agent ``index``'s brain asked at ``now``, on the simulated network."""
        nonlocal order
        for action in actions:
            if isinstance(action, SendCommand):
                command = action.command
                wheels[index] = (command.left, command.right)
                due = now + transit + command_delay
                heapq.heappush(commands, (due, order, index, command.encode()))
                order += 1
            elif isinstance(action, PublishState):
                if mute is not None and mute.covers(index, now):
                    continue
                if started is None:
                    exchange.add(index, action.state.stamp)
                    listed[index] = frozenset(action.state.neighbors)
                payload = action.state.encode()
                send(now + transit, ("state", index), "state", index, payload)
            elif isinstance(action, PublishBeacon):
                if mute is not None and mute.covers(index, now):
                    continue
                payload = action.beacon.encode()
                send(now + transit, ("beacon", action.tile), "beacon", index, payload)
            elif isinstance(action, FollowStates):
                follow(index, "state", action.ids)
            elif isinstance(action, FollowTiles):
                follow(index, "beacon", action.tiles)
            elif isinstance(action, FollowStranded):
                follow(index, "stranded", action.ids)
            elif isinstance(action, DeclareAlive):
                send(now + transit, ("alive", None), "alive", index, b"")
                tokens.setdefault(index, now + transit)

    rng = np.random.default_rng([seed, 7])
    first_turn = 1.0 / rate if turn_gaps is None else turn_gaps[1]
    agent_phase = rng.uniform(0.0, first_turn, n)
    gap_rng = np.random.default_rng([seed, 11])
    last_turn: dict[int, float] = {}
    events: list[tuple[float, int, str, int]] = []  # (time, order, what, index)
    for i in np.flatnonzero(~standing).tolist():
        due = float(agent_phase[i])
        heapq.heappush(events, (stall.resume(i, due) if stall else due, i, "agent", i))
    heapq.heappush(events, (0.0, -2, "robots", 0))
    heapq.heappush(events, (0.0, -1, "domain", 0))
    # When the mission starts (None: waiting), as the coordinator decides it: the agents'
    # tokens as it takes them (``transit`` s after each DeclareAlive), and their AgentStates'
    # stamps (coordinator.monitor.ExchangeGaps).
    started: float | None = None
    held = False  # the start was held past the warmup's end
    end = math.inf
    tokens: dict[int, float] = {}
    exchange = ExchangeGaps()
    listed: dict[int, frozenset[int]] = {}  # id -> the neighbours its last state names
    pairs, pairs_at = np.empty((0, 2), dtype=np.int64), -math.inf  # cells that meet, when
    undiscovered: list[str] = []
    seq = 0
    wheels = np.zeros((n, 2))
    t_log: list[float] = []
    e_log: list[float] = []
    traj: list[np.ndarray] = []
    heading_log: list[np.ndarray] = []
    wheel_log: list[np.ndarray] = []
    next_sample = warmup
    while events:
        now, rank, what, index = heapq.heappop(events)
        if now > end + 1e-9:
            break
        while commands and commands[0][0] <= now:
            due, _, to, payload = heapq.heappop(commands)
            robots[to].on_command(payload, due, START_WALL + due)
        while pending and pending[0][0] <= now:
            _, _, topic, kind, key_id, payload = heapq.heappop(pending)
            for to in subscribers.get(topic, ()):
                if kind == "alive":
                    appeared[to].append(key_id)
                else:
                    inbox[to][(kind, key_id, topic)] = payload
        wall = START_WALL + now
        if started is None and what == "domain" and now >= warmup:
            if len(tokens) < n - int(standing.sum()):  # (a brain without its pose: no endless wait)
                ready = now >= warmup + MAX_START_SETTLE
            else:
                up = now - max(tokens.values())
                ready = up >= start_settle(exchange.slowest())
                if ready and now - pairs_at >= DISCOVERY_PERIOD:
                    positions = np.array([robot.pose[:2] for robot in robots])
                    pairs_at = now
                    pairs = neighbour_pairs(
                        positions,
                        scenario.domain(0.0)[0],
                        DISCOVERY_EDGE,
                        standing,
                        DISCOVERY_REACH,
                    )
                gaps = discovery_gaps(listed, tokens.keys(), pairs) if ready else []
                if gaps and up < start_settle(exchange.slowest()) + DISCOVERY_WAIT:
                    ready = False
                else:
                    undiscovered = gaps
            if ready or not settle:
                # (on the first tick at the warmup's end: from the warmup's end exactly)
                started = now if held else warmup
                end = started + duration
                next_sample = started
            held = True
        if started is None:
            mission_t, state = 0.0, "waiting"
        else:
            mission_t = min(max(now - started, 0.0), duration)
            state = "running" if now < end else "done"
        if what == "robots":
            for robot in robots:
                robot.step(now)
                pose = robot.pose_message(wall + clock_skew, int(round(now * ROBOT_RATE)))
                payload = pose.encode()
                send(now + transit, ("pose", robot.id), "pose", robot.id, payload)
                if ("stranded", robot.id) in subscribers:
                    send(now + transit, ("stranded", robot.id), "stranded", robot.id, payload)
            heapq.heappush(events, (now + 1.0 / ROBOT_RATE, rank, what, index))
        elif what == "domain":
            vertices, velocities = scenario.domain(pace * mission_t)
            velocities, start = broadcast_motion(state, velocities, pace)
            if not announce_start:
                start = None
            payload = protocol.Domain(
                seq=seq, stamp=wall, t=mission_t, state=state, vertices=vertices,
                velocities=velocities, kappa=scenario.kappa, start_velocities=start,
            ).encode()  # fmt: skip
            seq += 1
            send(now + transit, ("domain", None), "domain", None, payload)
            if state == "running" and now >= next_sample - 1e-9:
                positions = np.array([r.pose[:2] for r in robots])
                t_log.append(mission_t)
                e_log.append(aggregate_error(positions, vertices, still=standing if dead else None))
                traj.append(positions)
                heading_log.append(np.array([r.pose[2] for r in robots]))
                wheel_log.append(wheels.copy())
                next_sample += SAMPLE_PERIOD
            heapq.heappush(events, (now + 1.0 / DOMAIN_RATE, rank, what, index))
        elif what == "hold":  # (planned only when the brain's next turn comes later)
            if brains[index].running:
                carry_out(index, brains[index].hold(now, wall), now)
        else:
            brain = brains[index]
            # What a packed process tells each brain (covswarm.agent.pack): the time since
            # its previous turn, by which it judges its neighbours' states.
            if turn_gaps is None:
                brain.pace(1.0 / rate)
            else:
                brain.pace(now - last_turn.get(index, now - first_turn))
                last_turn[index] = now
            items = [(kind, key_id, payload) for (kind, key_id, _), payload in inbox[index].items()]
            inbox[index].clear()
            if impair[index] is not None:
                items = impair[index].filter(items, now)
            for kind, key_id, payload in items:
                brain.receive(kind, payload, now, wall, key_id)
            # Token changes after the turn's data, as a packed process applies them.
            for other in appeared[index]:
                brain.on_liveliness("agent", other, True)
            appeared[index].clear()
            carry_out(index, brain.tick(now, wall), now)
            if turn_gaps is None:
                due = now + 1.0 / rate
            else:
                due = now + float(gap_rng.uniform(*turn_gaps))
            due = stall.resume(index, due) if stall else due
            if turn_gaps is not None and hold_after is not None and brain.running:
                expires = now + brain.runs_on_for(hold_after)
                if due > expires and (not stall or stall.resume(index, expires) == expires):
                    heapq.heappush(events, (expires, rank, "hold", index))
            heapq.heappush(events, (due, rank, what, index))
    stats = defaultdict(dict, {b.id: b.stats() for b in brains})
    return NetsimResult(
        np.array(t_log), np.array(e_log), np.array(traj), np.array(wheel_log),
        np.array(heading_log), dict(stats), math.nan if started is None else started,
        undiscovered, listed,
    )  # fmt: skip


def steady_state(result: NetsimResult) -> float:
    """Mean e_a over the second half of the mission (as summary.json's)."""
    t, e = result.t, result.error
    if t.size == 0:
        return math.nan
    return float(e[t >= 0.5 * t[-1]].mean())
