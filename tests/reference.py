"""Independent reference implementations used to verify tvd.coverage and tvd.control.

Nothing here imports covswarm.*: cells are built with shapely by clipping the domain with one
half-plane polygon per other robot, masses and centroids come from shapely, derivatives from
central finite differences. The conventions are the paper's definition of the cells plus
docs/CONTRACTS.md for degenerate cases:

- a robot exactly coincident with a lower-index robot does not take part in the
  tessellation and has an empty cell;
- every other robot i, inside S or not, gets V_i = S intersected with
  {q : |q - p_i| <= |q - p_j|} for every other participating robot j (the paper's
  V_i = {q in S : |p_i - q| <= |p_j - q| for all j}). A robot outside S thus has an empty
  cell only when every point of S is closer to some other robot;
- an empty cell has mass 0 and centroid = nearest point of S to the robot.

Note: CONTRACTS.md says "Empty cell (robot outside S, or coincident ...)", which read
literally would give every robot outside S an empty cell and drop it from the
tessellation. agent/coverage.py documents (and implements) the paper's definition above,
which is continuous when a robot crosses the boundary of S; these tests follow the paper.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import shapely
from scipy.optimize import linprog, minimize
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import nearest_points

# --------------------------------------------------------------------------------------
# Random geometry
# --------------------------------------------------------------------------------------


def signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def is_strictly_convex(poly: np.ndarray, rel_margin: float = 1e-3) -> bool:
    """CCW polygon with every turn clearly positive (no nearly collinear vertex)."""
    if len(poly) < 3 or signed_area(poly) <= 0:
        return False
    e = np.roll(poly, -1, axis=0) - poly
    e_prev = np.roll(e, 1, axis=0)
    cross = e_prev[:, 0] * e[:, 1] - e_prev[:, 1] * e[:, 0]
    lens = np.linalg.norm(e, axis=1)
    sin_turn = cross / (lens * np.roll(lens, 1))
    diam = np.max(np.linalg.norm(poly[:, None, :] - poly[None, :, :], axis=2))
    if np.min(lens) < 1e-3 * diam:
        return False
    # total turning must be exactly 2 pi (rules out star shapes with positive turns)
    ang = np.arctan2(e[:, 1], e[:, 0])
    turn = np.mod(ang - np.roll(ang, 1), 2 * np.pi)
    return bool(np.all(sin_turn > rel_margin) and abs(np.sum(turn) - 2 * np.pi) < 1e-9)


def random_convex_polygon(
    rng: np.random.Generator,
    k: int | None = None,
    scale: float | None = None,
    offset: float = 5.0,
) -> np.ndarray:
    """A random strictly convex CCW polygon with 3..10 vertices.

    Half the time: random points on a randomly shaped and rotated ellipse (exactly k
    vertices); otherwise the convex hull of random points. Random scale 0.1..100 and a
    random offset of up to `offset` times the scale.
    """
    if scale is None:
        scale = 10 ** rng.uniform(-1, 2)
    for _ in range(1000):
        kk = int(rng.integers(3, 11)) if k is None else k
        if rng.random() < 0.5:
            ang = np.sort(rng.uniform(0, 2 * np.pi, kk))
            gaps = np.diff(np.r_[ang, ang[0] + 2 * np.pi])
            if np.min(gaps) < 0.1 or np.max(gaps) > np.pi - 0.1:
                continue
            a, b = 1.0, rng.uniform(0.2, 1.0)
            pts = np.c_[a * np.cos(ang), b * np.sin(ang)]
        else:
            m = int(rng.integers(max(kk, 3), 3 * kk + 1))
            raw = rng.uniform(-1, 1, (m, 2)) * [1.0, rng.uniform(0.2, 1.0)]
            hull = shapely.MultiPoint(raw).convex_hull
            if hull.geom_type != "Polygon":
                continue
            pts = np.asarray(hull.exterior.coords)[:-1]
            if not 3 <= len(pts) <= 10 or (k is not None and len(pts) != k):
                continue
        th = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        poly = pts @ rot.T * scale + rng.uniform(-offset, offset, 2) * scale
        if signed_area(poly) < 0:
            poly = poly[::-1]
        poly = np.roll(poly, int(rng.integers(len(poly))), axis=0)
        if is_strictly_convex(poly):
            return np.ascontiguousarray(poly, dtype=float)
    raise RuntimeError("could not generate a convex polygon")


def as_cw(polygon: np.ndarray, velocity: np.ndarray | None = None, shift: int = 0):
    """Same polygon in the opposite orientation (and a rolled start vertex)."""
    p = np.roll(polygon[::-1], shift, axis=0).copy()
    if velocity is None:
        return p
    return p, np.roll(velocity[::-1], shift, axis=0).copy()


def scale_of(polygon: np.ndarray) -> float:
    """Diameter of the polygon."""
    d = polygon[:, None, :] - polygon[None, :, :]
    return float(np.max(np.linalg.norm(d, axis=2)))


def random_robots(
    rng: np.random.Generator,
    polygon: np.ndarray,
    n: int,
    outside_fraction: float = 0.0,
    margin: float = 1e-6,
) -> np.ndarray:
    """n robots; about `outside_fraction` of them strictly outside S.

    Robots are kept at least margin * diam(S) away from the boundary of S so that inside /
    outside is unambiguous for any sane tolerance in the code under test.
    """
    S = Polygon(polygon)
    diam = scale_of(polygon)
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    out = np.empty((n, 2))
    i = 0
    while i < n:
        want_out = rng.random() < outside_fraction
        if want_out:
            q = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo))
        else:
            q = rng.uniform(lo, hi)
        pt = Point(q)
        d = S.exterior.distance(pt)
        if d < margin * diam:
            continue
        if S.contains(pt) == want_out:
            continue
        out[i] = q
        i += 1
    return out


# --------------------------------------------------------------------------------------
# Reference tessellation (shapely)
# --------------------------------------------------------------------------------------


def participants(positions: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Boolean mask of robots taking part in the tessellation (not a later duplicate)."""
    n = len(positions)
    active = np.ones(n, dtype=bool)
    for i in range(n):
        if active[i]:
            for j in range(i):
                if (
                    active[j]
                    and positions[j, 0] == positions[i, 0]
                    and (positions[j, 1] == positions[i, 1])
                ):
                    active[i] = False
                    break
    return active


