"""Poses as the coordinator observes them, turned into timed samples (pure, no I/O).

Robots publish at their own rate and phase; the coordinator drains what arrived once per
tick, sometimes two poses of a robot, sometimes none. So that every observed pose is
recorded (and none twice), each one gets the mission time at which the robot measured it,
from its stamp, and a tick's poses are split into layers: layer k holds each robot's k-th
pose of the tick, so no layer names a robot twice (a viewer's scene entity per robot).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Observation:
    """One decoded pose: robot id, its sequence number, stamp (s, the run's scaled wall
    clock), x, y (m), theta (rad)."""

    id: int
    seq: int
    stamp: float
    x: float
    y: float
    theta: float


@dataclass(frozen=True)
class Layer:
    """Poses of distinct robots: ids (m,) ascending, poses (m, 3) x, y, theta, times (m,)
    mission times (s) at which each was measured."""

    ids: list[int]
    poses: np.ndarray
    times: np.ndarray


def timed_layers(
    observations: Sequence[Observation],
    t: float,
    t_prev: float,
    wall_now: float,
    last_time: Mapping[int, float],
) -> tuple[list[Layer], int]:
    """Split one tick's observations into layers; returns (layers, stale).

    t: the tick's mission time; t_prev: the previous record's (the poses were received in
    between); wall_now: the scaled wall clock at t. A pose measured at stamp s is given
    mission time t - (wall_now - s), clipped to [t_prev, t] (clocks of other hosts may be
    off by a little; a pose is never placed outside the interval it arrived in). A pose not
    later than the robot's ``last_time`` (a repeat or one overtaken in transit) is stale:
    dropped and counted, so each robot's times strictly increase.
    """
    by_robot: dict[int, list[Observation]] = {}
    for obs in observations:
        by_robot.setdefault(obs.id, []).append(obs)
    stale = 0
    timed: dict[int, list[tuple[float, Observation]]] = {}
    for ident, seen in by_robot.items():
        latest = last_time.get(ident, -np.inf)
        kept = []
        for obs in sorted(seen, key=lambda o: o.seq):
            when = min(max(t - (wall_now - obs.stamp), t_prev), t)
            if when <= latest:
                stale += 1
                continue
            kept.append((when, obs))
            latest = when
        if kept:
            timed[ident] = kept
    layers = []
    depth = max((len(v) for v in timed.values()), default=0)
    for k in range(depth):
        ids = sorted(i for i, v in timed.items() if len(v) > k)
        rows = [timed[i][k] for i in ids]
        layers.append(
            Layer(
                ids=ids,
                poses=np.array([[o.x, o.y, o.theta] for _, o in rows], dtype=float),
                times=np.array([when for when, _ in rows], dtype=float),
            )
        )
    return layers, stale
