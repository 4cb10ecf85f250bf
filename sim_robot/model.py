"""Kinematics of simulated differential-drive robots. Pure numpy, no I/O.

A pose is (x, y, heading) with the heading in radians, wrapped to [-pi, pi). Wheel commands
are rim speeds in m/s (left, right), held constant over a step, so each robot drives an
exact circular arc (a straight segment when both wheels agree).
"""

from __future__ import annotations

import numpy as np

from covswarm.tvd.drive import KHEPERA_IV, DiffDrive


def integrate(
    poses: np.ndarray, wheels: np.ndarray, dt: float, robot: DiffDrive = KHEPERA_IV
) -> np.ndarray:
    """Poses after driving the wheel speeds for dt seconds.

    poses: (n, 3) [x, y, heading]; wheels: (n, 2) [left, right] m/s. Returns a new (n, 3).
    Each wheel is clamped to +-max_wheel_speed on its own, like a motor controller would;
    a non-finite wheel command counts as 0 (the robot stops rather than vanishing).
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    wheels = np.asarray(wheels, dtype=float).reshape(-1, 2)
    if poses.shape[0] != wheels.shape[0]:
        raise ValueError(f"{poses.shape[0]} poses but {wheels.shape[0]} wheel commands")
    wheels = np.where(np.isfinite(wheels), wheels, 0.0)
    wheels = np.clip(wheels, -robot.max_wheel_speed, robot.max_wheel_speed)
    v = 0.5 * (wheels[:, 0] + wheels[:, 1])
    w = (wheels[:, 1] - wheels[:, 0]) / robot.wheel_separation
    heading = poses[:, 2]
    turn = w * dt
    # Chord of the arc: length v dt sin(turn/2)/(turn/2), direction heading + turn/2.
    # np.sinc(x) = sin(pi x)/(pi x) is exact at turn = 0, so no straight-line special case.
    chord = v * dt * np.sinc(turn / (2.0 * np.pi))
    mid = heading + 0.5 * turn
    out = np.empty_like(poses)
    out[:, 0] = poses[:, 0] + chord * np.cos(mid)
    out[:, 1] = poses[:, 1] + chord * np.sin(mid)
    out[:, 2] = (heading + turn + np.pi) % (2.0 * np.pi) - np.pi
    return out