def _halfplane(pi: np.ndarray, pj: np.ndarray, R: float) -> Polygon:
    """Large quadrilateral = {q : |q - pi| <= |q - pj|} within radius ~R of the bisector."""
    m = 0.5 * (pi + pj)
    d = pj - pi
    d = d / np.hypot(d[0], d[1])
    t = np.array([-d[1], d[0]])
    return Polygon([m + R * t, m + R * t - 2 * R * d, m - R * t - 2 * R * d, m - R * t])


def reference_cells(positions: np.ndarray, polygon: np.ndarray) -> list[Polygon | None]:
    """Shapely polygon of each cell, None for an empty cell."""
    positions = np.asarray(positions, dtype=float)
    S = Polygon(polygon)
    active = participants(positions, polygon)
    idx = np.flatnonzero(active)
    c = polygon.mean(axis=0)
    R = 10.0 * (
        np.max(np.linalg.norm(polygon - c, axis=1))
        + np.max(np.linalg.norm(positions - c, axis=1))
        + 1e-300
    )
    out: list[Polygon | None] = [None] * len(positions)
    P = positions[idx]
    m = len(idx)
    if m == 0:
        return out
    # half-plane quadrilaterals for every ordered pair, built in one vectorised call
    mid = 0.5 * (P[:, None, :] + P[None, :, :])
    d = P[None, :, :] - P[:, None, :]
    norm = np.hypot(d[..., 0], d[..., 1])
    norm[norm == 0] = 1.0
    d = d / norm[..., None]
    t = np.stack([-d[..., 1], d[..., 0]], axis=-1)
    quad = np.stack([mid + R * t, mid + R * t - 2 * R * d, mid - R * t - 2 * R * d, mid - R * t])
    halfplanes = shapely.polygons(np.moveaxis(quad, 0, 2))  # (m, m)
    for a, i in enumerate(idx):
        geoms = [S, *np.delete(halfplanes[a], a)]
        cell = shapely.intersection_all(geoms) if m > 1 else S
        if cell.is_empty or cell.area == 0.0:
            continue
        if cell.geom_type != "Polygon":  # may carry degenerate slivers/lines; keep polygon
            polys = [g for g in getattr(cell, "geoms", []) if g.geom_type == "Polygon"]
            cell = max(polys, key=lambda g: g.area)
        out[i] = cell
    return out


