"""When a moving S first touches an obstacle or leaves the workspace: conservative advancement.

Why stepping by gap / speed never misses a contact. S(t) is the convex hull of its vertices
V_i(t). A point p = sum_i lambda_i V_i(t) of S(t) has the partner sum_i lambda_i V_i(t') in
S(t'), at most max_i |V_i(t') - V_i(t)| <= v |t' - t| away, v a bound on every vertex's speed.
So S(t') lies within v |t' - t| of S(t) (and back), and the distance g(t) from S to an
obstacle changes no faster than v: from g(t) > 0, S cannot touch the obstacle before
t + g(t) / v. Stepping by that much, and stopping when g < tolerance, finds a contact (even
of a wall thinner than any step) at most tolerance / v before it happens, and never after.

The workspace is a box S may rest against (its walls bound S, they are not obstacles); its
test is per vertex and per axis: S leaves it when a vertex is more than ``tolerance`` beyond a
wall. A vertex's x (or y) changes no faster than the bound on the x (y) components of the
vertex velocities, so an S sliding along a wall is not slowed down by that wall.

The speed bounds come from the caller (``speed``: a proven bound, m/s), or from sampling the
motion's exact vertex velocities at ``samples`` + 1 instants, the largest sampled speed and
displacement rate times SPEED_MARGIN: safe for motions whose vertex speeds vary smoothly or
are piecewise constant on pieces longer than the sample spacing (every motion of
covswarm.mission.motion and covswarm.coordinator.steering; a keyframe segment shorter than
(t1 - t0) / samples needs ``speed``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from covswarm.world.model import World

Motion = Callable[[float], tuple[np.ndarray, np.ndarray]]  # t -> (vertices, velocities)

SPEED_MARGIN = 1.5  # sampled speed bounds are multiplied by this (module docstring)
SAMPLES = 256  # instants sampled for the speed bounds and the swept box


@dataclass(frozen=True)
class Contact:
    """The first contact of a motion: mission time (s) and what S touches (an obstacle's name,
    or "workspace")."""

    time: float
    obstacle: str


def first_contact(
    motion: Motion,
    t0: float,
    t1: float,
    world: World,
    *,
    tolerance: float = 1e-4,
    speed: float | None = None,
    samples: int = SAMPLES,
) -> Contact | None:
    """The first instant in [t0, t1] (s) at which S = motion(t)[0] (k, 2, convex CCW) comes
    within ``tolerance`` (m) of an obstacle or has a vertex more than ``tolerance`` outside the
    workspace, and what it touches; None if S stays clear throughout.

    A reported time is at most tolerance / speed before the true contact and never after it;
    between checks S may come within tolerance of an obstacle without touching it, and leave
    the workspace by at most 2 tolerance. ``speed``: a bound (m/s) on every vertex's speed
    over [t0, t1]; None to sample it (module docstring).
    """
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1):
        raise ValueError(f"first_contact: need finite t0 <= t1, got {t0!r}, {t1!r}")
    if not (tolerance > 0.0 and math.isfinite(tolerance)):
        raise ValueError(f"first_contact: tolerance must be a positive number, not {tolerance!r}")
    times = np.linspace(t0, t1, max(int(samples), 1) + 1)
    states = [motion(float(t)) for t in times]
    vertices = [np.asarray(v, dtype=float) for v, _ in states]
    if speed is None:
        axis_speed = _sampled_axis_speed(times, states)
        speed = float(np.hypot(*axis_speed))
    else:
        if not (speed >= 0.0 and math.isfinite(speed)):
            raise ValueError(f"first_contact: speed must be a finite bound >= 0, not {speed!r}")
        axis_speed = np.array([speed, speed])
    # Between samples a point moves at most speed * spacing / 2 from the nearer sample.
    reach = speed * (times[1] - times[0]) / 2.0 + tolerance if len(times) > 1 else tolerance
    stacked = np.concatenate(vertices)
    low, high = stacked.min(axis=0), stacked.max(axis=0)
    rows = world.candidates((low[0], high[0], low[1], high[1]), reach)

    t = float(t0)
    while True:
        polygon = np.asarray(motion(t)[0], dtype=float)
        gap, j = world.obstacle_gap(polygon, rows)
        if gap < tolerance:
            return Contact(t, world.obstacles[j].name)
        walls = _wall_gaps(polygon, world)  # (2,): least room in x and in y, m
        if np.any(walls < -tolerance):
            return Contact(t, "workspace")
        if t >= t1 or speed == 0.0:
            return None
        step = gap / speed
        for room, rate in zip(walls + 2.0 * tolerance, axis_speed, strict=True):
            if rate > 0.0:
                step = min(step, room / rate)
        t = min(t + step, float(t1))


def _sampled_axis_speed(times: np.ndarray, states: list) -> np.ndarray:
    """(2,) bounds (m/s) on |dx/dt| and |dy/dt| of every vertex: the largest sampled exact
    rate and the largest mean rate between samples (vertex counts may change: Morph merges
    coincident vertices, so means use each sample's own bounding values), times SPEED_MARGIN."""
    peak = np.zeros(2)
    counts = {len(v) for v, _ in states}
    if len(counts) == 1:  # one vertex count throughout: all at once
        vertices = np.array([v for v, _ in states], dtype=float)  # (samples, k, 2)
        velocities = np.array([u for _, u in states], dtype=float)
        if not np.all(np.isfinite(velocities)):
            raise ValueError("first_contact: the motion gives non-finite vertex velocities")
        peak = np.abs(velocities).max(axis=(0, 1))
        dt = np.diff(times)[:, None, None]
        moved = np.abs(np.diff(vertices, axis=0)) / np.where(dt > 0.0, dt, np.inf)
        return SPEED_MARGIN * np.maximum(peak, moved.max(axis=(0, 1)))
    for _, velocities in states:
        v = np.asarray(velocities, dtype=float)
        if not np.all(np.isfinite(v)):
            raise ValueError("first_contact: the motion gives non-finite vertex velocities")
        peak = np.maximum(peak, np.abs(v).max(axis=0))
    for (a, _), (b, _), dt in zip(states[:-1], states[1:], np.diff(times), strict=True):
        if dt > 0.0 and len(a) == len(b):
            peak = np.maximum(peak, np.abs(np.asarray(b) - np.asarray(a)).max(axis=0) / dt)
    return SPEED_MARGIN * peak


def _wall_gaps(polygon: np.ndarray, world: World) -> np.ndarray:
    """(2,) how far S's vertices are inside the workspace in x and in y (negative: outside)."""
    if world.workspace is None:
        return np.array([math.inf, math.inf])
    xmin, xmax, ymin, ymax = world.workspace
    x, y = polygon[:, 0], polygon[:, 1]
    return np.array(
        [min((x - xmin).min(), (xmax - x).min()), min((y - ymin).min(), (ymax - y).min())]
    )
