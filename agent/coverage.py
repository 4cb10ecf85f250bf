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

How a cell is built. Cell i is S clipped by the bisector half-planes of the other robots,
taken in order of distance from robot i and stopped as soon as the next robot is farther
than twice the cell's radius around p_i (no farther robot can cut the cell). This needs no
Delaunay triangulation, so collinear and coincident layouts, which Qhull refuses, are
ordinary inputs here, and a cell built from any superset of a robot's true neighbours is
the same cell: that is what lets one robot compute its control from its two-hop
neighbourhood alone (``agent.control.local_step``).

Degenerate layouts have defined behaviour:
- coincident robots: the one that comes first (lowest index) owns the cell, the others
  get an empty cell until they are apart;
- a robot whose cell is empty (outside S and dominated, or a coincident duplicate) gets
  mass 0 and, as its "centroid", the nearest point of S, so that kappa (c - p) drives it
  into S and is zero for a duplicate already inside S; its derivatives are those of that
  nearest point;
- a robot on the boundary of S, or outside S with a non-empty cell, is an ordinary robot.

Every public function accepts ``density=None`` (uniform); non-uniform densities are not
implemented yet and raise NotImplementedError rather than silently using phi = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# Relative tolerances, scaled by the size of S: below GEOMETRY_TOL * size two points are the
# same point and an edge has no length.
GEOMETRY_TOL = 1e-12

# Label of a cell edge: j >= 0 is the bisector with robot j; -(l + 1) is edge l of S, the
# edge from polygon vertex l to vertex l + 1.


@dataclass(frozen=True)
class Domain:
    """A validated subdomain S: counter-clockwise vertices and matching vertex velocities.

    vertices: (k, 2) counter-clockwise; velocities: (k, 2); size: the diameter of S.
    """

    vertices: np.ndarray
    velocities: np.ndarray
    size: float

    @property
    def tol(self) -> float:
        return GEOMETRY_TOL * self.size


@dataclass(frozen=True)
class Cell:
    """One robot's Voronoi cell clipped to S.

    vertices: (m, 2) counter-clockwise, (0, 2) when empty; labels: (m,) the origin of the edge
    from vertex k to vertex k + 1 (see the module notes); mass and centroid: Section 4.2.
    """

    vertices: np.ndarray
    labels: np.ndarray
    mass: float
    centroid: np.ndarray

    @property
    def empty(self) -> bool:
        return self.mass == 0.0


def _require_uniform(density: object) -> None:
    if density is not None:
        raise NotImplementedError(
            "non-uniform densities are not implemented yet: pass density=None (uniform)"
        )


def validate_polygon(polygon: np.ndarray) -> np.ndarray:
    """Check that ``polygon: (k, 2)`` is a convex polygon and return it counter-clockwise.

    Raises ValueError naming the problem: wrong shape, fewer than 3 vertices, NaN or inf,
    repeated consecutive vertices, zero area, a reflex vertex (non-convex) or a boundary
    that winds around more than once (self-intersecting). Collinear vertices are allowed.
    """
    return _domain(polygon, None).vertices