def nearest_point(polygon: np.ndarray, p: np.ndarray) -> np.ndarray:
    S = Polygon(polygon)
    pt = Point(p)
    if S.covers(pt):
        return np.array(p, dtype=float)
    return np.array(nearest_points(S.exterior, pt)[0].coords[0])


def reference_mass_centroid(positions: np.ndarray, polygon: np.ndarray):
    cells = reference_cells(positions, polygon)
    n = len(positions)
    mass = np.zeros(n)
    cen = np.zeros((n, 2))
    for i, cell in enumerate(cells):
        if cell is None:
            cen[i] = nearest_point(polygon, positions[i])
        else:
            mass[i] = cell.area
            cen[i] = cell.centroid.coords[0]
    return mass, cen


def shared_boundary_lengths(
    positions: np.ndarray, polygon: np.ndarray, cells: list[Polygon | None] | None = None
) -> dict[tuple[int, int], float]:
    """Length of V_i intersect V_j for i < j whose reference cells touch (within eps).

    Measured as the length of the bisector line inside both cells inflated by eps =
    1e-10 diam(S); exact up to O(eps / sin(angle)) at the ends of the shared edge.
    """
    if cells is None:
        cells = reference_cells(positions, polygon)
    diam = scale_of(polygon)
    eps = 1e-10 * diam
    R = 10.0 * (diam + np.max(np.abs(positions - polygon.mean(axis=0))))
    idx = [i for i, c in enumerate(cells) if c is not None]
    tree = shapely.STRtree([cells[i] for i in idx])
    out: dict[tuple[int, int], float] = {}
    for a, i in enumerate(idx):
        for b in tree.query(cells[i].buffer(eps)):
            j = idx[int(b)]
            if j <= i:
                continue
            if cells[i].distance(cells[j]) > eps:
                continue
            m = 0.5 * (positions[i] + positions[j])
            d = positions[j] - positions[i]
            t = np.array([-d[1], d[0]]) / np.hypot(d[0], d[1])
            line = LineString([m - R * t, m + R * t])
            both = cells[i].buffer(eps).intersection(cells[j].buffer(eps))
            out[(i, j)] = line.intersection(both).length
        del a
    return out


def min_cell_edge(cells: list[Polygon | None]) -> float:
    """Shortest edge over all reference cells (inf if none)."""
    best = np.inf
    for c in cells:
        if c is None:
            continue
        xy = np.asarray(c.exterior.coords)
        e = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        best = min(best, float(np.min(e)))
    return best


def min_pair_distance(positions: np.ndarray) -> float:
    if len(positions) < 2:
        return np.inf
    d = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=2)
    d[np.diag_indices(len(positions))] = np.inf
    return float(np.min(d))


def fd_valid(positions: np.ndarray, polygon: np.ndarray, delta: float = 1e-3) -> bool:
    """Documented criterion for central finite differences to be meaningful.

    Every change of the combinatorial structure of the clipped Voronoi diagram (an edge
    between two cells appearing or vanishing, a polygon vertex passing from one cell to
    another, a Voronoi vertex crossing the boundary of S) makes some cell edge shrink to
    zero length, and a robot crossing the boundary of S switches its cell on or off.
    So FD with a step h << delta * diam(S) is valid when every reference cell edge is
    longer than delta * diam(S), every robot is farther than delta * diam(S) from the
    boundary of S, and no two robots are closer than delta * diam(S).
    """
    diam = scale_of(polygon)
    S = Polygon(polygon)
    if min_pair_distance(positions) < delta * diam:
        return False
    if min(S.exterior.distance(Point(p)) for p in positions) < delta * diam:
        return False
    return min_cell_edge(reference_cells(positions, polygon)) >= delta * diam


# --------------------------------------------------------------------------------------
# Finite differences
# --------------------------------------------------------------------------------------


