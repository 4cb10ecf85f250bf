"""One ROS 2 robot standing in for one covswarm robot: the bridge's sans-IO state machine
(its brain, as agent.brain is the agent's; bridge.process is the Zenoh shell).

covswarm -> ROS 2: an agent's WheelCommand (rim speeds of a differential drive, m/s)
becomes a Twist (v, omega) for the robot's ``cmd_vel``. When no valid command arrived for
``cmd_timeout`` the brain asks for a zero Twist, repeated every ``stop_period`` for
``stop_hold`` seconds (one lost sample must not leave a robot driving), then stays quiet so
that a teleop node can take over between missions.

ROS 2 -> covswarm: a PoseStamped / Pose2D / Odometry payload becomes a covswarm Pose. A
pose is stamped with its header stamp, else the attachment's source timestamp, else its
time of receipt (``stamp_source="receive"`` always takes the time of receipt: for a pose
source whose clock is not the bridge's); poses older than ``pose_max_age``, from more than
``max_clock_skew`` in the future, or malformed are dropped and counted per reason, and so
are the poses of a second publisher on the robot's topic while the first one's are fresh
(``second_source``: two robots or trackers under one id; the robot follows the publisher
it heard first, and the next one once that one is quiet for ``pose_timeout``). The
robot is *visible* (the bridge holds its covswarm liveliness token) while its newest valid
pose is at most ``pose_timeout`` old.

Times: ``now`` monotonic seconds, ``now_wall`` seconds since the epoch, both supplied by the
caller so that tests drive the clock.
"""

from __future__ import annotations

import logging
import math

from covswarm import protocol
from covswarm.bridge import cdr
from covswarm.bridge.rmw_zenoh import decode_attachment
from covswarm.protocol.inbound import (
    COMMAND_REASONS,
    MAX_CLOCK_SKEW,
    DropLog,
    accept_command,
    check_stamp,
)
from covswarm.tvd.drive import KHEPERA_IV, twist_from_wheels

log = logging.getLogger("covswarm.bridge")

# "second_source": a pose from another publisher (GID) on the robot's topic while the one
# it follows is live: two robots or trackers under one id, whose poses mixed would make the
# robot jump between them (covswarm.bridge.brain.RobotBrain.on_pose).
DROP_REASONS = (*COMMAND_REASONS, "attachment", "second_source")
STAMP_SOURCES = ("message", "receive")


