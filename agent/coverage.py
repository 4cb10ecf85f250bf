"""Voronoi cells clipped to a convex subdomain, their masses, centroids and derivatives.

Implements Sections 2-4 of Xu & Diaz-Mercado, "Multi-Agent Control Using Coverage Over
Time-Varying Domains", for uniform density phi = 1 over a convex polygon S(t):

- mass m_i and centroid c_i of each cell V_i (Section 4.2, sums wrapping around the cell);
- dc/dp, the blocks of eqs. (dcidpj) / (dcidpi) in the closed form of the Lemma "Analytic
  Partial Derivatives";
- dc/dt of Proposition 1 (eq. dcidt2): the boundary term, in closed form for a boundary
  velocity that varies linearly along each edge of S, which is exact for translation,
  scaling and rotation (the paper's form with one normal speed per edge is the special
  case of an edge that does not rotate).

Conventions. ``positions: (n, 2)``; ``polygon: (k, 2)`` vertices of S in either orientation;
``polygon_velocity: (k, 2)`` the velocity of each vertex, a boundary point between two
vertices moving with the linear interpolation of their velocities. Jacobians are ordered
``[x0, y0, x1, y1, ...]``.

How a cell is built. A convex cell is the intersection of half-planes: the edges of S and
the bisectors with the robot's candidate neighbours. Every candidate line's piece inside all
the other half-planes is found at once, for a whole batch of cells, as a one-dimensional
linear programme vectorised over (cells, lines, constraints); the lines whose piece has
positive length are the cell's edges, already oriented counter-clockwise and labelled with
the robot or polygon edge they come from, which is all the mass, centroid, dc/dp and dc/dt
need. No Delaunay triangulation is involved, so collinear and coincident layouts, which
Qhull refuses, are ordinary inputs here. A constraint that does not touch the cell changes
nothing, so any superset of a robot's true neighbours gives the same cell: that is what lets
one robot compute its control from its two-hop neighbourhood alone
(``agent.control.local_step``). For the whole team, candidates are the nearest robots from a
k-d tree; a cell not closed within half the distance to its farthest candidate is rebuilt
with every robot as a candidate.

Degenerate layouts have defined behaviour:
- coincident robots: the one that comes first (lowest index) owns the cell, the others
  get an empty cell until they are apart;
- a robot whose cell is empty (outside S and dominated, or a coincident duplicate) gets
  mass 0 and, as its "centroid", the nearest point of S, so that kappa (c - p) drives it
  into S and is zero for a duplicate already inside S; its derivatives are those of that
  nearest point;
- a robot on the boundary of S, or outside S with a non-empty cell, is an ordinary robot.

Every public function accepts ``density``: None is uniform (phi = 1, the closed forms
above); otherwise a DensityModel snapshot at the current time (agent.density.Density),
whose own quadrature replaces the mass, centroid, dc/dp and dc/dt integrals. Cells do not
depend on phi.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.spatial import cKDTree

# Relative tolerances, scaled by the size of S: below GEOMETRY_TOL * size two points are the
# same point and an edge has no length.
GEOMETRY_TOL = 1e-12
# Validation compares every pair of polygon edges; larger polygons are refused, not slow.
MAX_POLYGON_VERTICES = 1024

# Label of a cell edge: j >= 0 is the bisector with robot j; -(l + 1) is edge l of S, the
# edge from polygon vertex l to vertex l + 1.


@dataclass(frozen=True)
class Domain:
    """A validated subdomain S: counter-clockwise vertices and matching vertex velocities.

    vertices: (k, 2) counter-clockwise; velocities: (k, 2); size: the diameter of S.
    Derived once for the hot path: normals (k, 2) unit outward normal of edge l (from vertex
    l to l + 1) and offsets (k,) with S = {q : normals q <= offsets}; edge_param (k, 2) the
    edge vector over its squared length (q . edge_param gives the edge parameter);
    normal_speed (k,) the outward speed at vertex l and normal_speed_change (k,) its change
    to vertex l + 1, both along edge l.
    """

    vertices: np.ndarray
    velocities: np.ndarray
    size: float
    normals: np.ndarray
    offsets: np.ndarray
    edge_param: np.ndarray
    normal_speed: np.ndarray
    normal_speed_change: np.ndarray

    @property
    def tol(self) -> float:
        return GEOMETRY_TOL * self.size


@dataclass(frozen=True)
class CellBatch:
    """The cells of robots ``owners`` as labelled edges, K cells of L candidate lines each.

    owners: (K,) robot indices; start, end: (K, L, 2) edge ends, the present edges first and
    in counter-clockwise order, each edge's end the next one's start; labels:
    (K, L) the robot (>= 0) or polygon edge (-(l + 1)) each line comes from; present: (K, L)
    the line is an edge of positive length; mass: (K,) m_i, 0 for an empty cell; centroid:
    (K, 2) c_i, the nearest point of S for an empty cell (Section 4.2).
    """

    owners: np.ndarray
    start: np.ndarray
    end: np.ndarray
    labels: np.ndarray
    present: np.ndarray
    mass: np.ndarray
    centroid: np.ndarray

    @property
    def empty(self) -> np.ndarray:
        return self.mass == 0.0

    @property
    def shared(self) -> np.ndarray:
        """(K, L) edges shared with another robot's cell."""
        return self.present & (self.labels >= 0)

    @property
    def boundary(self) -> np.ndarray:
        """(K, L) edges on the boundary of S."""
        return self.present & (self.labels < 0)

    def vertices(self, k: int) -> np.ndarray:
        """Counter-clockwise vertices (m, 2) of cell k, (0, 2) when empty."""
        return self.start[k][self.present[k]]


