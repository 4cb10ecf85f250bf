"""``covswarm robot``: one simulated Khepera IV as its own process.

This is the reference implementation of the robot contract that a real-robot bridge must
honour, and agents see nothing else of a robot:

- subscribe to ``covswarm/<swarm>/robot/<id>/cmd`` (WheelCommand, rim speeds in m/s);
- publish ``covswarm/<swarm>/robot/<id>/pose`` (Pose) at ``--pose-rate``;
- declare the liveliness token ``covswarm/<swarm>/alive/robot/<id>`` once ready, and refuse
  to start if another process already claims the same id (protocol.session.claim).

The robot integrates its kinematics (sim_robot.model.integrate, exact arcs) at ``--rate``
from the last valid command and stops its wheels when no valid command arrived for
``--cmd-timeout`` seconds (an agent that dies or stalls must not leave its robot driving).
Invalid commands (undecodable, wrong id, out-of-range or non-finite speeds, stamped more
than ``--max-clock-skew`` ahead of this clock or older than ``--cmd-timeout`` plus that
skew) are dropped, counted per reason and logged rate-limited (protocol.inbound); they
never reach the wheels.

Import-light on purpose (numpy, msgpack, zenoh; no scipy, no matplotlib): a 2-core machine
starts hundreds of these.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import click
import numpy as np
import zenoh

import protocol
from agent.drive import KHEPERA_IV, DiffDrive
from protocol.inbound import MAX_CLOCK_SKEW, STAMP_REASONS, DropLog, RateLimit, check_stamp
from protocol.security import SECURE_OPTION
from protocol.session import StopFlag, Ticker, claim, session_config
from sim_robot.model import integrate

log = logging.getLogger("covswarm.robot")

# Why a command was dropped: protocol reasons, the clock policy, or addressed to another id.
DROP_REASONS = (*protocol.REASONS, *STAMP_REASONS, "wrong_id")


@dataclass
class RobotCounters:
    """What happened to the commands a robot received (drops: RobotSim.drops)."""

    commands: int = 0  # valid commands applied
    timeouts: int = 0  # times the wheels were stopped for lack of commands


class RobotSim:
    """Pure state of one simulated robot: pose, wheels, command timeout. No I/O.

    Times are monotonic seconds supplied by the caller, so tests drive the clock.
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
    ) -> None:
        if not (cmd_timeout > 0 and np.isfinite(cmd_timeout)):
            raise ValueError(f"cmd_timeout must be positive, got {cmd_timeout!r}")
        if not np.all(np.isfinite(pose)):
            raise ValueError(f"initial pose must be finite, got {pose!r}")
        self.id = protocol.check_id(robot_id)
        self.robot = robot
        self.cmd_timeout = cmd_timeout
        self.max_clock_skew = max_clock_skew
        self.pose = np.array(pose, dtype=float)
        self.wheels = np.zeros(2)
        self.counters = RobotCounters()
        self.drops = DropLog(log, f"robot {self.id}", DROP_REASONS)
        self._last_command: float | None = None
        self._last_step = now

    def on_command(self, payload: object, now: float, now_wall: float) -> bool:
        """Apply a raw WheelCommand payload received at ``now`` (monotonic) and ``now_wall``
        (s since the epoch); False if it was dropped."""
        try:
            command = protocol.WheelCommand.decode(payload)
            check_stamp(command.stamp, now_wall, self.cmd_timeout, self.max_clock_skew)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"command: {exc}")
            return False
        if command.id != self.id:
            self.drops.drop("wrong_id", f"command for robot {command.id}")
            return False
        # Decoding guarantees finite speeds; the model clamps them to this robot's limit.
        self.wheels = np.array([command.left, command.right])
        self._last_command = now
        self.counters.commands += 1
        return True

    def step(self, now: float) -> np.ndarray:
        """Drive from the previous step to ``now``; returns the new pose (x, y, heading).

        The elapsed time is capped at ``cmd_timeout``: after a stall (an overloaded machine,
        SIGSTOP) the robot must not jump by what it would have driven meanwhile.
        """
        commanded = self._last_command is not None and now - self._last_command <= self.cmd_timeout
        if not commanded and self.wheels.any():
            self.counters.timeouts += 1
            self.wheels = np.zeros(2)
        dt = min(max(now - self._last_step, 0.0), self.cmd_timeout)
        self._last_step = now
        if dt > 0.0:
            self.pose = integrate(self.pose[None], self.wheels[None], dt, self.robot)[0]
        return self.pose

    def pose_message(self, stamp: float, seq: int) -> protocol.Pose:
        """The current pose as a wire message (ProtocolError if it left the sane bounds)."""
        x, y, theta = (float(v) for v in self.pose)
        return protocol.Pose(id=self.id, x=x, y=y, theta=theta, stamp=stamp, seq=seq)