class RobotBrain:
    """The bridge's view of one robot: its last command, its newest pose, its drops."""

    def __init__(
        self,
        robot_id: int,
        pose_type: str,
        *,
        axle: float = KHEPERA_IV.wheel_separation,
        cmd_timeout: float = 0.5,
        pose_max_age: float = 0.5,
        pose_timeout: float = 1.0,
        max_clock_skew: float = MAX_CLOCK_SKEW,
        stop_hold: float = 1.0,
        stop_period: float = 0.1,
        stamp_source: str = "message",
    ) -> None:
        if not (axle > 0 and math.isfinite(axle)):
            raise ValueError(f"axle (wheel separation) must be positive, got {axle!r}")
        if pose_type not in cdr.POSE_TYPES.values():
            raise ValueError(
                f"pose type must be one of {sorted(cdr.POSE_TYPES)}, got {pose_type!r}"
            )
        if stamp_source not in STAMP_SOURCES:
            raise ValueError(f"stamp source must be one of {STAMP_SOURCES}, got {stamp_source!r}")
        for name, value in (("cmd_timeout", cmd_timeout), ("pose_max_age", pose_max_age),
                            ("pose_timeout", pose_timeout)):  # fmt: skip
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be positive, got {value!r}")
        self.id = protocol.check_id(robot_id)
        self.pose_type = pose_type
        self.axle = axle
        self.cmd_timeout, self.pose_max_age, self.pose_timeout = (
            cmd_timeout,
            pose_max_age,
            pose_timeout,
        )
        self.max_clock_skew = max_clock_skew
        self.stop_hold, self.stop_period = stop_hold, stop_period
        self.stamp_source = stamp_source
        self.drops = DropLog(log, f"bridge robot {self.id}", DROP_REASONS)
        self.commands = 0  # valid commands received
        self.twists = 0  # Twists asked for, zero ones included
        self.stops = 0  # times the command timeout stopped the robot
        self.poses = 0  # valid poses received
        self._twist: tuple[float, float] | None = None  # from a command not yet sent
        self._last_command: float | None = None
        self._stopped_at: float | None = None
        self._last_zero = -math.inf
        self._pose: cdr.PlanarPose | None = None  # newest valid pose not yet forwarded
        self._last_pose: float | None = None
        self._source: bytes | None = None  # the GID of the publisher whose poses we take

    # covswarm -> ROS 2 ------------------------------------------------------------------
    def on_command(self, payload: bytes, now: float, now_wall: float) -> bool:
        """Take a raw WheelCommand payload; False if it was dropped."""
        command = accept_command(
            payload, self.id, now_wall, self.cmd_timeout, self.max_clock_skew, self.drops
        )
        if command is None:
            return False
        self._twist = twist_from_wheels(command.left, command.right, self.axle)
        self._last_command = now
        self._stopped_at = None
        self.commands += 1
        return True

    def twist(self, now: float) -> tuple[float, float] | None:
        """The (v, omega) to publish now, or None for nothing.

        A new command's twist once; after ``cmd_timeout`` without one, (0, 0) every
        ``stop_period`` for ``stop_hold`` s.
        """
        if self._twist is not None:
            twist, self._twist = self._twist, None
            self.twists += 1
            return twist
        if self._last_command is None:
            return None
        if self._stopped_at is None:
            if now - self._last_command <= self.cmd_timeout:
                return None
            self._stopped_at = now
            self.stops += 1
        if now - self._stopped_at > self.stop_hold or now - self._last_zero < self.stop_period:
            return None
        self._last_zero = now
        self.twists += 1
        return 0.0, 0.0

    # ROS 2 -> covswarm ------------------------------------------------------------------
    def on_pose(
        self, payload: bytes, attachment: bytes | None, now: float, now_wall: float
    ) -> bool:
        """Take a raw CDR pose payload and its rmw_zenoh attachment; False if dropped."""
        source_stamp, gid = None, None
        if attachment is not None:
            try:
                decoded = decode_attachment(attachment)
            except ValueError as exc:
                self.drops.drop("attachment", f"pose: {exc}")
                return False
            source_stamp, gid = decoded.source_timestamp_ns * 1e-9, decoded.gid
        if gid is not None and gid != self._source:
            if self._source is not None and self.visible(now):
                self.drops.drop(
                    "second_source",
                    f"pose from a second publisher ({gid.hex()}) while {self._source.hex()}'s "
                    "are fresh: two robots or trackers under one id?",
                )
                return False
        try:
            pose = cdr.decode_pose(payload, self.pose_type)
            if self.stamp_source == "receive":
                stamp = now_wall
            else:
                stamp = next(s for s in (pose.stamp, source_stamp, now_wall) if s is not None)
            check_stamp(stamp, now_wall, self.pose_max_age, self.max_clock_skew)
            # The covswarm message's own bounds (coordinates, angle) before it is kept.
            protocol.Pose(id=self.id, x=pose.x, y=pose.y, theta=pose.theta, stamp=stamp, seq=0)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"pose: {exc}")
            return False
        self._pose = cdr.PlanarPose(pose.x, pose.y, pose.theta, stamp)
        self._last_pose = now
        if gid is not None:
            self._source = gid
        self.poses += 1
        return True

    def take_pose(self, seq: int) -> protocol.Pose | None:
        """The newest valid pose not yet forwarded, as a covswarm Pose (then forgotten)."""
        pose, self._pose = self._pose, None
        if pose is None:
            return None
        return protocol.Pose(
            id=self.id, x=pose.x, y=pose.y, theta=pose.theta, stamp=pose.stamp, seq=seq
        )

    def visible(self, now: float) -> bool:
        """True while the newest valid pose is at most ``pose_timeout`` old."""
        return self._last_pose is not None and now - self._last_pose <= self.pose_timeout
