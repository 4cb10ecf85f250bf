"""What ``covswarm bridge ros2 --publish-state`` shows ROS 2 tools: S(t), poses, e_a. No I/O.

Kept from the swarm's own traffic: the coordinator's newest Domain (the vertices of S(t)),
its newest Status (e_a), and every robot's newest Pose; each is dropped and counted when
malformed (protocol decoders), and a robot whose pose is older than ``pose_timeout``
(monotonic s, from receipt) leaves the PoseArray.
"""

from __future__ import annotations

import logging

import numpy as np

from covswarm import protocol
from covswarm.protocol.inbound import DropLog

log = logging.getLogger("covswarm.bridge")


class MissionView:
    """The newest S(t), e_a and robot poses of one swarm."""

    def __init__(self, pose_timeout: float = 1.0) -> None:
        self.pose_timeout = pose_timeout
        self.drops = DropLog(log, "bridge state view", protocol.REASONS)
        self._vertices: np.ndarray | None = None
        self._error: float | None = None
        self._poses: dict[int, tuple[float, tuple[float, float, float]]] = {}

    def on_domain(self, payload: bytes) -> None:
        try:
            domain = protocol.Domain.decode(payload)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"domain: {exc}")
            return
        self._vertices = np.array(domain.vertices, dtype=float)

    def on_status(self, payload: bytes) -> None:
        try:
            status = protocol.Status.decode(payload)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"status: {exc}")
            return
        self._error = status.error

    def on_pose(self, payload: bytes, now: float) -> None:
        try:
            pose = protocol.Pose.decode(payload)
        except protocol.ProtocolError as exc:
            self.drops.drop(exc.reason, f"pose: {exc}")
            return
        self._poses[pose.id] = (now, (pose.x, pose.y, pose.theta))

    def polygon(self) -> np.ndarray | None:
        """(k, 2) vertices of the newest S(t), m; None before the first Domain."""
        return self._vertices

    def error(self) -> float | None:
        """The newest e_a (m) the coordinator reported; None before its first Status."""
        return self._error

    def poses(self, now: float) -> np.ndarray:
        """(n, 3) x, y, theta of every robot heard from within ``pose_timeout``, by id."""
        fresh = sorted((rid, pose) for rid, (t, pose) in self._poses.items()
                       if now - t <= self.pose_timeout)  # fmt: skip
        return np.array([pose for _, pose in fresh], dtype=float).reshape(-1, 3)
