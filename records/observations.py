"""Poses as the coordinator observes them, turned into timed samples (pure, no I/O).

Robots publish at their own rate and phase; the coordinator drains what arrived once per
tick, sometimes two poses of a robot, sometimes none. So that every observed pose is
recorded (and none twice), each one gets the mission time at which the robot measured it,
from its stamp, and a tick's poses are split into layers: layer k holds each robot's k-th
pose of the tick, so no layer names a robot twice (a viewer's scene entity per robot).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Layer:
    """Poses of distinct robots: ids (m,) ascending, poses (m, 3) x, y, theta, times (m,)
    mission times (s) at which each was measured."""

    ids: list[int]
    poses: np.ndarray
    times: np.ndarray


def timed_layers(
    observations: np.ndarray,
    t: float,
    t_prev: float,
    wall_now: float,
    last_time: Mapping[int, float],
) -> tuple[list[Layer], int]:
    """Split one tick's observations into layers; returns (layers, stale).

    observations: (m, 6) rows id, seq, stamp (s, the run's scaled wall clock), x, y (m),
    theta (rad), in any order; t: the tick's mission time; t_prev: the previous record's
    (the poses were received in between); wall_now: the scaled wall clock at t. A pose
    stamped s is given mission time t - (wall_now - s), clipped to [t_prev, t] (clocks of
    other hosts may be off by a little; a pose is never placed outside the interval it
    arrived in). A pose not later than the robot's ``last_time`` or its previous pose (a
    repeat, or one overtaken in transit) is stale: dropped and counted, so each robot's
    times strictly increase. Vectorised: this runs at the team's pose rate.
    """
    rows = np.asarray(observations, dtype=float).reshape(-1, 6)
    if not len(rows):
        return [], 0
    rows = rows[np.lexsort((rows[:, 1], rows[:, 0]))]  # by robot, then sequence number
    ids = rows[:, 0].astype(np.int64)
    when = np.clip(t - (wall_now - rows[:, 2]), t_prev, t)
    first = np.r_[True, ids[1:] != ids[:-1]]
    group = np.cumsum(first) - 1
    floor = np.array([last_time.get(int(i), -np.inf) for i in ids[first]])[group]
    # The latest time before each pose within its robot's run: a running maximum per group
    # (groups offset by more than the times' range so that one never leaks into the next).
    span = t - t_prev + 1.0
    running = np.maximum.accumulate(when + group * span) - group * span
    before = np.r_[-np.inf, running[:-1]]
    before[first] = -np.inf
    keep = when > np.maximum(floor, before)
    stale = int(np.count_nonzero(~keep))
    rows, ids, when, group = rows[keep], ids[keep], when[keep], group[keep]
    if not len(rows):
        return [], stale
    first = np.r_[True, group[1:] != group[:-1]]
    rank = np.arange(len(rows)) - np.maximum.accumulate(np.where(first, np.arange(len(rows)), 0))
    layers = [
        Layer(ids=ids[rank == k].tolist(), poses=rows[rank == k, 3:6], times=when[rank == k])
        for k in range(int(rank.max()) + 1)
    ]
    return layers, stale