def run_robot(
    sim: RobotSim,
    swarm: str,
    config: zenoh.Config,
    rate: float,
    pose_rate: float,
) -> RobotCounters:
    """Zenoh shell around ``sim``: runs until SIGINT/SIGTERM, returns the counters.

    Refuses to start (ClickException) if another process claims the same robot id.
    """
    stop = StopFlag()
    alive = protocol.alive_key(swarm, "robot", sim.id)
    with zenoh.open(config) as session:
        # The token must stay referenced: zenoh undeclares a token when it is collected.
        claimed = claim(session, swarm, "robot", sim.id)
        if claimed is None:
            raise click.ClickException(f"robot {sim.id} is already running in swarm {swarm!r}")
        publisher = session.declare_publisher(
            protocol.pose_key(swarm, sim.id), congestion_control=zenoh.CongestionControl.DROP
        )
        # A ring keeps the newest commands without a Python callback thread; drained per tick.
        commands = session.declare_subscriber(
            protocol.cmd_key(swarm, sim.id), zenoh.handlers.RingChannel(16)
        )
        token = session.liveliness().declare_token(alive)
        log.info("robot %d ready in swarm %s", sim.id, swarm)
        ticker = Ticker(rate)
        pose_period = 1.0 / pose_rate
        next_pose = time.monotonic()
        seq = 0
        unpublishable = RateLimit()
        try:
            while not stop.is_set():
                now = ticker.wait(stop)
                wall = time.time()
                while (sample := commands.try_recv()) is not None:
                    sim.on_command(sample.payload.to_bytes(), now, wall)
                sim.step(now)
                if now >= next_pose:
                    next_pose = max(next_pose + pose_period, now)
                    try:
                        publisher.put(sim.pose_message(wall, seq).encode())
                        seq += 1
                    except protocol.ProtocolError as exc:
                        if unpublishable.ready():  # once per LOG_INTERVAL, not per tick
                            log.error("robot %d: pose not publishable: %s", sim.id, exc)
        finally:
            token.undeclare()
            claimed.undeclare()
        log.info(
            "robot %d stopping: %s, dropped %s, %d ticks, %d overruns",
            sim.id,
            sim.counters,
            sim.drops.summary(),
            ticker.ticks,
            ticker.overruns,
        )
    return sim.counters


@click.command("robot")
@click.option("--id", "robot_id", type=click.IntRange(0, protocol.MAX_ID), required=True)
@click.option(
    "--connect", multiple=True, required=True, help="Router endpoint, e.g. tcp/127.0.0.1:7447."
)
@click.option("--swarm", default="default", show_default=True, help="Swarm (run) name.")
@click.option("--x", type=float, default=0.0, show_default=True, help="Initial x (m).")
@click.option("--y", type=float, default=0.0, show_default=True, help="Initial y (m).")
@click.option("--theta", type=float, default=0.0, show_default=True, help="Initial heading.")
@click.option("--rate", type=click.FloatRange(min=1.0), default=50.0, show_default=True)
@click.option("--pose-rate", type=click.FloatRange(min=0.1), default=20.0, show_default=True)
@click.option("--cmd-timeout", type=click.FloatRange(min=0.01), default=0.5, show_default=True)
@click.option(
    "--max-clock-skew",
    type=click.FloatRange(min=0.0),
    default=MAX_CLOCK_SKEW,
    show_default=True,
    help="Drop commands stamped more than this (s) ahead of this clock.",
)
@click.option(
    "--max-wheel-speed",
    type=click.FloatRange(min=0.0, min_open=True),
    default=0.8,
    show_default=True,
    help="Rim speed limit (m/s).",
)
@SECURE_OPTION
@click.option("--verbose", is_flag=True, help="Log at INFO level.")
def robot_command(
    robot_id: int,
    connect: tuple[str, ...],
    swarm: str,
    x: float,
    y: float,
    theta: float,
    rate: float,
    pose_rate: float,
    cmd_timeout: float,
    max_clock_skew: float,
    max_wheel_speed: float,
    secure: Path | None,
    verbose: bool,
) -> None:
    """Run one simulated Khepera IV (pose publisher, wheel-command subscriber)."""
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING)
    try:
        protocol.check_swarm(swarm)
        robot = DiffDrive(max_wheel_speed=max_wheel_speed)
        sim = RobotSim(
            robot_id,
            (x, y, theta),
            robot=robot,
            cmd_timeout=cmd_timeout,
            max_clock_skew=max_clock_skew,
            now=time.monotonic(),
        )
        config = session_config(list(connect), None, "client", secure=secure)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    run_robot(sim, swarm, config, rate, pose_rate)