def validate_positions(positions: np.ndarray) -> np.ndarray:
    """Check ``positions: (n, 2)`` (n >= 1, all finite) and return them as float64."""
    points = np.asarray(positions, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 1:
        raise ValueError(f"positions must have shape (n, 2) with n >= 1, got {points.shape}")
    if not np.all(np.isfinite(points)):
        bad = np.flatnonzero(~np.all(np.isfinite(points), axis=1))
        raise ValueError(f"positions contain NaN or inf (robots {bad.tolist()})")
    return points


def _domain(polygon: np.ndarray, polygon_velocity: np.ndarray | None) -> Domain:
    """Validate S and its vertex velocities; orient both counter-clockwise."""
    vertices = np.asarray(polygon, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 2:
        raise ValueError(f"polygon must have shape (k, 2), got {vertices.shape}")
    k = vertices.shape[0]
    if k < 3:
        raise ValueError(f"polygon needs at least 3 vertices, got {k}")
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
    size = float(np.max(np.linalg.norm(vertices - vertices.mean(axis=0), axis=1))) * 2.0
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.linalg.norm(edges, axis=1)
    if size == 0.0 or np.any(lengths <= GEOMETRY_TOL * size):
        first = int(np.argmax(lengths <= GEOMETRY_TOL * size)) if size else 0
        raise ValueError(
            f"polygon vertex {first} repeats vertex {(first + 1) % k}: zero-length edge"
        )
    area2 = float(np.sum(_cross(vertices, np.roll(vertices, -1, axis=0))))
    if abs(area2) <= 1e-9 * size * size:
        raise ValueError("polygon has zero area (its vertices are collinear)")
    if area2 < 0.0:
        vertices = vertices[::-1].copy()
        velocities = velocities[::-1].copy()
        edges = np.roll(vertices, -1, axis=0) - vertices
    turn = _cross(np.roll(edges, 1, axis=0), edges)
    if np.any(turn < -1e-9 * size * size):
        bad = int(np.argmin(turn))
        raise ValueError(f"polygon is not convex: reflex angle at vertex {bad}")
    turning = np.arctan2(turn, np.sum(np.roll(edges, 1, axis=0) * edges, axis=1))
    if abs(float(np.sum(turning)) - 2.0 * np.pi) > 1e-6:
        raise ValueError("polygon is self-intersecting: its boundary winds around more than once")
    return Domain(vertices=vertices, velocities=velocities, size=size)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z-component of the cross product of stacked 2-vectors: (..., 2) x (..., 2) -> (...)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _clip(
    vertices: np.ndarray, labels: np.ndarray, normal: np.ndarray, offset: float, label: int
) -> tuple[np.ndarray, np.ndarray]:
    """Clip a convex polygon to the half-plane ``normal . q <= offset``.

    vertices: (m, 2) counter-clockwise; labels: (m,). The new edge gets ``label``.
    Convexity means the kept vertices form one cyclic run, so the result is that run plus
    the exit and entry points, computed without a loop over vertices.
    """
    side = vertices @ normal - offset
    inside = side <= 0.0
    if inside.all():
        return vertices, labels
    if not inside.any():
        return vertices[:0], labels[:0]
    following = np.roll(inside, -1)
    exit_edge = int(np.flatnonzero(inside & ~following)[0])
    entry_edge = int(np.flatnonzero(~inside & following)[0])
    m = len(vertices)
    a, b = vertices[exit_edge], vertices[(exit_edge + 1) % m]
    exit_point = a + (b - a) * (side[exit_edge] / (side[exit_edge] - side[(exit_edge + 1) % m]))
    a, b = vertices[entry_edge], vertices[(entry_edge + 1) % m]
    entry_point = a + (b - a) * (
        side[entry_edge] / (side[entry_edge] - side[(entry_edge + 1) % m])
    )
    run = np.arange(entry_edge + 1, entry_edge + 1 + np.count_nonzero(inside)) % m
    new_vertices = np.concatenate([vertices[run], exit_point[None], entry_point[None]])
    new_labels = np.concatenate([labels[run], [label, labels[entry_edge]]])
    # The last kept vertex starts the edge towards the exit point, which lies on the same
    # original edge, so it keeps that edge's label; already true because run ends at exit_edge.
    return new_vertices, new_labels


def _drop_short_edges(
    vertices: np.ndarray, labels: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Remove vertices that start an edge shorter than ``tol`` (clipping through a vertex)."""
    if len(vertices) == 0:
        return vertices, labels
    lengths = np.linalg.norm(np.roll(vertices, -1, axis=0) - vertices, axis=1)
    keep = lengths > tol
    if keep.all():
        return vertices, labels
    if np.count_nonzero(keep) < 3:
        return vertices[:0], labels[:0]
    return vertices[keep], labels[keep]


def _polygon_mass_centroid(vertices: np.ndarray) -> tuple[float, np.ndarray]:
    """Area and centroid of a counter-clockwise polygon (Section 4.2, wrapping sums).

    Computed relative to the first vertex so that far-from-origin cells keep their digits.
    """
    origin = vertices[0]
    local = vertices - origin
    following = np.roll(local, -1, axis=0)
    cross = _cross(local, following)
    area = 0.5 * float(np.sum(cross))
    if area <= 0.0:
        return 0.0, origin.copy()
    centroid = origin + np.sum((local + following) * cross[:, None], axis=0) / (6.0 * area)
    return area, centroid


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


def clipped_cell(index: int, points: np.ndarray, order: np.ndarray, domain: Domain) -> Cell:
    """Cell of robot ``index`` among ``points: (n, 2)``, clipped to S.

    order: indices of the other robots sorted by distance from robot ``index``, ties by index
    (see ``distance_order``). It may hold only the nearest ones: clipping stops once the next
    is beyond twice the cell's radius, so any superset of the true neighbours gives the same
    cell. Labels of bisector edges are indices into ``points``.
    """
    me = points[index]
    vertices = domain.vertices - me
    k = len(vertices)
    labels = -(np.arange(k) + 1)
    radius = float(np.sqrt(np.max(np.sum(vertices * vertices, axis=1))))
    tol = domain.tol
    for other in order:
        other = int(other)
        if other == index:
            continue
        normal = points[other] - me
        distance = float(np.hypot(normal[0], normal[1]))
        if distance > 2.0 * radius + tol:
            break
        if distance <= tol:
            if other < index:  # a coincident robot that comes first owns the cell
                vertices = vertices[:0]
                break
            continue
        vertices, labels = _clip(vertices, labels, normal, 0.5 * distance * distance, other)
        if len(vertices) == 0:
            break
        radius = float(np.sqrt(np.max(np.sum(vertices * vertices, axis=1))))
    vertices, labels = _drop_short_edges(vertices, labels, tol)
    if len(vertices) == 0:
        nearest, _, _ = nearest_point(domain, me)
        return Cell(np.empty((0, 2)), np.empty(0, dtype=np.int64), 0.0, nearest)
    vertices = vertices + me
    mass, centroid = _polygon_mass_centroid(vertices)
    if mass <= tol * tol:
        nearest, _, _ = nearest_point(domain, me)
        return Cell(np.empty((0, 2)), np.empty(0, dtype=np.int64), 0.0, nearest)
    return Cell(vertices, labels.astype(np.int64), mass, centroid)


def distance_order(points: np.ndarray, index: int, candidates: np.ndarray) -> np.ndarray:
    """``candidates`` sorted by distance from robot ``index``, ties broken by index.

    The tie-break makes coincident robots clip in index order, so a cell's bisector edge is
    labelled with the duplicate that owns a cell.
    """
    distance = np.sum((points[candidates] - points[index]) ** 2, axis=1)
    return candidates[np.lexsort((candidates, distance))]


def _all_cells(points: np.ndarray, domain: Domain) -> list[Cell]:
    """Every robot's cell; candidates come from a k-d tree, widened until each cell closes."""
    n = len(points)
    if n == 1:
        return [clipped_cell(0, points, np.empty(0, dtype=np.int64), domain)]
    tree = cKDTree(points)
    k = min(n, 16)
    _, nearest = tree.query(points, k=k)
    result = []
    for i in range(n):
        order = distance_order(points, i, nearest[i])
        while True:
            cell = clipped_cell(i, points, order, domain)
            if len(order) >= n or _closed(cell, points[i], points[order[-1]], domain):
                break
            _, wider = tree.query(points[i], k=min(n, 2 * len(order)))
            order = distance_order(points, i, wider)
        result.append(cell)
    return result


def _closed(cell: Cell, me: np.ndarray, farthest: np.ndarray, domain: Domain) -> bool:
    """True when no robot beyond ``farthest`` can cut the cell (it is within the radius)."""
    distance = float(np.linalg.norm(farthest - me))
    if cell.empty:
        return True
    radius = float(np.sqrt(np.max(np.sum((cell.vertices - me) ** 2, axis=1))))
    return distance > 2.0 * radius + domain.tol


def _tessellate(
    positions: np.ndarray, polygon: np.ndarray, polygon_velocity: np.ndarray | None = None
) -> tuple[np.ndarray, Domain, list[Cell]]:
    points = validate_positions(positions)
    domain = _domain(polygon, polygon_velocity)
    return points, domain, _all_cells(points, domain)


def cells(positions: np.ndarray, polygon: np.ndarray, density: object = None) -> list[np.ndarray]:
    """Each robot's Voronoi cell clipped to S.

    positions: (n, 2); polygon: (k, 2). Returns n arrays of counter-clockwise vertices
    (m_i, 2), an empty (0, 2) array for an empty cell.
    """
    _require_uniform(density)
    _, _, all_cells = _tessellate(positions, polygon)
    return [cell.vertices.copy() for cell in all_cells]


def mass_centroid(
    positions: np.ndarray, polygon: np.ndarray, density: object = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mass m_i and centroid c_i of every cell for uniform density (Section 4.2).

    positions: (n, 2); polygon: (k, 2). Returns mass (n,) and centroid (n, 2); an empty
    cell has mass 0 and the nearest point of S as its centroid.
    """
    _require_uniform(density)
    _, _, all_cells = _tessellate(positions, polygon)
    return _masses(all_cells), _centroids(all_cells)


def _masses(all_cells: list[Cell]) -> np.ndarray:
    return np.array([cell.mass for cell in all_cells], dtype=np.float64)


def _centroids(all_cells: list[Cell]) -> np.ndarray:
    return np.array([cell.centroid for cell in all_cells], dtype=np.float64).reshape(-1, 2)


def cell_neighbors(cell: Cell, tol: float) -> np.ndarray:
    """Labels of the bisector edges of ``cell`` with positive length (its Voronoi neighbours)."""
    if cell.empty:
        return np.empty(0, dtype=np.int64)
    lengths = np.linalg.norm(np.roll(cell.vertices, -1, axis=0) - cell.vertices, axis=1)
    return np.unique(cell.labels[(cell.labels >= 0) & (lengths > tol)])


def neighbors(positions: np.ndarray, polygon: np.ndarray, density: object = None) -> list[set[int]]:
    """Delaunay neighbours of each robot whose shared cell edge inside S has positive length.

    positions: (n, 2); polygon: (k, 2). Returns n sets of robot indices.
    """
    _require_uniform(density)
    _, domain, all_cells = _tessellate(positions, polygon)
    return [set(cell_neighbors(cell, domain.tol).tolist()) for cell in all_cells]


def _edge_moments(
    start: np.ndarray, end: np.ndarray, centroid: np.ndarray, anchor: np.ndarray
) -> np.ndarray:
    """Line integral of (q - c)(q - a)^T along segments (the Lemma's bracket times length).

    start, end: (E, 2) segment ends; centroid: (E, 2) c; anchor: (E, 2) a. Returns (E, 2, 2):
    |d| [ (v1 - c)(v1 - a)^T + ((v1 - c) d^T + d (v1 - a)^T) / 2 + d d^T / 3 ], d = v2 - v1.
    """
    d = end - start
    u = start - centroid
    w = start - anchor
    bracket = (
        u[:, :, None] * w[:, None, :]
        + 0.5 * (u[:, :, None] * d[:, None, :] + d[:, :, None] * w[:, None, :])
        + d[:, :, None] * d[:, None, :] / 3.0
    )
    return np.linalg.norm(d, axis=1)[:, None, None] * bracket


def jacobian_blocks(
    index: int, cell: Cell, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-zero blocks of row ``index`` of dc/dp from its non-empty cell.

    Returns (columns (E,), off-diagonal blocks (E, 2, 2) = dc_i/dp_j by eq. (dcidpj), and the
    diagonal block (2, 2) = dc_i/dp_i by eq. (dcidpi)). Several edges may share a column only
    through clipping artefacts; callers add them.
    """
    if cell.empty:
        return np.empty(0, dtype=np.int64), np.empty((0, 2, 2)), np.zeros((2, 2))
    following = np.roll(cell.vertices, -1, axis=0)
    interior = cell.labels >= 0
    columns = cell.labels[interior]
    start, end = cell.vertices[interior], following[interior]
    if len(columns) == 0:
        return columns, np.empty((0, 2, 2)), np.zeros((2, 2))
    me = points[index]
    others = points[columns]
    scale = 1.0 / (cell.mass * np.linalg.norm(others - me, axis=1))
    centroid = np.broadcast_to(cell.centroid, start.shape)
    off = -scale[:, None, None] * _edge_moments(start, end, centroid, others)
    diagonal = np.sum(
        scale[:, None, None] * _edge_moments(start, end, centroid, np.broadcast_to(me, start.shape)),
        axis=0,
    )
    return columns, off, diagonal


def boundary_rate(cell: Cell, domain: Domain) -> np.ndarray:
    """dc_i/dt from the motion of S (Proposition 1, second term) for a non-empty cell: (2,).

    On a cell edge lying on edge l of S, the outward normal speed nu is linear in position
    (vertex velocities interpolate linearly), so with nu1, nu2 at the edge's ends
    integral (q - c) nu ds = |d| [ (v1 - c)(nu1 + nu2) / 2 + d (nu1 / 6 + nu2 / 3) ].
    """
    boundary = cell.labels < 0
    if cell.empty or not boundary.any():
        return np.zeros(2)
    following = np.roll(cell.vertices, -1, axis=0)
    start, end = cell.vertices[boundary], following[boundary]
    edge = -cell.labels[boundary] - 1
    a = domain.vertices[edge]
    e = domain.vertices[(edge + 1) % len(domain.vertices)] - a
    ua = domain.velocities[edge]
    ub = domain.velocities[(edge + 1) % len(domain.vertices)]
    length2 = np.sum(e * e, axis=1)
    outward = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.sqrt(length2)[:, None]

    def normal_speed(q: np.ndarray) -> np.ndarray:
        s = np.sum((q - a) * e, axis=1) / length2
        return np.sum(((1.0 - s)[:, None] * ua + s[:, None] * ub) * outward, axis=1)

    nu1, nu2 = normal_speed(start), normal_speed(end)
    d = end - start
    integral = np.linalg.norm(d, axis=1)[:, None] * (
        (start - cell.centroid) * (0.5 * (nu1 + nu2))[:, None]
        + d * (nu1 / 6.0 + nu2 / 3.0)[:, None]
    )
    return np.sum(integral, axis=0) / cell.mass


def nearest_point_derivatives(
    domain: Domain, point: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest point q of S to ``point`` and its derivatives: (q (2,), dq/dp (2, 2), dq/dt (2,)).

    This is the "centroid" of an empty cell. Inside S, q = p; on an edge's interior region q
    slides along the moving edge; in a vertex region q is the vertex.
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
    dg = float(-ua @ e + (point - a) @ de)
    dh = 2.0 * float(e @ de)
    dsigma = (dg * h - g * dh) / (h * h)
    return q, np.outer(e, e) / h, ua + dsigma * e + sigma * de


def centroid_jacobian(
    positions: np.ndarray, polygon: np.ndarray, density: object = None
) -> np.ndarray:
    """dc/dp for uniform density, eqs. (dcidpj)/(dcidpi) in closed form.

    positions: (n, 2); polygon: (k, 2). Returns a dense (2n, 2n) array ordered
    [x0, y0, x1, y1, ...]. The row of an empty cell is the derivative of the nearest point of S.
    """
    _require_uniform(density)
    points, domain, all_cells = _tessellate(positions, polygon)
    n = len(points)
    jacobian = np.zeros((n, 2, n, 2))
    for i, cell in enumerate(all_cells):
        if cell.empty:
            jacobian[i, :, i, :] = nearest_point_derivatives(domain, points[i])[1]
            continue
        columns, off, diagonal = jacobian_blocks(i, cell, points)
        np.add.at(jacobian, (i, slice(None), columns, slice(None)), off)
        jacobian[i, :, i, :] += diagonal
    return jacobian.reshape(2 * n, 2 * n)


def centroid_rate(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    density: object = None,
) -> np.ndarray:
    """dc/dt of Proposition 1 (eq. dcidt2) for uniform density: the boundary term.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2). For an empty cell
    it is the velocity of the nearest point of S.
    """
    _require_uniform(density)
    points, domain, all_cells = _tessellate(positions, polygon, polygon_velocity)
    return _rates(points, domain, all_cells)


def _rates(points: np.ndarray, domain: Domain, all_cells: list[Cell]) -> np.ndarray:
    return np.array(
        [
            nearest_point_derivatives(domain, points[i])[2]
            if cell.empty
            else boundary_rate(cell, domain)
            for i, cell in enumerate(all_cells)
        ]
    ).reshape(-1, 2)


def aggregate_error(positions: np.ndarray, polygon: np.ndarray, density: object = None) -> float:
    """Aggregated CVT error e_a = ||p - c(p, t)|| over the whole team (Section 5), metres."""
    _require_uniform(density)
    points, _, all_cells = _tessellate(positions, polygon)
    return float(np.linalg.norm(points - _centroids(all_cells)))
