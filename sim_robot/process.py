"""``covswarm robot``: one simulated Khepera IV as its own process.

This is the reference implementation of the robot contract that a real-robot bridge must
honour, and agents see nothing else of a robot:

- subscribe to ``covswarm/<swarm>/robot/<id>/cmd`` (WheelCommand, rim speeds in m/s);
- publish ``covswarm/<swarm>/robot/<id>/pose`` (Pose) at ``--pose-rate`` (at REST_POSE_RATE
  until a command first sets its wheels moving: its pose cannot change before);
- declare the liveliness token ``covswarm/<swarm>/alive/robot/<id>`` once ready, and refuse
  to start if another process already claims the same id (runtime.claims.claim).

The robot integrates its kinematics (tvd.drive.integrate, exact arcs; the robots of a
process as one numpy batch, :func:`step_robots`) at ``--rate`` from the last valid command,
each command acting from its stamp within the step (:func:`step_with_commands`), and
stops its wheels when no valid command arrived for ``--cmd-timeout`` seconds (an agent
that dies or stalls must not leave its robot driving).
Invalid commands (undecodable, wrong id, out-of-range or non-finite speeds, stamped more
than ``--max-clock-skew`` ahead of this clock or older than ``--cmd-timeout`` plus that
skew) are dropped, counted per reason and logged rate-limited (protocol.inbound); they
never reach the wheels. Given a world (``RobotSim(world=...)``), its obstacles and workspace
walls are solid: a robot driving into one stops at the contact (covswarm.world.contact).
The process subscribes to the coordinator's World broadcast (``covswarm/<swarm>/world``) and
gives the newest world to all its robots (:class:`WorldHeld`); until one arrives, the floor
is open.

``covswarm robot --ids 0-9 --pose x,y,theta ...`` simulates several robots in one process
(one Zenoh session; each robot keeps its own keys, claim and token), which is how one
machine hosts hundreds of them. ``--time-scale`` runs the simulation slower than real time
(runtime.clock.scaled).

Import-light on purpose (numpy, msgpack, zenoh; no scipy, no matplotlib): a 2-core machine
starts hundreds of these.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import click
import msgpack
import numpy as np
import zenoh

from covswarm import protocol
from covswarm.protocol.inbound import (
    COMMAND_REASONS,
    MAX_CLOCK_SKEW,
    DropLog,
    RateLimit,
    accept_command,
)
from covswarm.protocol.messages import MAX_ANGLE, MAX_COORD, MAX_SEQ, MAX_STAMP, SCHEMA_VERSION
from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.protocol.session import open_session, session_config
from covswarm.runtime import options
from covswarm.runtime.claims import claim_or_refuse
from covswarm.runtime.clock import StopFlag, Ticker, scaled
from covswarm.sim_robot.config import RobotConfig
from covswarm.tvd.drive import KHEPERA_IV, MAX_WHEEL_SPEED, DiffDrive, integrate
from covswarm.world.contact import stop_at_contacts
from covswarm.world.model import World
from covswarm.world.wire import from_message

log = logging.getLogger("covswarm.robot")

# Why a World broadcast was dropped: protocol reasons, geometry the model refuses, or not
# newer than the held one (by sequence number) while its sender still talks.
WORLD_DROP_REASONS = (*protocol.REASONS, "bad_world", "old_world")
# Hz: poses of a robot never driven yet (before the mission: agents command zero wheels
# until it starts). Its pose cannot change, so fewer copies lose nothing, and 1000 robots
# at 20 Hz while the team is still starting (20 000 puts/s through the router, decoded by
# every agent near them) would starve the processes still starting. Four poses per agent
# stale timeout (1 s) keep every robot fresh to its agent and neighbours.
REST_POSE_RATE = 4.0
# s: silence of the held world's sender after which any sequence number is taken (a
# restarted coordinator numbers from 0 again); it repeats its World every second.
WORLD_RESTART_SILENCE = 5.0


@dataclass
class RobotCounters:
    """What happened to the commands a robot received (drops: RobotSim.drops)."""

    commands: int = 0  # valid commands applied
    driven: bool = False  # a command has set non-zero wheels (publish at the full pose rate)
    timeouts: int = 0  # times the wheels were stopped for lack of commands
    contact_stops: int = 0  # steps on which an obstacle or wall stopped the body


class RobotSim:
    """Pure state of one simulated robot: pose, wheels, command timeout. No I/O.

    Times are monotonic seconds supplied by the caller, so tests drive the clock. world: the
    arena whose obstacles and walls stop the body (a disk of ``robot.body_diameter``), None
    for an open floor.
    """

    def __init__(
        self,
        robot_id: int,
        pose: tuple[float, float, float],
        *,
        robot: DiffDrive = KHEPERA_IV,
        cmd_timeout: float = 0.5,
        max_clock_skew: float = MAX_CLOCK_SKEW,
        now: float = 0.0,
        world: World | None = None,
    ) -> None:
        if not (cmd_timeout > 0 and np.isfinite(cmd_timeout)):
            raise ValueError(f"cmd_timeout must be positive, got {cmd_timeout!r}")
        if not np.all(np.isfinite(pose)):
            raise ValueError(f"initial pose must be finite, got {pose!r}")
        if max(abs(pose[0]), abs(pose[1])) > protocol.MAX_COORD:
            # it would start, and then never publish a pose (Pose refuses it)
            raise ValueError(
                f"initial position ({pose[0]:g}, {pose[1]:g}) m is beyond the protocol's "
                f"+-{protocol.MAX_COORD:g} m"
            )
        self.id = protocol.check_id(robot_id)
        self.robot = robot
        self.cmd_timeout = cmd_timeout
        self.max_clock_skew = max_clock_skew
        self.pose = np.array(pose, dtype=float)
        self.world = world
        self.wheels = np.zeros(2)
        self.counters = RobotCounters()
        self.drops = DropLog(log, f"robot {self.id}", COMMAND_REASONS)
        self._last_command = -np.inf  # never: timed out whenever it is stepped
        self._last_step = now

    def on_command(self, payload: object, now: float, now_wall: float) -> bool:
        """Apply a raw WheelCommand payload that arrived at ``now`` (monotonic) and
        ``now_wall`` (s since the epoch), from then on; False if it was dropped."""
        command = self.accept(payload, now_wall)
        if command is None:
            return False
        self.apply(command, now)
        return True

    def accept(self, payload: object, now_wall: float) -> protocol.WheelCommand | None:
        """A raw WheelCommand payload decoded and checked at ``now_wall`` (s since the
        epoch; protocol.inbound.accept_command), or None, the drop counted."""
        return accept_command(
            payload, self.id, now_wall, self.cmd_timeout, self.max_clock_skew, self.drops
        )

    def apply(self, command: protocol.WheelCommand, now: float) -> None:
        """Drive ``command``'s wheels from ``now`` (monotonic s) on: the old wheels until
        then. Not back to the last step: a command must not act before it arrived, which
        the agents predicting their robot from the commands they sent rely on. Stepped to
        ``now`` already (:func:`step_with_commands`): nothing to drive."""
        if now != self._last_step:
            self.step(now)
        # Decoding guarantees finite speeds; the model clamps them to this robot's limit.
        self.wheels = np.array([command.left, command.right])
        moving = command.left != 0.0 or command.right != 0.0
        self.counters.driven = self.counters.driven or moving
        self._last_command = now
        self.counters.commands += 1

    def step(self, now: float) -> np.ndarray:
        """Drive from the previous step to ``now``; returns the new pose (x, y, heading).

        The elapsed time is capped at ``cmd_timeout``: after a stall (an overloaded machine,
        SIGSTOP) the robot must not jump by what it would have driven meanwhile. In a world,
        the move (the chord of the arc) stops at the first contact with an obstacle or wall;
        the heading turns all the same (a disk turning in place moves nothing). One robot
        of :func:`step_robots`.
        """
        return step_robots([self], now)[0]

    def pose_message(self, stamp: float, seq: int) -> protocol.Pose:
        """The current pose as a wire message (ProtocolError if it left the sane bounds)."""
        x, y, theta = (float(v) for v in self.pose)
        return protocol.Pose(id=self.id, x=x, y=y, theta=theta, stamp=stamp, seq=seq)


class PoseSchedule:
    """When a robot process publishes poses: every robot driven so far at ``pose_rate``
    (Hz), and every robot, driven or not, at REST_POSE_RATE (or ``pose_rate`` if lower).
    Sans-IO: times are the caller's monotonic seconds, from ``start``."""

    def __init__(self, pose_rate: float, start: float) -> None:
        self.period = 1.0 / pose_rate
        self.rest_period = max(self.period, 1.0 / REST_POSE_RATE)
        self._next = self._next_rest = start

    def due(self, now: float) -> tuple[bool, bool]:
        """(driven robots publish, every robot publishes) at ``now``; a late tick does not
        make up for the ticks it missed."""
        publish = now >= self._next
        if publish:
            self._next = max(self._next + self.period, now)
        rest = publish and now >= self._next_rest
        if rest:
            self._next_rest = max(self._next_rest + self.rest_period, now)
        return publish, rest


