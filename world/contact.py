"""Solid obstacles and walls for simulated robots: a body stops at the first contact.

A robot is a disk of radius r. Over one simulation step its centre moves along the segment
p(t) = start + t (end - start), t in [0, 1]. For a convex obstacle O the signed distance
g(t) = sd(p(t), O) (distance outside, minus the depth inside) is convex in t, so the body
overlaps O, g < r, on one interval of t at most, and the move is cut at the first t where
g reaches r. That t is exact, not bisected: the body touches O exactly when its centre
enters O inflated by r, whose boundary is O's edges pushed out by r along their outward
normals joined by arcs of radius r about its vertices, so the first contact is the earliest
crossing of an offset edge (within the edge's extent) or a vertex circle. Each wall of the
workspace box is a half-plane: the centre stays r inside it.

A body that starts touching or overlapping something (placed there, or resting where it
stopped) may move anywhere that does not take it deeper: by convexity, g(t) >= g(0) along
the whole segment exactly when g's one-sided derivative at 0 is >= 0, so the move is either
whole or nothing (the body stays put; it still turns, a disk turning in place moves nothing).
Robots are not obstacles to each other here: collisions between robots are counted by
covswarm.mission.physical, not prevented.

Unicycles drive arcs; this checks the chord between the step's poses, which departs from the
arc by v dt |omega| dt / 8 at most (0.8 m/s, 3 rad/s, dt 0.05 s: 0.8 mm).
"""

from __future__ import annotations

import numpy as np

from covswarm.tvd.geometry import nearest_points
from covswarm.world.model import Obstacle, World

# m: a body this much beyond its contact distance already counts as resting on the wall, so
# rounding at a stop (the centre a few ulp inside the inflated obstacle) neither blocks a move
# away nor lets a move in slip through.
_RESTING = 1e-12


