"""Convex-polygon geometry for the world model: obstacles, S against obstacles, barrier rows.

Pure numpy. A polygon is a (k, 2) float array of vertices in metres, counter-clockwise (CCW),
the last vertex not repeating the first. Every function here takes convex polygons as
returned by `validate_convex`; none re-checks convexity (the callers validate once at load).
"""

from __future__ import annotations

import numpy as np

# Relative tolerance of the convexity and collinearity tests: a cross product smaller than
# this times the squared size of the polygon counts as zero (rounding in map coordinates).
_REL_EPS = 1e-12


def area(polygon: np.ndarray) -> float:
    """Area (m^2) of a simple polygon (k, 2) by the shoelace formula; 0 for fewer than 3 vertices.

    Positive for either orientation (the absolute value of the signed area).
    """
    p = np.asarray(polygon, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0


def validate_convex(vertices: object) -> np.ndarray:
    """A convex polygon as a (k, 2) CCW float array, or ValueError saying why it is not one.

    Accepted: k >= 3 finite (x, y) pairs in metres forming a convex polygon of positive area,
    in either orientation. A clockwise polygon is reoriented (reversed) to CCW, since the
    orientation carries no meaning in a file; collinear and repeated vertices are dropped (they
    change no point of the polygon). Refused: not a list of pairs, non-finite values, fewer
    than 3 distinct vertices, zero area, a reflex corner or a self-intersecting outline
    (the turning sum of a convex outline is exactly one turn).
    """
    try:
        p = np.array(vertices, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"vertices must be a list of [x, y] numbers ({exc})") from None
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"vertices must be a list of [x, y] pairs, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("vertices must be finite numbers")
    if len(p) < 3:
        raise ValueError(f"a polygon needs at least 3 vertices, got {len(p)}")
    scale = float(np.ptp(p, axis=0).max())
    if scale == 0.0:
        raise ValueError("the polygon has zero area (all vertices coincide)")
    if _signed_area(p) < 0.0:
        p = p[::-1]
    eps = _REL_EPS * scale * scale
    # Drop repeated then collinear vertices until none is left (each pass may expose another).
    while True:
        nxt = np.roll(p, -1, axis=0)
        keep = np.linalg.norm(nxt - p, axis=1) > 1e-12 * scale
        p = p[keep]
        if len(p) < 3:
            raise ValueError("the polygon has zero area (fewer than 3 distinct vertices)")
        prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        e1, e2 = p - prev, nxt - p
        cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        straight = (np.abs(cross) <= eps) & (np.einsum("ij,ij->i", e1, e2) > 0.0)
        if not straight.any():
            break
        p = p[~straight]
        if len(p) < 3:
            raise ValueError("the polygon has zero area (its vertices are collinear)")
    if np.any(cross <= eps):
        raise ValueError("the polygon is not convex (a corner turns the wrong way or folds back)")
    turning = np.arctan2(cross, np.einsum("ij,ij->i", e1, e2)).sum()
    if not np.isclose(turning, 2.0 * np.pi, atol=1e-6):
        raise ValueError("the polygon is not convex (its outline winds more than once)")
    if _signed_area(p) <= eps:
        raise ValueError("the polygon has zero area")
    return np.ascontiguousarray(p)


def _edges(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(polygon, dtype=float)
    return a, np.roll(a, -1, axis=0) - a


def nearest_points(
    points: np.ndarray, polygon: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest point of a convex polygon (k, 2) to each of `points` (n, 2), metres.

    Returns (nearest (n, 2), distance (n,), inside (n,) bool). A point inside the polygon or
    on its boundary is its own nearest point, distance 0, inside True. Vectorised: O(n k).
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    a, d = _edges(polygon)
    rel = p[:, None, :] - a[None, :, :]  # (n, k, 2)
    cross = d[None, :, 0] * rel[..., 1] - d[None, :, 1] * rel[..., 0]
    inside = np.all(cross >= 0.0, axis=1)
    t = np.clip(np.einsum("nkj,kj->nk", rel, d) / np.einsum("kj,kj->k", d, d), 0.0, 1.0)
    q = a[None, :, :] + t[..., None] * d[None, :, :]  # (n, k, 2)
    d2 = np.einsum("nkj,nkj->nk", p[:, None, :] - q, p[:, None, :] - q)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(p))
    nearest = q[rows, best]
    distance = np.sqrt(d2[rows, best])
    nearest[inside] = p[inside]
    distance[inside] = 0.0
    return nearest, distance, inside


def point_polygon_distance_grad(point: np.ndarray, polygon: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed distance h (m) from `point` (2,) to a convex polygon (k, 2), and grad h (2,).

    Outside: h = |p - q| with q the nearest point of the polygon, grad h = (p - q) / h, the
    unit vector from q to p (h is convex and differentiable there). On the boundary and
    inside: h = max_i n_i . (p - a_i) <= 0, minus the depth to the nearest edge line, and
    grad h = n_i, the outward unit normal of that edge (at a corner, the first edge of the
    maximum). So h is continuous, negative inside, and its gradient always points away from
    the polygon: a barrier row grad h . u >= -gamma (h - r) pushes a robot out, never in.
    """
    p = np.asarray(point, dtype=float).reshape(2)
    nearest, dist, inside = nearest_points(p[None, :], polygon)
    if not inside[0] and dist[0] > 0.0:
        return float(dist[0]), (p - nearest[0]) / dist[0]
    a, d = _edges(polygon)
    normals = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    depth = np.einsum("kj,kj->k", normals, p[None, :] - a)
    i = int(np.argmax(depth))
    return float(min(depth[i], 0.0)), normals[i]


def polygons_intersect(a: np.ndarray, b: np.ndarray, tolerance: float = 0.0) -> bool:
    """Whether convex polygons a (k, 2) and b (m, 2) share a point (separating-axis test).

    Touching counts as intersecting; so does a gap of at most `tolerance` (m) along every
    edge normal (for convex polygons, the projections on the edge normals decide).
    """
    for poly in (a, b):
        _, d = _edges(poly)
        normals = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
        pa = np.asarray(a, dtype=float) @ normals.T  # (k, axes)
        pb = np.asarray(b, dtype=float) @ normals.T
        if np.any(pa.max(axis=0) + tolerance < pb.min(axis=0)) or np.any(
            pb.max(axis=0) + tolerance < pa.min(axis=0)
        ):
            return False
    return True


def polygon_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (m) between convex polygons a and b: 0 when they intersect.

    Otherwise the closest pair involves a vertex of one and an edge of the other, so the
    minimum of the vertex-to-polygon distances both ways is exact.
    """
    if polygons_intersect(a, b):
        return 0.0
    return float(min(nearest_points(a, b)[1].min(), nearest_points(b, a)[1].min()))


def clip_halfplane(polygon: np.ndarray, start: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The part (j, 2) of a convex polygon (k, 2) on the left of (or on) the directed line
    through ``start`` (2,) along ``direction`` (2,): one Sutherland–Hodgman step.

    Shape (0, 2) when nothing is left.
    """
    out = np.asarray(polygon, dtype=float).reshape(-1, 2)
    if len(out) == 0:
        return out
    side = direction[0] * (out[:, 1] - start[1]) - direction[1] * (out[:, 0] - start[0])
    nxt_side = np.roll(side, -1)
    nxt = np.roll(out, -1, axis=0)
    pieces = []
    for j in range(len(out)):
        if side[j] >= 0.0:
            pieces.append(out[j])
        if (side[j] >= 0.0) != (nxt_side[j] >= 0.0):
            s = side[j] / (side[j] - nxt_side[j])
            pieces.append(out[j] + s * (nxt[j] - out[j]))
    out = np.array(pieces, dtype=float).reshape(-1, 2)
    return drop_repeats(out)


def drop_repeats(polygon: np.ndarray) -> np.ndarray:
    """Without vertices that repeat their predecessor up to rounding: the direction of so short
    an edge is noise, and a half-plane through it would cut at random."""
    if len(polygon) < 2:
        return polygon
    scale = max(float(np.ptp(polygon, axis=0).max()), 1e-300)
    step = np.linalg.norm(polygon - np.roll(polygon, 1, axis=0), axis=1)
    keep = step > _REL_EPS * 1e3 * scale
    return polygon[keep] if keep.any() else polygon[:1]


def clip_convex(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ∩ b for convex CCW polygons (Sutherland–Hodgman: a clipped by each edge line of b).

    Returns the intersection's vertices (j, 2), CCW; shape (0, 2) when they are disjoint. A
    contact along an edge or at a point may come back as a degenerate polygon of area 0.
    """
    out = np.asarray(a, dtype=float)
    b = drop_repeats(np.asarray(b, dtype=float))
    for start, end in zip(b, np.roll(b, -1, axis=0), strict=True):
        if len(out) == 0:
            break
        out = clip_halfplane(out, start, end - start)
    return out