class PosePayloads:
    """The Pose payloads of a process's robots (``ids``, in order), encoded as one numpy
    batch: row by row the bytes of ``RobotSim.pose_message(stamp, seq).encode()``, None for
    a row Pose refuses (out of bounds, not finite). Building and packing a Pose per robot
    cost 4-8 us of CPU a pose, the batch 0.3-0.7 us (500 robots).

    Relies on the wire form of Pose (protocol.messages: a map of "v" and the fields in
    order; msgpack packs a float as 0xcb and 8 big-endian bytes, an int in its shortest
    form): tests/test_robot_process.py compares the bytes with Pose.encode.
    """

    # x, y and theta: the only part that differs between robots besides the id.
    _MIDDLE = np.dtype(
        [("fx", "u1"), ("x", ">f8"), ("ky", "S2"), ("fy", "u1"), ("y", ">f8")]
        + [("kt", "S6"), ("ft", "u1"), ("theta", ">f8")]
    )

    def __init__(self, ids: Sequence[int]) -> None:
        pack = msgpack.Packer(use_bin_type=True).pack
        self._pack = pack
        head = b"\x87" + pack("v") + pack(SCHEMA_VERSION) + pack("id")
        self._heads = [head + pack(protocol.check_id(i)) + pack("x") for i in ids]
        middle = self._middle = np.zeros(len(self._heads), self._MIDDLE)
        middle["fx"] = middle["fy"] = middle["ft"] = 0xCB  # msgpack's float64
        middle["ky"], middle["kt"] = pack("y"), pack("theta")

    def encode(self, poses: np.ndarray, stamp: float, seq: int) -> list[bytes | None]:
        """The payload of each row of ``poses`` ((n, 3) x, y, heading) at ``stamp`` (s since
        the epoch) with sequence number ``seq``."""
        x, y, theta = poses[:, 0], poses[:, 1], poses[:, 2]
        # NaN fails every comparison, an infinity the bound: Pose's checks, as one batch.
        ok = (np.abs(x) <= MAX_COORD) & (np.abs(y) <= MAX_COORD)
        ok &= np.abs(theta) <= MAX_ANGLE
        if not (0.0 <= stamp <= MAX_STAMP and 0 <= seq <= MAX_SEQ):
            ok[:] = False
        middle = self._middle
        middle["x"], middle["y"], middle["theta"] = x, y, theta
        flat, size = middle.tobytes(), middle.itemsize
        tail = self._pack("stamp") + self._pack(float(stamp)) + self._pack("seq") + self._pack(seq)
        return [
            head + flat[k * size : (k + 1) * size] + tail if good else None
            for k, (head, good) in enumerate(zip(self._heads, ok.tolist(), strict=True))
        ]