def fd_jacobian(
    centroid_fn: Callable[[np.ndarray], np.ndarray], positions: np.ndarray, h: float
) -> np.ndarray:
    """Central differences of centroid_fn (positions -> (n,2)), ordering [x0,y0,x1,y1..]."""
    n = len(positions)
    J = np.zeros((2 * n, 2 * n))
    for k in range(2 * n):
        pp = positions.copy()
        pm = positions.copy()
        pp[k // 2, k % 2] += h
        pm[k // 2, k % 2] -= h
        J[:, k] = (centroid_fn(pp) - centroid_fn(pm)).ravel() / (2 * h)
    return J


def random_cov(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """A random SPD 2x2 with determinant sigma^4 (geometric-mean deviation sigma)."""
    a = rng.normal(size=(2, 2))
    m = a @ a.T + 0.3 * np.eye(2)
    return m / np.sqrt(np.linalg.det(m)) * sigma**2


def rot(theta: float) -> np.ndarray:
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


SKEW = np.array([[0.0, -1.0], [1.0, 0.0]])


def motion(kind: str, polygon: np.ndarray, rng: np.random.Generator):
    """A polygon motion P(t) and its exact vertex velocity at t = 0.

    Returns (P: t -> (k,2), V (k,2)). Kinds: translate, scale, rotate, combo (translate +
    scale + rotate about different points), affine (general linear map + translation),
    vertexwise (each vertex with its own constant velocity).
    """
    diam = scale_of(polygon)
    c = polygon.mean(axis=0)
    o = c + rng.normal(size=2) * diam  # a point not necessarily inside S
    v = rng.normal(size=2) * diam
    s = rng.normal()
    w = rng.normal()
    if kind == "translate":
        return (lambda t: polygon + t * v), np.tile(v, (len(polygon), 1))
    if kind == "scale":
        return (lambda t: o + (1 + s * t) * (polygon - o)), s * (polygon - o)
    if kind == "rotate":
        return (lambda t: o + (polygon - o) @ rot(w * t).T), w * (polygon - o) @ SKEW.T
    if kind == "combo":
        o2 = c + rng.normal(size=2) * diam

        def P(t):
            q = o + (1 + s * t) * (polygon - o)
            return o2 + (q - o2) @ rot(w * t).T + t * v

        V = s * (polygon - o) + w * (polygon - o2) @ SKEW.T + v
        return P, V
    if kind == "affine":
        A = rng.normal(size=(2, 2))
        return (lambda t: polygon + t * ((polygon - o) @ A.T + v)), (polygon - o) @ A.T + v
    if kind == "vertexwise":
        W = rng.normal(size=polygon.shape) * diam
        return (lambda t: polygon + t * W), W
    raise ValueError(kind)


KINDS = ("translate", "scale", "rotate", "combo", "affine", "vertexwise")


def fd_rate(
    centroid_fn: Callable[[np.ndarray], np.ndarray], P: Callable[[float], np.ndarray], h: float
) -> np.ndarray:
    """Central difference in time of centroid_fn(P(t)) at t = 0."""
    return (centroid_fn(P(h)) - centroid_fn(P(-h))) / (2 * h)


def two_hop(nbrs: list[set[int]], i: int) -> set[int]:
    one = set(nbrs[i])
    two = set(one)
    for j in one:
        two |= set(nbrs[j])
    two.add(i)
    return two


def dense_qp(nominal: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """Reference for the safety filter: SLSQP on min |u - nominal|^2, A u <= b from a HiGHS
    feasible point; None when HiGHS finds the rows infeasible. Rows are normalised to unit
    |a| (the same set), which SLSQP needs at 10 m scales."""
    norm = np.linalg.norm(A, axis=1)
    A, b = A / norm[:, None], b / norm
    feasible = linprog(np.zeros(2), A_ub=A, b_ub=b, bounds=[(None, None)] * 2, method="highs")
    if feasible.status == 2:
        return None
    result = minimize(
        lambda u: np.sum((u - nominal) ** 2),
        feasible.x,
        jac=lambda u: 2.0 * (u - nominal),
        constraints=[{"type": "ineq", "fun": lambda u: b - A @ u, "jac": lambda u: -A}],
        method="SLSQP",
        options={"ftol": 1e-12, "maxiter": 500},
    )
    assert result.success, result.message
    return result.x