@runtime_checkable
class DensityModel(Protocol):
    """A non-uniform phi at the current time and its integrals over a batch of cells.

    weigh: the batch with m_i, c_i of phi; jacobian_blocks / boundary_rates: as the
    functions of that name here (boundary_rates with the dphi/dt term of Proposition 1).
    """

    def weigh(self, batch: CellBatch) -> CellBatch: ...

    def jacobian_blocks(
        self, batch: CellBatch, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def boundary_rates(
        self, batch: CellBatch, points: np.ndarray, domain: Domain
    ) -> np.ndarray: ...


def check_density(density: object) -> None:
    """Raise TypeError unless ``density`` is None (uniform) or a DensityModel."""
    if density is not None and not isinstance(density, DensityModel):
        raise TypeError(
            f"density must be None (uniform) or an agent.density.Density, not {type(density)}"
        )


def cell_jacobian_blocks(
    batch: CellBatch, points: np.ndarray, density: DensityModel | None
) -> tuple[np.ndarray, np.ndarray]:
    """``jacobian_blocks`` for phi = 1 (closed form) or the density's quadrature."""
    if density is None:
        return jacobian_blocks(batch, points)
    return density.jacobian_blocks(batch, points)


def cell_rates(
    batch: CellBatch, points: np.ndarray, domain: Domain, density: DensityModel | None
) -> np.ndarray:
    """dc/dt of Proposition 1: ``boundary_rates`` for phi = 1, else both of its terms."""
    if density is None:
        return boundary_rates(batch, points, domain)
    return density.boundary_rates(batch, points, domain)


def validate_polygon(polygon: np.ndarray) -> np.ndarray:
    """Check that ``polygon: (k, 2)`` is a convex polygon and return it counter-clockwise.

    Raises ValueError naming the problem: wrong shape, fewer than 3 vertices, NaN or inf,
    repeated consecutive vertices, zero area, a reflex vertex (non-convex) or a boundary
    that winds around more than once (self-intersecting). Collinear vertices are allowed.
    """
    return make_domain(polygon).vertices


def validate_positions(positions: np.ndarray) -> np.ndarray:
    """Check ``positions: (n, 2)`` (n >= 1, all finite) and return them as float64."""
    points = np.asarray(positions, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 1:
        raise ValueError(f"positions must have shape (n, 2) with n >= 1, got {points.shape}")
    if not np.all(np.isfinite(points)):
        bad = np.flatnonzero(~np.all(np.isfinite(points), axis=1))
        raise ValueError(f"positions contain NaN or inf (robots {bad.tolist()})")
    return points


def make_domain(polygon: np.ndarray, polygon_velocity: np.ndarray | None = None) -> Domain:
    """Validate S (``polygon: (k, 2)``) and its vertex velocities; orient both CCW.

    ``polygon_velocity: (k, 2)`` defaults to a still domain. Raises ValueError (see
    ``validate_polygon``).
    """
    vertices = np.asarray(polygon, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 2:
        raise ValueError(f"polygon must have shape (k, 2), got {vertices.shape}")
    k = vertices.shape[0]
    if k < 3:
        raise ValueError(f"polygon needs at least 3 vertices, got {k}")
    if k > MAX_POLYGON_VERTICES:
        raise ValueError(f"polygon has {k} vertices, more than the {MAX_POLYGON_VERTICES} allowed")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("polygon vertices contain NaN or inf")
    if polygon_velocity is None:
        velocities = np.zeros_like(vertices)
    else:
        velocities = np.asarray(polygon_velocity, dtype=np.float64)
        if velocities.shape != vertices.shape:
            raise ValueError(
                f"polygon_velocity must have the polygon's shape {vertices.shape}, "
                f"got {velocities.shape}"
            )
        if not np.all(np.isfinite(velocities)):
            raise ValueError("polygon_velocity contains NaN or inf")
    size = 2.0 * float(np.max(np.linalg.norm(vertices - vertices.mean(axis=0), axis=1)))
    edges = np.roll(vertices, -1, axis=0) - vertices
    short = np.linalg.norm(edges, axis=1) <= GEOMETRY_TOL * size
    if size == 0.0 or short.any():
        first = int(np.argmax(short))
        raise ValueError(
            f"polygon vertex {first} repeats vertex {(first + 1) % k}: zero-length edge"
        )
    area2 = float(np.sum(cross(vertices, np.roll(vertices, -1, axis=0))))
    if area2 < 0.0:
        vertices = vertices[::-1].copy()
        velocities = velocities[::-1].copy()
        edges = np.roll(vertices, -1, axis=0) - vertices
    turn = cross(np.roll(edges, 1, axis=0), edges)
    turning = np.arctan2(turn, np.sum(np.roll(edges, 1, axis=0) * edges, axis=1))
    # Only left turns adding up to one full turn: a simple convex polygon. Anything else is
    # examined further, to say what is wrong.
    if abs(area2) > 1e-9 * size * size and np.all(turn >= -1e-9 * size * size):
        if abs(float(np.sum(turning)) - 2.0 * np.pi) <= 1e-6:
            return _derive(vertices, velocities, size)
    crossing = _crossing_edges(vertices)
    if crossing is not None:
        raise ValueError(
            f"polygon is self-intersecting: edge {crossing[0]} crosses edge {crossing[1]}"
        )
    if abs(area2) <= 1e-9 * size * size:
        raise ValueError("polygon has zero area (its vertices are collinear)")
    if np.any(turn < -1e-9 * size * size):
        raise ValueError(f"polygon is not convex: reflex angle at vertex {int(np.argmin(turn))}")
    raise ValueError("polygon is self-intersecting: its boundary winds around more than once")


def _derive(vertices: np.ndarray, velocities: np.ndarray, size: float) -> Domain:
    """The Domain of valid CCW ``vertices`` and ``velocities``, with its derived arrays."""
    edges = np.roll(vertices, -1, axis=0) - vertices
    length2 = np.sum(edges * edges, axis=1)
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / np.sqrt(length2)[:, None]
    start_speed = np.sum(velocities * normals, axis=1)
    end_speed = np.sum(np.roll(velocities, -1, axis=0) * normals, axis=1)
    return Domain(
        vertices=vertices,
        velocities=velocities,
        size=size,
        normals=normals,
        offsets=np.sum(normals * vertices, axis=1),
        edge_param=edges / length2[:, None],
        normal_speed=start_speed,
        normal_speed_change=end_speed - start_speed,
    )


def _crossing_edges(vertices: np.ndarray) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges that intersect, or None for a simple polygon."""
    k = len(vertices)
    a, b = vertices, np.roll(vertices, -1, axis=0)
    d = b - a
    # Orientation of each edge's ends relative to every other edge: [i, j] = edge i vs ends of j.
    side_a = cross(d[:, None, :], a[None, :, :] - a[:, None, :])
    side_b = cross(d[:, None, :], b[None, :, :] - a[:, None, :])
    straddles = (side_a * side_b) < 0.0  # proper crossings; touching is left to convexity
    index = np.arange(k)
    gap = np.abs(index[:, None] - index[None, :])
    non_adjacent = (gap > 1) & (gap < k - 1)
    hits = np.argwhere(straddles & straddles.T & non_adjacent)
    return (int(hits[0][0]), int(hits[0][1])) if len(hits) else None


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z-component of the cross product of stacked 2-vectors: (..., 2) x (..., 2) -> (...)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def build_cells(
    points: np.ndarray, owners: np.ndarray, candidates: np.ndarray, domain: Domain
) -> CellBatch:
    """The clipped Voronoi cells of ``owners: (K,)`` among ``points: (n, 2)``.

    candidates: (K, D) robot indices whose bisectors may cut each cell, -1 for padding (the
    owner itself is ignored). A robot coincident with the owner and of lower index owns the
    cell, leaving the owner's cell empty; one of higher index is ignored.
    """
    tol = domain.tol
    me = points[owners]  # work relative to the owner: cells far from the origin keep digits
    valid = (candidates >= 0) & (candidates != owners[:, None])
    offsets_to = points[np.maximum(candidates, 0)] - me[:, None, :]
    distance = np.linalg.norm(offsets_to, axis=2)
    coincident = valid & (distance <= tol)
    dominated = np.any(coincident & (candidates < owners[:, None]), axis=1)
    valid &= ~coincident
    safe = np.where(valid, distance, 1.0)
    bisector_normal = offsets_to / safe[:, :, None]
    bisector_offset = np.where(valid, 0.5 * distance, np.inf)

    k = len(domain.vertices)
    polygon_normal = domain.normals
    polygon_offset = domain.offsets - me @ polygon_normal.T

    # Polygon edges first: where a bisector lies on an edge of S, the lower line index wins.
    count = len(owners)
    normal = np.concatenate(
        [np.broadcast_to(polygon_normal, (count, k, 2)), bisector_normal], axis=1
    )
    offset = np.concatenate([polygon_offset, bisector_offset], axis=1)
    active = np.concatenate([np.ones((count, k), dtype=bool), valid], axis=1)
    labels = np.concatenate([np.broadcast_to(-(np.arange(k) + 1), (count, k)), candidates], axis=1)

    finite_offset = np.where(active, offset, 0.0)
    nx, ny = normal[..., 0], normal[..., 1]
    # Line l is foot_l + t direction_l with foot_l = offset_l normal_l (its point closest to
    # the owner) and direction_l = (-ny, nx), which keeps the interior on the left so edges
    # run counter-clockwise. It must satisfy normal_m . q <= offset_m for every m:
    # t rate_lm <= slack_lm. Indices [cell, line l, constraint m].
    cosine = nx[:, :, None] * nx[:, None, :] + ny[:, :, None] * ny[:, None, :]
    rate = nx[:, :, None] * ny[:, None, :] - ny[:, :, None] * nx[:, None, :]
    slack = finite_offset[:, None, :] - finite_offset[:, :, None] * cosine
    parallel = np.abs(rate) <= 1e-12
    bound = slack / np.where(parallel, 1.0, rate)
    constraining = active[:, None, :] & ~np.eye(normal.shape[1], dtype=bool)
    upper = np.where(constraining & (rate > 1e-12), bound, np.inf).min(axis=2)
    lower = np.where(constraining & (rate < -1e-12), bound, -np.inf).max(axis=2)
    length = upper - lower
    present = active & (length > tol) & ~dominated[:, None]
    # A parallel constraint either excludes the whole line or none of it; of two identical
    # lines (same side, same offset) only the first is kept, so no edge counts twice.
    parallel &= constraining
    if parallel.any():
        earlier = np.tri(normal.shape[1], k=-1, dtype=bool)  # [l, m]: m < l
        excluded = parallel & ((slack < -tol) | ((cosine > 0.0) & (np.abs(slack) <= tol) & earlier))
        present &= ~excluded.any(axis=2)

    along = np.where(present, lower, 0.0)
    start = np.stack([finite_offset * nx - along * ny, finite_offset * ny + along * nx], axis=-1)
    start[~present] = 0.0
    # Each vertex is computed once, as the start of its edge, and reused as the end of the
    # previous edge: nearly parallel bisectors (nearly coincident robots) make a vertex
    # ill-conditioned, and two independent copies of it would leave the boundary open.
    count = present.sum(axis=1)
    centre = start.sum(axis=1) / np.maximum(count, 1)[:, None]
    angle = np.arctan2(start[..., 1] - centre[:, 1:], start[..., 0] - centre[:, :1])
    order = np.argsort(np.where(present, angle, np.inf), axis=1)
    rows = np.arange(len(owners))[:, None]
    start, labels, present = start[rows, order], labels[rows, order], present[rows, order]
    position = np.arange(present.shape[1])
    following = np.where(position + 1 < count[:, None], position + 1, 0)
    end = start[rows, following]
    end[~present] = 0.0
    # Moments about a vertex of the cell, not the owner: a sliver cell far from its robot
    # would otherwise lose its digits to cancellation.
    origin = start[:, :1, :]
    twice_area = np.where(present, cross(start - origin, end - origin), 0.0)
    mass = 0.5 * np.sum(twice_area, axis=1)
    empty = mass <= tol * tol
    mass = np.where(empty, 0.0, mass)
    moment = np.sum((start + end - 2.0 * origin) * twice_area[..., None], axis=1)
    centroid = me + origin[:, 0, :] + moment / (6.0 * np.where(empty, 1.0, mass))[:, None]
    for i in np.flatnonzero(empty):
        centroid[i] = nearest_point(domain, me[i])[0]
    present &= ~empty[:, None]
    return CellBatch(
        owners=owners,
        start=start + me[:, None, :],
        end=end + me[:, None, :],
        labels=labels,
        present=present,
        mass=mass,
        centroid=centroid,
    )


def cell_radius(batch: CellBatch, points: np.ndarray) -> np.ndarray:
    """(K,) the largest distance from each owner to its cell's vertices (0 when empty)."""
    me = points[batch.owners][:, None, :]
    reach = np.linalg.norm(batch.start - me, axis=2)
    return np.where(batch.present, reach, 0.0).max(axis=1)


# Nearest robots offered to each cell of the whole team; a cell needing more is rebuilt.
TEAM_CANDIDATES = 16
# Cells built per vectorised batch: bounds the (K, L, L) temporaries to a few tens of MB.
BATCH_CELLS = 512


def team_cells(points: np.ndarray, domain: Domain) -> CellBatch:
    """Every robot's cell, ``points: (n, 2)``; owners are 0..n-1 in order."""
    n = len(points)
    everyone = np.arange(n)
    if n <= TEAM_CANDIDATES + 1:
        return build_cells(points, everyone, np.broadcast_to(everyone, (n, n)), domain)
    tree = cKDTree(points)
    distance, nearest = tree.query(points, k=TEAM_CANDIDATES + 1)
    batch = _concatenate(
        [
            build_cells(points, everyone[s : s + BATCH_CELLS], nearest[s : s + BATCH_CELLS], domain)
            for s in range(0, n, BATCH_CELLS)
        ]
    )
    # Robots beyond the farthest candidate cannot cut a cell within half that distance; cells
    # that reach farther (large boundary cells) are rebuilt with twice the candidates.
    width = TEAM_CANDIDATES + 1
    unclosed = np.flatnonzero(distance[:, -1] <= 2.0 * cell_radius(batch, points) + domain.tol)
    while len(unclosed) and width < n:
        width = min(n, 2 * width)
        distance, nearest = tree.query(points[unclosed], k=width)
        rebuilt = build_cells(points, unclosed, nearest, domain)
        batch = _replace(batch, unclosed, rebuilt)
        still = distance[:, -1] <= 2.0 * cell_radius(rebuilt, points) + domain.tol
        unclosed = unclosed[still]
    return batch


def _concatenate(parts: list[CellBatch]) -> CellBatch:
    if len(parts) == 1:
        return parts[0]
    return CellBatch(
        **{
            name: np.concatenate([getattr(part, name) for part in parts])
            for name in CellBatch.__dataclass_fields__
        }
    )


def _replace(batch: CellBatch, rows: np.ndarray, rebuilt: CellBatch) -> CellBatch:
    """``batch`` with ``rows`` replaced by ``rebuilt`` (which may have more lines per cell)."""
    width = max(batch.labels.shape[1], rebuilt.labels.shape[1])

    def widen(array: np.ndarray, fill: float | int | bool) -> np.ndarray:
        pad = [(0, 0), (0, width - array.shape[1])] + [(0, 0)] * (array.ndim - 2)
        return np.pad(array, pad, constant_values=fill)

    fields = {}
    for name in CellBatch.__dataclass_fields__:
        old, new = getattr(batch, name), getattr(rebuilt, name)
        if old.ndim >= 2 and name not in ("centroid",):
            fill = False if old.dtype == bool else 0
            old, new = widen(old, fill), widen(new, fill)
        merged = old.copy()
        merged[rows] = new
        fields[name] = merged
    return CellBatch(**fields)


def nearest_point(domain: Domain, point: np.ndarray) -> tuple[np.ndarray, int, float]:
    """Nearest point of S to ``point: (2,)``.

    Returns (q (2,), edge l, sigma): q = S_l + sigma (S_{l+1} - S_l); l = -1 when the point is
    inside S (then q is the point itself).
    """
    vertices = domain.vertices
    edges = np.roll(vertices, -1, axis=0) - vertices
    outward = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    if np.all(np.sum((point - vertices) * outward, axis=1) <= 0.0):
        return point.copy(), -1, 0.0
    sigma = np.sum((point - vertices) * edges, axis=1) / np.sum(edges * edges, axis=1)
    sigma = np.clip(sigma, 0.0, 1.0)
    candidates = vertices + sigma[:, None] * edges
    edge = int(np.argmin(np.sum((candidates - point) ** 2, axis=1)))
    return candidates[edge], edge, float(sigma[edge])


def nearest_point_derivatives(
    domain: Domain, point: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest point q of S to ``point: (2,)`` and (q, dq/dp (2, 2), dq/dt (2,)).

    This is the "centroid" of an empty cell. Inside S, q = p; in an edge's region q slides
    along the moving edge; in a vertex's region q is the vertex.
    """
    q, edge, sigma = nearest_point(domain, point)
    if edge < 0:
        return q, np.eye(2), np.zeros(2)
    k = len(domain.vertices)
    ua, ub = domain.velocities[edge], domain.velocities[(edge + 1) % k]
    if sigma <= 0.0:
        return q, np.zeros((2, 2)), ua.copy()
    if sigma >= 1.0:
        return q, np.zeros((2, 2)), ub.copy()
    a = domain.vertices[edge]
    e = domain.vertices[(edge + 1) % k] - a
    de = ub - ua
    h = float(e @ e)
    g = float((point - a) @ e)
    dsigma = ((-ua @ e + (point - a) @ de) * h - g * 2.0 * (e @ de)) / (h * h)
    return q, np.outer(e, e) / h, ua + dsigma * e + sigma * de


def _edge_moments(
    start: np.ndarray, end: np.ndarray, centroid: np.ndarray, anchor: np.ndarray
) -> np.ndarray:
    """Line integrals of (q - c)(q - a)^T along segments: the Lemma's bracket times |d|.

    start, end, centroid, anchor: (..., 2), broadcast. Returns (..., 2, 2):
    |d| [ (v1 - c)(v1 - a)^T + ((v1 - c) d^T + d (v1 - a)^T) / 2 + d d^T / 3 ], d = v2 - v1.
    """
    d = end - start
    u = start - centroid
    w = start - anchor
    bracket = (
        u[..., :, None] * w[..., None, :]
        + 0.5 * (u[..., :, None] * d[..., None, :] + d[..., :, None] * w[..., None, :])
        + d[..., :, None] * d[..., None, :] / 3.0
    )
    return np.linalg.norm(d, axis=-1)[..., None, None] * bracket


def jacobian_blocks(batch: CellBatch, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form blocks of dc/dp for the batch's rows (non-empty cells).

    Returns off: (K, L, 2, 2), dc_i/dp_j by eq. (dcidpj) for the edge shared with robot
    labels[k, l] (zero where there is none), and diagonal: (K, 2, 2), dc_i/dp_i by eq.
    (dcidpi). Empty cells get zero blocks.
    """
    me = points[batch.owners]
    others = points[np.maximum(batch.labels, 0)]
    separation = np.linalg.norm(others - me[:, None, :], axis=2)
    shared = batch.shared
    scale = np.where(
        shared,
        1.0 / (np.where(shared, separation, 1.0) * np.maximum(batch.mass, 1e-300)[:, None]),
        0.0,
    )
    start, end = batch.start, batch.end
    centroid = batch.centroid[:, None, :]
    # Both brackets from one: with anchor p_j the bracket is the one with anchor p_i plus
    # (integral of (q - c) ds) (p_i - p_j)^T, and that integral is |d| (v1 - c + d / 2).
    about_me = _edge_moments(start, end, centroid, me[:, None, :])
    d = end - start
    first = np.linalg.norm(d, axis=-1)[..., None] * (start - centroid + 0.5 * d)
    gap = me[:, None, :] - others
    off = -scale[..., None, None] * (about_me + first[..., :, None] * gap[..., None, :])
    diagonal = np.sum(scale[..., None, None] * about_me, axis=1)
    return off, diagonal


def boundary_rates(batch: CellBatch, points: np.ndarray, domain: Domain) -> np.ndarray:
    """dc_i/dt of Proposition 1 for the batch's cells, (K, 2).

    The boundary term: on a cell edge lying on edge l of S the outward normal speed nu is
    linear in position (vertex velocities interpolate linearly), so with nu1, nu2 at its ends
    integral (q - c) nu ds = |d| [ (v1 - c)(nu1 + nu2) / 2 + d (nu1 / 6 + nu2 / 3) ].
    An empty cell gets the velocity of its nearest point of S.
    """
    edge = np.where(batch.boundary, -batch.labels - 1, 0)
    a = domain.vertices[edge]
    param = domain.edge_param[edge]
    speed, change = domain.normal_speed[edge], domain.normal_speed_change[edge]
    nu1 = speed + change * np.sum((batch.start - a) * param, axis=-1)
    nu2 = speed + change * np.sum((batch.end - a) * param, axis=-1)
    d = batch.end - batch.start
    integral = np.linalg.norm(d, axis=-1)[..., None] * (
        (batch.start - batch.centroid[:, None, :]) * (0.5 * (nu1 + nu2))[..., None]
        + d * (nu1 / 6.0 + nu2 / 3.0)[..., None]
    )
    integral = np.where(batch.boundary[..., None], integral, 0.0)
    rates = np.sum(integral, axis=1) / np.where(batch.empty, 1.0, batch.mass)[:, None]
    for i in np.flatnonzero(batch.empty):
        rates[i] = nearest_point_derivatives(domain, points[batch.owners[i]])[2]
    return rates


def tessellate(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray | None = None,
    density: DensityModel | None = None,
) -> tuple[np.ndarray, Domain, CellBatch]:
    """Validate the inputs and build every robot's cell: (points, domain, cells).

    With a density the cells' masses and centroids are those of phi.
    """
    check_density(density)
    points = validate_positions(positions)
    domain = make_domain(polygon, polygon_velocity)
    batch = team_cells(points, domain)
    return points, domain, batch if density is None else density.weigh(batch)


def cells(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> list[np.ndarray]:
    """Each robot's Voronoi cell clipped to S.

    positions: (n, 2); polygon: (k, 2). Returns n arrays of counter-clockwise vertices
    (m_i, 2), an empty (0, 2) array for an empty cell.
    """
    check_density(density)
    points, _, batch = tessellate(positions, polygon)
    return [batch.vertices(i) for i in range(len(points))]


def mass_centroid(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mass m_i and centroid c_i of every cell (Section 4.2; quadrature with a density).

    positions: (n, 2); polygon: (k, 2). Returns mass (n,) and centroid (n, 2); an empty
    cell has mass 0 and the nearest point of S as its centroid.
    """
    _, _, batch = tessellate(positions, polygon, density=density)
    return batch.mass.copy(), batch.centroid.copy()


def neighbors(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> list[set[int]]:
    """Delaunay neighbours of each robot whose shared cell edge inside S has positive length.

    positions: (n, 2); polygon: (k, 2). Returns n sets of robot indices.
    """
    check_density(density)
    points, _, batch = tessellate(positions, polygon)
    return [set(batch.labels[i][batch.shared[i]].tolist()) for i in range(len(points))]


def centroid_jacobian(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> np.ndarray:
    """dc/dp, eqs. (dcidpj)/(dcidpi): closed form for uniform density, else quadrature.

    positions: (n, 2); polygon: (k, 2). Returns a dense (2n, 2n) array ordered
    [x0, y0, x1, y1, ...]. The row of an empty cell is the derivative of the nearest point
    of S.
    """
    points, domain, batch = tessellate(positions, polygon, density=density)
    n = len(points)
    off, diagonal = cell_jacobian_blocks(batch, points, density)
    jacobian = np.zeros((n, n, 2, 2))
    rows = np.broadcast_to(batch.owners[:, None], batch.labels.shape)
    shared = batch.shared
    np.add.at(jacobian, (rows[shared], batch.labels[shared]), off[shared])
    jacobian[batch.owners, batch.owners] += diagonal
    for i in np.flatnonzero(batch.empty):
        jacobian[i, i] = nearest_point_derivatives(domain, points[i])[1]
    return jacobian.transpose(0, 2, 1, 3).reshape(2 * n, 2 * n)


def centroid_rate(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    density: DensityModel | None = None,
) -> np.ndarray:
    """dc/dt of Proposition 1 (eq. dcidt2): the boundary term, plus the dphi/dt term.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2). For an empty cell
    it is the velocity of the nearest point of S.
    """
    points, domain, batch = tessellate(positions, polygon, polygon_velocity, density)
    return cell_rates(batch, points, domain, density)


def aggregate_error(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> float:
    """Aggregated CVT error e_a = ||p - c(p, t)|| over the whole team (Section 5), metres."""
    points, _, batch = tessellate(positions, polygon, density=density)
    return float(np.linalg.norm(points - batch.centroid))