def step_robots(sims: Sequence[RobotSim], now: float | np.ndarray) -> np.ndarray:
    """Drive every robot of ``sims`` from its previous step to ``now`` (monotonic s: one time
    for all, or (n,), one per robot) as one numpy batch (tvd.drive.integrate, exact arcs,
    each with its own elapsed time and wheels); returns their (n, 3) poses (x m, y m,
    heading rad), row k of ``sims[k]``, which also holds it.

    Per robot this is :meth:`RobotSim.step`: the command timeout, the elapsed time capped at
    ``cmd_timeout``, no motion for a robot stepped already at ``now`` (its command arrived
    this tick) or with stopped wheels, and a world's obstacles and walls stopping the chord
    at the first contact (world.contact.stop_at_contacts, one batch per world).
    A process hosting hundreds of robots pays numpy's per-call cost once per tick instead
    of a scalar integration per robot.
    """
    # The command timeout and the elapsed time as a batch too: a method call per robot was
    # an eighth of the batch's CPU.
    n = len(sims)
    timeouts = np.fromiter((sim.cmd_timeout for sim in sims), float, n)
    since_command = now - np.fromiter((sim._last_command for sim in sims), float, n)
    since_step = now - np.fromiter((sim._last_step for sim in sims), float, n)
    poses = np.array([sim.pose for sim in sims], dtype=float).reshape(-1, 3)
    wheels = np.array([sim.wheels for sim in sims], dtype=float).reshape(-1, 2)
    turning = wheels.any(axis=1)
    for k in np.flatnonzero(turning & ~(since_command <= timeouts)).tolist():
        sims[k].counters.timeouts += 1
        sims[k].wheels = np.zeros(2)
        turning[k] = False
    if isinstance(now, np.ndarray):
        for sim, stepped in zip(sims, now.tolist(), strict=True):
            sim._last_step = stepped
    else:
        for sim in sims:
            sim._last_step = now
    dts = np.minimum(np.maximum(since_step, 0.0), timeouts)
    # Robots with stopped wheels stay where they are (no arc, no contact check): before the
    # mission, that is every robot.
    moving = np.flatnonzero((dts > 0.0) & turning)
    if not moving.size:
        return poses
    robot = sims[0].robot
    if any(sim.robot is not robot and sim.robot != robot for sim in sims):
        raise ValueError("step_robots: the robots of one batch share one model (DiffDrive)")
    moved = integrate(poses[moving], wheels[moving], dts[moving], robot)
    worlds = [sims[k].world for k in moving.tolist()]
    for world in {id(w): w for w in worlds if w is not None}.values():
        # The robots of a process share the world they heard: one batch per world.
        rows = np.array([w is world for w in worlds])
        radius = 0.5 * robot.body_diameter
        moved[rows, :2], hit = stop_at_contacts(
            poses[moving[rows], :2], moved[rows, :2], radius, world
        )
        for k in moving[rows][hit].tolist():
            sims[k].counters.contact_stops += 1
    poses[moving] = moved
    for k, row in zip(moving.tolist(), moved, strict=True):
        sims[k].pose = row
    return poses