def stop_at_contacts(
    starts: np.ndarray, ends: np.ndarray, radius: float, world: World
) -> tuple[np.ndarray, np.ndarray]:
    """Where n disk bodies moving from ``starts`` to ``ends`` (n, 2) m stop, and whether each
    was stopped: (positions (n, 2), hit (n,) bool).

    radius: the bodies' radius, m (>= 0). A body that reaches no obstacle or wall ends at
    ``ends`` exactly (the same floats); one that would overlap one stops at the first contact
    along its segment (module docstring). ValueError on non-finite or misshapen input.
    """
    p = np.asarray(starts, dtype=float)
    q = np.asarray(ends, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or q.shape != p.shape:
        raise ValueError(f"starts and ends must both be (n, 2), got {p.shape} and {q.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ValueError("starts and ends must be finite")
    if not (np.isfinite(radius) and radius >= 0.0):
        raise ValueError(f"radius must be a finite number >= 0, got {radius!r}")
    fraction = contact_fractions(p, q, float(radius), world)
    hit = fraction < 1.0
    out = q.copy()
    out[hit] = p[hit] + fraction[hit, None] * (q[hit] - p[hit])
    return out, hit


def stop_at_contact(
    start: np.ndarray, end: np.ndarray, radius: float, world: World
) -> tuple[np.ndarray, bool]:
    """One body: :func:`stop_at_contacts` for start, end (2,) m; (position (2,), hit)."""
    out, hit = stop_at_contacts(
        np.asarray(start, dtype=float).reshape(1, 2),
        np.asarray(end, dtype=float).reshape(1, 2),
        radius,
        world,
    )
    return out[0], bool(hit[0])


def contact_fractions(p: np.ndarray, q: np.ndarray, radius: float, world: World) -> np.ndarray:
    """(n,) the fraction t* in [0, 1] of each move p -> q (n, 2) that the body of ``radius``
    m may drive before its first contact (1: the whole move)."""
    d = q - p
    fraction = np.ones(len(p))
    if world.workspace is not None:
        fraction = np.minimum(fraction, _wall_fractions(p, d, radius, world.workspace))
    if not world.obstacles or len(p) == 0:
        return fraction
    low, high = np.minimum(p, q).min(axis=0), np.maximum(p, q).max(axis=0)
    for j in world.candidates((low[0], high[0], low[1], high[1]), radius):
        fraction = np.minimum(fraction, _obstacle_fractions(p, d, radius, world.obstacles[j]))
    return fraction


def _wall_fractions(
    p: np.ndarray, d: np.ndarray, radius: float, box: tuple[float, float, float, float]
) -> np.ndarray:
    """Per move, the fraction before the body reaches a wall of ``box``: each wall a
    half-plane g = (distance inside it) >= radius, g affine in t with rate ``rate``."""
    xmin, xmax, ymin, ymax = box
    gap = np.stack([p[:, 0] - xmin, xmax - p[:, 0], p[:, 1] - ymin, ymax - p[:, 1]], axis=1)
    rate = np.stack([d[:, 0], -d[:, 0], d[:, 1], -d[:, 1]], axis=1)
    slack = gap - radius
    resting = slack <= _RESTING
    closing = rate < 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(closing & ~resting, slack / -np.where(closing, rate, -1.0), np.inf)
    t = np.where(closing & resting, 0.0, t)  # deeper from contact: not at all
    return np.clip(t.min(axis=1), 0.0, 1.0)


def _obstacle_fractions(
    p: np.ndarray, d: np.ndarray, radius: float, obstacle: Obstacle
) -> np.ndarray:
    """Per move, the fraction before the body first touches one convex obstacle."""
    v = obstacle.vertices  # (k, 2) CCW
    e = np.roll(v, -1, axis=0) - v
    normal = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
    nearest, distance, inside = nearest_points(p, v)
    # Signed distance at the start: the distance outside, the (negative) depth inside.
    depth = np.einsum("nkj,kj->nk", p[:, None, :] - v[None], normal)  # n_i . (p - a_i)
    signed = np.where(inside, depth.max(axis=1), distance)
    rate = d @ normal.T  # (n, k): n_i . d
    # One-sided derivative of the signed distance along d at t = 0: along the unit vector
    # from the nearest point outside, the largest over the deepest edges' normals inside.
    with np.errstate(divide="ignore", invalid="ignore"):
        outward = np.einsum("nj,nj->n", p - nearest, d) / distance
    deepest = depth >= depth.max(axis=1, keepdims=True) - _RESTING
    inward_rate = np.where(deepest, rate, -np.inf).max(axis=1)
    slope = np.where(inside | (distance == 0.0), inward_rate, outward)
    resting = signed - radius <= _RESTING
    fraction = np.where(resting & (slope < 0.0), 0.0, 1.0)
    free = ~resting
    if np.any(free):
        fraction[free] = np.minimum(1.0, _entry_time(p[free], d[free], radius, v, e, normal))
    return fraction


def _entry_time(
    p: np.ndarray, d: np.ndarray, radius: float, v: np.ndarray, e: np.ndarray, normal: np.ndarray
) -> np.ndarray:
    """(n,) first t >= 0 at which p + t d (n, 2), starting more than ``radius`` from the
    obstacle, enters it inflated by ``radius``: the earliest crossing of an offset edge line
    n_i . (x - a_i) = r within edge i's extent, or of a vertex circle |x - a_i| = r; inf if
    never."""
    rel = p[:, None, :] - v[None]  # (n, k, 2): p - a_i
    # Offset edges, crossed from outside (above r) while closing in.
    above = np.einsum("nkj,kj->nk", rel, normal) - radius
    rate = d @ normal.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_edge = np.where((rate < 0.0) & (above >= 0.0), above / -rate, np.inf)
    at = rel + np.where(np.isfinite(t_edge), t_edge, 0.0)[..., None] * d[:, None, :]
    along = np.einsum("nkj,kj->nk", at, e) / np.einsum("kj,kj->k", e, e)
    t_edge = np.where((along >= 0.0) & (along <= 1.0), t_edge, np.inf)
    # Vertex circles: the smaller root of |rel + t d|^2 = r^2.
    a = np.einsum("nj,nj->n", d, d)[:, None]
    b = np.einsum("nkj,nj->nk", rel, d)
    c = np.einsum("nkj,nkj->nk", rel, rel) - radius**2
    disc = b * b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        root = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    t_vertex = np.where((a > 0.0) & (disc >= 0.0) & (root >= 0.0), root, np.inf)
    return np.minimum(t_edge.min(axis=1), t_vertex.min(axis=1))