def step_with_commands(
    sims: Sequence[RobotSim],
    received: Sequence[tuple[RobotSim, object]],
    now: float,
    now_wall: float,
) -> np.ndarray:
    """One tick of a robot process at ``now`` (monotonic; ``now_wall``: s since the epoch,
    the same instant): ``received``, the raw WheelCommand payloads read since the last tick
    as (robot, payload) pairs in arrival order, each applied from its arrival
    (:meth:`RobotSim.apply`, its robot driven on the old wheels up to then); then every
    robot of ``sims`` driven to ``now`` as one batch (:func:`step_robots`). Returns the
    (n, 3) poses at ``now``.

    A command read at a tick arrived since the last one, when is not known: reading each on
    arrival (a Zenoh callback per command) doubled a robot process's CPU. Its stamp, the
    agent's clock when it sent it, is taken instead, bounded by the robot's last step and
    ``now``: on one host the arrival follows by the transit, a fraction of a millisecond;
    across hosts by the transit and the clocks' offset (up to ``max_clock_skew``, and never
    outside the tick). A real robot acts on a command as it arrives, and so do the agents
    predicting it from the commands they sent (agent.latency); acting at the next 20 Hz tick
    added 0-50 ms of latency they are not told of.

    The same as applying each command alone from its arrival, then stepping the batch: the
    commands go in rounds (each robot's first command of the tick, its second, ...), each
    round's robots driven to their arrivals as one batch. One robot stepped alone per
    command cost a numpy batch of one per command: with 50 robots commanded at 30 Hz, half
    a robot process's CPU.
    """
    pending = []
    for sim, payload in received:
        command = sim.accept(payload, now_wall)
        if command is not None:
            pending.append((sim, command))
    while pending:
        first: list[tuple[RobotSim, protocol.WheelCommand]] = []
        later: list[tuple[RobotSim, protocol.WheelCommand]] = []
        seen: set[int] = set()
        for item in pending:
            (later if id(item[0]) in seen else first).append(item)
            seen.add(id(item[0]))
        arrivals = [
            min(max(now - (now_wall - command.stamp), sim._last_step), now)
            for sim, command in first
        ]
        step_robots([sim for sim, _ in first], np.array(arrivals))
        for (sim, command), arrival in zip(first, arrivals, strict=True):
            sim.apply(command, arrival)
        pending = later
    return step_robots(sims, now)


class WorldHeld:
    """The newest World a robot process heard, as a model (covswarm.world.model.World).

    Sans-IO: feed it raw payloads with the monotonic time of receipt. A repeat of the held
    message refreshes it; a different one is taken if its sequence number is higher, or
    any once the held one's sender has been silent for WORLD_RESTART_SILENCE. Malformed
    payloads and refused geometry are dropped and counted (``drops``), never raised.
    """

    def __init__(self) -> None:
        self.world: World | None = None
        self.drops = DropLog(log, "robot world", WORLD_DROP_REASONS)
        self._message: protocol.World | None = None
        self._received = -np.inf

    def on_payload(self, payload: object, now: float) -> bool:
        """Take a World payload received at ``now``; True if it is (or repeats) the held one."""
        try:
            message = protocol.World.decode(payload)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"world: {exc}")
            return False
        held = self._message
        if held is not None and message.same_world(held):
            self._received = now
            return True
        if held is not None and message.seq <= held.seq:
            if now - self._received < WORLD_RESTART_SILENCE:
                self.drops.drop("old_world", f"world seq {message.seq} <= {held.seq}")
                return False
        try:
            self.world = from_message(message)
        except ValueError as exc:
            self.drops.drop("bad_world", f"world: {exc}")
            return False
        self._message, self._received = message, now
        return True


def drops_line(sims: list[RobotSim]) -> str | None:
    """One log line with every robot's non-zero drop counts per reason, as JSON after a
    fixed prefix (``robot drops {"3": {"undecodable": 2}}``), for the launcher's log and
    whoever gathers it into summary.json; None when nothing was dropped."""

    counts = {
        str(sim.id): {reason: n for reason, n in sorted(sim.drops.counts.items()) if n}
        for sim in sims
        if sim.drops.total
    }
    return None if not counts else DROPS_PREFIX + json.dumps(counts, separators=(",", ":"))


DROPS_PREFIX = "robot drops "


def gather_drops(log_text: str) -> dict[str, dict[str, int]]:
    """Per robot id and reason, the drop counts of every :func:`drops_line` in a robot
    process's log (the launcher puts them in summary.json); malformed lines are skipped."""

    gathered: dict[str, dict[str, int]] = {}
    for line in log_text.splitlines():
        _, found, rest = line.partition(DROPS_PREFIX)
        if not found:
            continue
        try:
            counts = json.loads(rest)
        except ValueError:
            continue
        if not isinstance(counts, dict):
            continue
        for rid, reasons in counts.items():
            if isinstance(reasons, dict):
                mine = gathered.setdefault(str(rid), {})
                for reason, n in reasons.items():
                    if isinstance(n, int):
                        mine[str(reason)] = mine.get(str(reason), 0) + n
    return gathered


def run_robots(
    sims: list[RobotSim],
    swarm: str,
    config: zenoh.Config,
    rate: float,
    pose_rate: float,
    time_scale: float = 1.0,
) -> list[RobotCounters]:
    """Zenoh shell around ``sims``: runs until SIGINT/SIGTERM, returns their counters.

    Several simulated robots may share this process and its one Zenoh session (``covswarm
    robot --ids``), each with its own pose publisher, command subscriber, claim and
    liveliness token, stepped one after the other at ``rate`` Hz of mission time.
    Refuses to start (ClickException) if another process claims one of the ids.
    ``time_scale``: see runtime.clock.scaled (the robots' sims must be started on the
    same scaled monotonic clock).
    """
    stop = StopFlag()
    wall_clock = scaled(time.time, time_scale)
    with open_session(config) as session:
        # Tokens must stay referenced: zenoh undeclares a token when it is collected.
        tokens: list[zenoh.LivelinessToken] = []
        links: list[tuple[RobotSim, zenoh.Publisher, zenoh.Subscriber]] = []
        ticker = Ticker(rate, time_scale=time_scale)
        try:
            for sim in sims:
                tokens.append(claim_or_refuse(session, swarm, "robot", sim.id))
                publisher = session.declare_publisher(
                    protocol.pose_key(swarm, sim.id),
                    congestion_control=zenoh.CongestionControl.DROP,
                )
                # A ring keeps the newest commands without a Python callback thread.
                commands = session.declare_subscriber(
                    protocol.cmd_key(swarm, sim.id), zenoh.handlers.RingChannel(16)
                )
                links.append((sim, publisher, commands))
            # The arena, repeated every second by the coordinator: the newest is enough.
            held = WorldHeld()
            worlds = session.declare_subscriber(
                protocol.world_key(swarm), zenoh.handlers.RingChannel(2)
            )
            for sim in sims:
                tokens.append(
                    session.liveliness().declare_token(protocol.alive_key(swarm, "robot", sim.id))
                )
                log.info("robot %d ready in swarm %s", sim.id, swarm)
            encoder = PosePayloads([sim.id for sim in sims])
            schedule = PoseSchedule(pose_rate, ticker.now())
            seq = 0
            unpublishable = RateLimit()
            while not stop.is_set():
                now = ticker.wait(stop)
                wall = wall_clock()
                publish, rest = schedule.due(now)
                while (sample := worlds.try_recv()) is not None:
                    if held.on_payload(sample.payload.to_bytes(), now):
                        for sim in sims:
                            sim.world = held.world
                received = [
                    (sim, sample.payload.to_bytes())
                    for sim, _, commands in links
                    for sample in iter(commands.try_recv, None)
                ]
                poses = step_with_commands(sims, received, now, wall)
                if not publish:
                    continue
                payloads = encoder.encode(poses, wall, seq)
                for (sim, publisher, _), payload in zip(links, payloads, strict=True):
                    if not (rest or sim.counters.driven):
                        continue
                    try:
                        # A pose the batch refused: Pose says why (ProtocolError).
                        publisher.put(payload or sim.pose_message(wall, seq).encode())
                    except protocol.ProtocolError as exc:
                        if unpublishable.ready():  # once per LOG_INTERVAL, not per tick
                            log.error("robot %d: pose not publishable: %s", sim.id, exc)
                seq += 1
        finally:
            for token in tokens:
                token.undeclare()
        for sim in sims:
            log.info("robot %d stopping: %s, dropped %s", sim.id, sim.counters, sim.drops.summary())
        if (line := drops_line(sims)) is not None:  # a flood shows without --verbose
            log.warning("%s", line)
        log.info("world: %s, dropped %s", "held" if held.world else "none", held.drops.summary())
        log.info("%d ticks, %d overruns", ticker.ticks, ticker.overruns)
    return [sim.counters for sim in sims]


def parse_pose(text: str) -> tuple[float, float, float]:
    """``"x,y,theta"`` -> (x, y, theta); ValueError unless three finite numbers."""
    parts = text.split(",")
    try:
        pose = tuple(float(p) for p in parts)
    except ValueError:
        pose = ()
    if len(pose) != 3 or not all(np.isfinite(pose)):
        raise ValueError(f"pose must be three finite numbers x,y,theta, got {text!r}")
    return pose  # type: ignore[return-value]


@click.command("robot")
@options.id_options("Several robots in this process instead, e.g. 0-9 (one session).")
@options.connect_option(options.ROUTER_HELP)
@options.SWARM_OPTION
@click.option("--x", type=float, default=0.0, show_default=True, help="Initial x (m).")
@click.option("--y", type=float, default=0.0, show_default=True, help="Initial y (m).")
@click.option("--theta", type=float, default=0.0, show_default=True, help="Initial heading.")
@click.option(
    "--pose",
    multiple=True,
    help="With --ids: initial x,y,theta of each robot, in the order of the ids [0,0,0].",
)
# Integration is exact over a step (constant wheels drive an arc) and each command acts from
# its stamp within the step (step_with_commands), so stepping at the pose rate loses
# nothing, and on a machine hosting hundreds of robots every saved tick is CPU the agents
# need.
@options.float_option(
    "--rate", low=1.0, high=options.MAX_RATE, default=20.0, help="Integration steps per second."
)
@options.float_option(
    "--pose-rate",
    low=0.1,
    high=options.MAX_RATE,
    default=20.0,
    help="Poses published per second (fewer before a first command moves the wheels).",
)
@options.float_option(
    "--cmd-timeout", low=0.01, default=0.5, help="No command for this long (s): the wheels stop."
)
@options.TIME_SCALE_OPTION
@options.MAX_CLOCK_SKEW_OPTION
@options.float_option(
    "--max-wheel-speed",
    low=0.0,
    low_open=True,
    default=MAX_WHEEL_SPEED,
    help="Rim speed limit (m/s).",
)
@SECURE_OPTION
@options.VERBOSE_OPTION
def robot_command(**options: Any) -> None:
    """Run one simulated Khepera IV, or several (pose publisher, wheel-command subscriber)."""
    run_robot_process(RobotConfig(**options))


def run_robot_process(config: RobotConfig) -> None:
    """The robot process ``config`` describes: its robots until SIGINT/SIGTERM."""
    logging.basicConfig(level=logging.INFO if config.verbose else logging.WARNING)
    robot_ids = options.id_selection(config.id, config.ids)
    if config.id is not None and config.pose:
        raise click.UsageError("--pose goes with --ids; one robot takes --x/--y/--theta")
    if config.pose and len(config.pose) != len(robot_ids):
        raise click.UsageError(f"{len(robot_ids)} ids but {len(config.pose)} --pose values")
    try:
        protocol.check_swarm(config.swarm)
        initial = [parse_pose(p) for p in config.pose] or [
            (config.x, config.y, config.theta)
        ] * len(robot_ids)
        robot = DiffDrive(max_wheel_speed=config.max_wheel_speed)
        now = scaled(time.monotonic, config.time_scale)()
        sims = [
            RobotSim(
                i,
                pose,
                robot=robot,
                cmd_timeout=config.cmd_timeout,
                max_clock_skew=config.max_clock_skew,
                now=now,
            )
            for i, pose in zip(robot_ids, initial, strict=True)
        ]
        session = session_config(
            list(config.connect), None, "client", secure=config.secure, role="robot", id=robot_ids
        )
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    with watch_expiry(config.secure, "robot", robot_ids):  # its certificate's end stops it
        run_robots(sims, config.swarm, session, config.rate, config.pose_rate, config.time_scale)
