"""Voronoi cells clipped to a convex subdomain, their masses, centroids and derivatives.

Implements Sections 2-4 of Xu & Diaz-Mercado, "Multi-Agent Control Using Coverage Over
Time-Varying Domains", for uniform density phi = 1 over a convex polygon S(t):

- mass m_i and centroid c_i of each cell V_i (Section 4.2, sums wrapping around the cell);
- dc/dp, the blocks of eqs. (6) / (7) (Section 2.3) in the closed form of Lemma 3
  ("Analytic Partial Derivatives", Section 4.3);
- dc/dt of Proposition 1 (Section 3, eq. (9)): the boundary term, in closed form for a boundary
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
(``covswarm.tvd.control.local_step``). For the whole team, candidates are the nearest robots from a
k-d tree; a cell not closed within half the distance to its farthest candidate is rebuilt
with every robot as a candidate. Many robots' local views at once (``local_cells``,
``covswarm.tvd.control.local_steps``): each cell takes only its own view's robots as
candidates, the nearest of them first, so one batch holds many local diagrams side by side.
The intersection costs L^2 per cell for L lines and runs in passes that keep its
temporaries in cache (PIECE_PAIRS).

Degenerate layouts have defined behaviour:
- coincident robots: the one that comes first (lowest index) owns the cell, the others
  get an empty cell until they are apart;
- a robot whose cell is empty (outside S and dominated, or a coincident duplicate) gets
  mass 0 and, as its "centroid", the nearest point of S, so that kappa (c - p) drives it
  into S and is zero for a duplicate already inside S; its derivatives are those of that
  nearest point;
- a robot on the boundary of S, or outside S with a non-empty cell, is an ordinary robot.

Every public function accepts ``density``: None is uniform (phi = 1, the closed forms
above); otherwise a DensityModel snapshot at the current time (covswarm.tvd.density.Density),
whose own integrals replace the mass, centroid, dc/dp and dc/dt closed forms. Cells do not
depend on phi.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
from scipy.spatial import cKDTree

from covswarm.tvd.arrays import still_mask

# Relative tolerances, scaled by the size of S: below GEOMETRY_TOL * size two points are the
# same point and an edge has no length.
GEOMETRY_TOL = 1e-12
# Validation compares every pair of polygon edges; larger polygons are refused, not slow.
MAX_POLYGON_VERTICES = 1024

# Label of a cell edge: j >= 0 is the bisector with robot j; -(l + 1) is edge l of S, the
# edge from polygon vertex l to vertex l + 1.


@dataclass(frozen=True)
class CoverageDomain:
    """A validated subdomain S: counter-clockwise vertices and matching vertex velocities.

    vertices: (k, 2) counter-clockwise; velocities: (k, 2); size: half the perimeter of S,
    between its diameter and 1.6 times it. Derived once for the hot path, plane vectors as
    complex numbers x + iy: normals (k,) unit outward normal of edge l (from vertex l to
    l + 1) and offsets (k,) with S = {q : normals . q <= offsets}; the outward normal speed
    of a point q of edge l, linear along the edge because the vertex velocities interpolate
    linearly, is speed_offset[l] + speed_gradient[l] . q with speed_offset (k,) and
    speed_gradient (k,).
    """

    vertices: np.ndarray
    velocities: np.ndarray
    size: float
    normals: np.ndarray
    offsets: np.ndarray
    speed_offset: np.ndarray
    speed_gradient: np.ndarray

    @property
    def tol(self) -> float:
        return GEOMETRY_TOL * self.size


@dataclass(frozen=True)
class CellBatch:
    """The cells of robots ``owners`` as labelled edges, K cells of L candidate lines each.

    Points of the plane are complex numbers x + iy. owners: (K,) robot indices; start, end:
    (K, L) edge ends, the present edges first and in counter-clockwise order, each edge's
    end the next one's start; labels: (K, L) the robot (>= 0) or polygon edge (-(l + 1))
    each line comes from; present: (K, L) the line is an edge of positive length; mass: (K,)
    m_i, 0 for an empty cell; centroid: (K,) c_i, the nearest point of S for an empty cell
    (Section 4.2).
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
        return as_vectors(self.start[k][self.present[k]])


@runtime_checkable
class DensityModel(Protocol):
    """A non-uniform phi at the current time and its integrals over a batch of cells.

    weigh: the batch with m_i, c_i of phi; jacobian_blocks / boundary_rates: as the
    functions of that name here (boundary_rates with the dphi/dt term of Proposition 1);
    jacobian_times: the blocks applied to own (K,) and others (K, L) complex vectors,
    (K,) complex, as ``jacobian_times`` here (what a robot's step needs, without the blocks).
    """

    def weigh(self, batch: CellBatch) -> CellBatch: ...

    def jacobian_blocks(
        self, batch: CellBatch, points: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def jacobian_times(
        self, batch: CellBatch, points: np.ndarray, own: np.ndarray, others: np.ndarray
    ) -> np.ndarray: ...

    def boundary_rates(
        self, batch: CellBatch, points: np.ndarray, domain: CoverageDomain
    ) -> np.ndarray: ...


def check_density(density: object) -> None:
    """Raise TypeError unless ``density`` is None (uniform) or a DensityModel."""
    # isinstance against a runtime Protocol inspects the class each time: a robot checks
    # a fresh snapshot every tick, so the classes that passed once are remembered.
    if density is None or type(density) in _DENSITY_MODELS:
        return
    if not isinstance(density, DensityModel):
        raise TypeError(
            f"density must be None (uniform) or a tvd.density.Density, not {type(density)}"
        )
    _DENSITY_MODELS.add(type(density))


_DENSITY_MODELS: set[type] = set()


def cell_jacobian_blocks(
    batch: CellBatch, points: np.ndarray, density: DensityModel | None
) -> tuple[np.ndarray, np.ndarray]:
    """``jacobian_blocks`` for phi = 1 (closed form) or the density's own integrals."""
    if density is None:
        return jacobian_blocks(batch, points)
    return density.jacobian_blocks(batch, points)


def cell_rates(
    batch: CellBatch, points: np.ndarray, domain: CoverageDomain, density: DensityModel | None
) -> np.ndarray:
    """dc/dt of Proposition 1, (K,) complex: ``boundary_rates`` for phi = 1, else both of its
    terms."""
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


def make_domain(polygon: np.ndarray, polygon_velocity: np.ndarray | None = None) -> CoverageDomain:
    """Validate S (``polygon: (k, 2)``) and its vertex velocities; orient both CCW.

    ``polygon_velocity: (k, 2)`` defaults to a still domain. Raises ValueError (see
    ``validate_polygon``).
    """
    vertices = np.array(polygon, dtype=np.float64)  # a copy: the CoverageDomain is immutable
    if vertices.ndim != 2 or vertices.shape[1] != 2:
        raise ValueError(f"polygon must have shape (k, 2), got {vertices.shape}")
    k = vertices.shape[0]
    if k < 3:
        raise ValueError(f"polygon needs at least 3 vertices, got {k}")
    if k > MAX_POLYGON_VERTICES:
        raise ValueError(f"polygon has {k} vertices, more than the {MAX_POLYGON_VERTICES} allowed")
    if not np.isfinite(vertices).all():
        raise ValueError("polygon vertices contain NaN or inf")
    if polygon_velocity is None:
        velocities = np.zeros_like(vertices)
    else:
        velocities = np.array(polygon_velocity, dtype=np.float64)
        if velocities.shape != vertices.shape:
            raise ValueError(
                f"polygon_velocity must have the polygon's shape {vertices.shape}, "
                f"got {velocities.shape}"
            )
        if not np.isfinite(velocities).all():
            raise ValueError("polygon_velocity contains NaN or inf")
    # Plane vectors as complex numbers: conj(a) b = a . b + i a x b in one operation.
    z = vertices.view(np.complex128)[:, 0]
    edges = _following(z) - z
    lengths = np.abs(edges)
    size = 0.5 * float(lengths.sum())
    if not size > 0.0 or lengths.min() <= GEOMETRY_TOL * size:
        first = int(np.argmin(lengths))
        raise ValueError(
            f"polygon vertex {first} repeats vertex {(first + 1) % k}: zero-length edge"
        )
    bend = np.concatenate((edges[-1:], edges[:-1])).conj() * edges
    turn = bend.imag
    area2 = float((z.conj() * edges).imag.sum())
    flat = 1e-9 * size * size
    # Only left turns adding up to one full turn: a simple convex polygon. Anything else is
    # examined further, to say what is wrong.
    if area2 > flat and turn.min() >= -flat:
        if abs(float(np.arctan2(turn, bend.real).sum()) - 2.0 * np.pi) <= 1e-6:
            return _derive(vertices, velocities, size, edges, lengths)
    elif area2 < -flat and turn.max() <= flat:
        return make_domain(vertices[::-1], velocities[::-1])
    crossing = _crossing_edges(vertices)
    if crossing is not None:
        raise ValueError(
            f"polygon is self-intersecting: edge {crossing[0]} crosses edge {crossing[1]}"
        )
    if abs(area2) <= flat:
        raise ValueError("polygon has zero area (its vertices are collinear)")
    reflex = turn < -flat if area2 > 0.0 else turn > flat
    if reflex.any():
        raise ValueError(f"polygon is not convex: reflex angle at vertex {int(np.argmax(reflex))}")
    raise ValueError("polygon is self-intersecting: its boundary winds around more than once")


def _following(array: np.ndarray) -> np.ndarray:
    """``array`` shifted by one along its first axis: row l holds row l + 1 (wrapping)."""
    return np.concatenate((array[1:], array[:1]))


def _derive(
    vertices: np.ndarray,
    velocities: np.ndarray,
    size: float,
    edges: np.ndarray,
    lengths: np.ndarray,
) -> CoverageDomain:
    """The CoverageDomain of valid CCW ``vertices`` and ``velocities`` (k, 2), with its derived
    arrays; ``edges`` (k,) complex, ``lengths`` (k,) their lengths."""
    z = vertices.view(np.complex128)[:, 0]
    u = velocities.view(np.complex128)[:, 0]
    normal = edges * (-1j / lengths)  # edge turned clockwise by a right angle: outward
    start_speed = (normal.conj() * u).real
    end_speed = (normal.conj() * _following(u)).real
    # nu(q) = nu_start + (nu_end - nu_start) (q - vertex) . edge / |edge|^2 along edge l.
    gradient = ((end_speed - start_speed) / (lengths * lengths)) * edges
    return CoverageDomain(
        vertices=vertices,
        velocities=velocities,
        size=size,
        normals=normal,
        offsets=(normal.conj() * z).real,
        speed_offset=start_speed - (gradient.conj() * z).real,
        speed_gradient=gradient,
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


def signed_area(polygon: np.ndarray) -> float:
    """Shoelace area of a polygon's ``(k, 2)`` vertices (m^2), positive when they run
    counter-clockwise: the mass of S for phi = 1 (Section 4.2's sum over its edges)."""
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z-component of the cross product of stacked 2-vectors: (..., 2) x (..., 2) -> (...)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def build_cells(
    points: np.ndarray, owners: np.ndarray, candidates: np.ndarray, domain: CoverageDomain
) -> CellBatch:
    """The clipped Voronoi cells of ``owners: (K,)`` among ``points: (n, 2)``.

    candidates: (K, D), or (1, D) shared by every cell, robot indices whose bisectors may
    cut each cell, -1 for padding (the owner itself is ignored). A robot coincident with the
    owner and of lower index owns the cell, leaving the owner's cell empty; one of higher
    index is ignored. The batch keeps as many lines per cell as the largest cell has edges.
    """
    lines = _clip(points, owners, candidates, domain)
    tol, present, normal = domain.tol, lines.present, lines.normal
    count = len(owners)
    # Relative to the owner; the clockwise direction is -i normal, so the start offset
    # normal - lower clockwise is normal (offset + i lower).
    start = normal * (lines.offset + 1j * np.where(present, lines.lower, 0.0))
    # Counter-clockwise order of a convex cell's edges is the order of their normals' angles,
    # from -pi exclusive (+ 0.0 turns a normal's -0.0 into +0.0, whose angle is +pi).
    angle = np.where(present, np.arctan2(normal.imag + 0.0, normal.real), np.inf)
    edges = present.sum(axis=1)
    width = max(int(edges.max()), 1)
    # Each vertex is computed once, as the start of its edge, and reused as the end of the
    # previous edge: nearly parallel bisectors (nearly coincident robots) make a vertex
    # ill-conditioned, and two independent copies of it would leave the boundary open. So
    # the edges' starts are gathered in order, the first edge's again after the last one
    # and in place of the padding, and each edge ends where the next column starts.
    present = np.arange(width) < edges[:, None]
    order = np.argsort(angle, axis=1)[:, :width]
    order = np.where(present, order, order[:, :1]).take(_ring(width), axis=1)
    rows = np.arange(count)[:, None]
    vertex = start[rows, order]  # (K, W + 1)
    # Moments about a vertex of the cell, not the owner: a sliver cell far from its robot
    # would otherwise lose its digits to cancellation. Padding adds nothing (a = b = 0).
    origin = vertex[:, 0]
    about = vertex - origin[:, None]
    a, b = about[:, :-1], about[:, 1:]
    twice_area = (a.conj() * b).imag
    mass = 0.5 * twice_area.sum(axis=1)
    empty = mass <= tol * tol
    moment = (twice_area * (a + b)).sum(axis=1)
    me = lines.me
    centroid = me + origin + moment / (6.0 * np.where(empty, 1.0, mass))
    if empty.any():
        mass = np.where(empty, 0.0, mass)
        for i in np.flatnonzero(empty):
            centroid[i] = complex(*nearest_point(domain, points[owners[i]])[0])
        present &= ~empty[:, None]
    vertex += me[:, None]
    return CellBatch(
        owners=owners,
        start=vertex[:, :-1],
        end=vertex[:, 1:],
        labels=lines.labels[rows, order[:, :-1]],
        present=present,
        mass=mass,
        centroid=centroid,
    )


@cache
def _ring(width: int) -> np.ndarray:
    """Columns 0, 1, ..., width - 1, 0: a row of ``width`` items closed into a ring."""
    ring = np.arange(width + 1) % width
    ring.flags.writeable = False
    return ring


def as_vectors(numbers: np.ndarray) -> np.ndarray:
    """Complex numbers (...) as stacked 2-vectors (..., 2), a view when the last axis is
    contiguous (the inverse of ``as_complex``)."""
    if numbers.ndim and numbers.strides[-1] != numbers.itemsize:
        numbers = np.ascontiguousarray(numbers)
    return numbers.view(np.float64).reshape(*numbers.shape, 2)


def neighbor_candidates(
    points: np.ndarray, owners: np.ndarray, candidates: np.ndarray, domain: CoverageDomain
) -> np.ndarray:
    """(K, D) bool: which ``candidates`` (K, D) robot indices, -1 padding, may bound the cell
    of each of ``owners`` (K,) among ``points: (n, 2)``.

    A superset of its Voronoi neighbours in S, for deciding whose cells to build next: the
    half-plane intersection of ``build_cells`` with every constraint loosened by the
    tolerance, no tie-breaking and none of the cell's integrals, so that nothing that
    touches the cell is missed (at worst a robot whose bisector only touches it). The owner
    itself, robots coincident with it and padding are never candidates.
    """
    tol = domain.tol
    count, k = len(owners), len(domain.offsets)
    where = as_complex(points)
    me = where[owners]
    offsets_to = where[candidates] - me[:, None]  # padding reads points[-1]: masked
    distance = np.abs(offsets_to)
    valid = (distance > tol) & (candidates >= 0)
    # An invalid line gets a zero normal and the size of S as offset: it never binds.
    normal = np.empty((count, k + candidates.shape[1]), dtype=np.complex128)
    normal[:, :k] = domain.normals
    normal[:, k:] = offsets_to * (valid / np.maximum(distance, tol))
    offset = np.empty(normal.shape)
    offset[:, :k] = domain.offsets - (me[:, None] * domain.normals.conj()).real
    offset[:, k:] = np.where(valid, 0.5 * distance, domain.size)
    upper, lower = _piece_bounds(normal, offset, tol, loosen=True)
    return valid & (upper[:, k:] > lower[:, k:] - tol)


class _Lines(NamedTuple):
    """The lines of a batch of cells (relative to each owner) and their pieces in the cell.

    Plane vectors as complex numbers. me: (K,) owners; normal: (K, L) unit normals; offset,
    lower: (K, L) normal . q <= offset, the piece starts at offset normal + lower (-ny, nx);
    labels, present: (K, L) as in CellBatch, before the cell's mass is known.
    """

    me: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    lower: np.ndarray
    labels: np.ndarray
    present: np.ndarray


def _clip(
    points: np.ndarray, owners: np.ndarray, candidates: np.ndarray, domain: CoverageDomain
) -> _Lines:
    """Each candidate line's piece inside all the other half-planes: see ``build_cells``."""
    tol = domain.tol
    count = len(owners)
    k = len(domain.offsets)
    lines = k + candidates.shape[1]
    where = as_complex(points)
    me = where[owners]  # work relative to the owner: cells far from the origin keep digits
    offsets_to = where[candidates] - me[:, None]  # padding reads points[-1], unused
    distance = np.abs(offsets_to)
    # The owner itself (distance 0) and robots coincident with it cast no bisector.
    close = distance <= tol
    valid = ~close & (candidates >= 0)
    rival = close & (candidates < owners[:, None])
    dominated = np.any(rival & (candidates >= 0), axis=1) if rival.any() else None

    # Line l: normal_l . q <= offset_l, q relative to the owner. Polygon edges come first:
    # where a bisector lies on an edge of S, the lower line index wins. An unused candidate
    # gets a zero normal and a positive offset: a constraint that never binds.
    normal = np.empty((count, lines), dtype=np.complex128)
    normal[:, :k] = domain.normals
    normal[:, k:] = offsets_to * (valid / np.maximum(distance, tol))
    offset = np.empty((count, lines))
    offset[:, :k] = domain.offsets - (me[:, None] * domain.normals.conj()).real
    offset[:, k:] = np.where(valid, 0.5 * distance, domain.size)
    labels = np.empty((count, lines), dtype=np.int64)
    labels[:, :k] = _polygon_labels(k)
    labels[:, k:] = candidates
    active = np.ones((count, lines), dtype=bool)
    active[:, k:] = valid

    upper, lower = _piece_bounds(normal, offset, tol, loosen=False)
    present = active & (upper > lower + tol)
    if dominated is not None:
        present &= ~dominated[:, None]
    return _Lines(me, normal, offset, lower, labels, present)


# Pairs (line, constraint) per pass of ``_piece_bounds``: its (2, L, K, L) temporaries then
# stay within a few MB, in cache. Measured against one pass for all cells: tvd_d1 of 1000
# robots 26 -> 6.6 ms, local_steps of 500 two-hop views 41 -> 22 us per view.
PIECE_PAIRS = 1 << 16

# The LP's columns of a line from its row (nx, ny, o): the foot (o nx, o ny, -1) and the
# clockwise direction (ny, -nx, 0).
_COLUMN_ENDS = np.array([-1.0, 0.0])[:, None, None]
_CLOCKWISE = np.array([1.0, -1.0])[:, None]


def _piece_bounds(
    normal: np.ndarray, offset: np.ndarray, tol: float, loosen: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Where each line's piece inside all the other half-planes starts and ends, (K, L).

    normal: (K, L) unit normals as complex numbers (zero for a line that is no constraint),
    offset: (K, L), half-planes normal . q <= offset. Line l is foot_l + t direction_l with
    foot_l = offset_l normal_l and direction_l = (-ny, nx), which keeps the interior on the
    left so edges run counter-clockwise; it must satisfy normal_m . q <= offset_m for every
    m: t rate_lm <= slack_lm, an upper bound on t where rate_lm > 0, a lower one where < 0.
    Returns (upper, lower) over m; the piece is empty unless upper > lower.

    loosen: every slack grows by tol (a superset of the pieces, no tie-breaking). Otherwise
    the slack of (near) parallel pairs is shifted by tol: of two identical lines (same side,
    same offset) the first excludes the second, never the reverse, so no edge counts twice,
    and a line never excludes itself; the shift is tol for rate 0 and 0 from |rate| = 1e-12
    on, so that vertices of lines that do cross are exact.
    """
    count, lines = offset.shape
    step = max(1, PIECE_PAIRS // (lines * lines))
    if count > step:
        parts = [
            _piece_bounds(normal[s : s + step], offset[s : s + step], tol, loosen)
            for s in range(0, count, step)
        ]
        return tuple(np.concatenate(bounds) for bounds in zip(*parts, strict=True))
    # Computed with the opposite direction (y, -x), so that the sign of clockwise_rate
    # tells the kinds apart without a negation: clockwise_rate = -rate, excess = -slack.
    # Every pair comes from one batched matrix product: row (normal_m, offset_m) of
    # constraint m times the columns (foot_l, -1) and (clockwise_l, 0) of line l, stored
    # [m, k, l] so that the reductions over m run along the outermost axis, which numpy does
    # a few times faster than along the innermost one. In-place operations where possible:
    # at these sizes each numpy call costs more than its arithmetic.
    rows = np.empty((count, 3, lines))
    rows[:, 0] = normal.real
    rows[:, 1] = normal.imag
    rows[:, 2] = offset
    columns = np.empty((2, count, 3, lines))
    np.multiply(rows[:, :2], rows[:, 2:], out=columns[0, :, :2])
    np.multiply(rows[:, 1::-1], _CLOCKWISE, out=columns[1, :, :2])
    columns[:, :, 2] = _COLUMN_ENDS
    pairs = np.empty((2, lines, count, lines))
    np.matmul(rows.swapaxes(1, 2), columns, out=pairs.swapaxes(1, 2))
    excess, clockwise_rate = pairs
    if loosen:
        excess -= tol
    else:
        shift = np.square(clockwise_rate)
        shift *= -1e24 * tol
        shift += tol
        np.maximum(shift, 0.0, out=shift)
        shift *= _earlier_sign(lines)
        excess += shift
    # slack / rate is the bound and the sign of rate its kind. A (near) parallel constraint
    # gives +-inf or a huge bound: harmless when satisfied (slack > 0), and when violated
    # an upper bound of -inf or a lower one of +inf, which excludes the whole line.
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        bound = excess / clockwise_rate
        # -inf where bounds are upper ones: copysign(inf, clockwise_rate), signed zeros
        # included, but as a division, which numpy vectorises.
        side = np.inf / clockwise_rate
    return np.maximum(bound, side).min(axis=0), np.minimum(bound, side).max(axis=0)


@cache
def _polygon_labels(k: int) -> np.ndarray:
    """Labels -(l + 1) of the k edges of S, (k,)."""
    labels = -np.arange(1, k + 1)
    labels.flags.writeable = False
    return labels


@cache
def _earlier_sign(lines: int) -> np.ndarray:
    """(lines, 1, lines) [m, 0, l] = +1 where m < l, else -1: which of two identical lines
    wins."""
    sign = np.where(np.tri(lines, k=-1, dtype=bool).T, 1.0, -1.0)[:, None, :]
    sign.flags.writeable = False
    return sign


def cell_radius(batch: CellBatch, points: np.ndarray) -> np.ndarray:
    """(K,) the largest distance from each owner to its cell's vertices (0 when empty)."""
    reach = np.abs(batch.start - as_complex(points)[batch.owners][:, None])
    return np.where(batch.present, reach, 0.0).max(axis=1)


# Nearest robots offered to each cell of the whole team; a cell needing more is rebuilt.
TEAM_CANDIDATES = 16
# Cells built per build_cells call (build_cells_in_chunks): bounds its (K, L) arrays, and
# each chunk is only as wide as its widest cell's candidates (PIECE_PAIRS bounds the pairs).
BATCH_CELLS = 512


def team_cells(points: np.ndarray, domain: CoverageDomain) -> CellBatch:
    """Every robot's cell, ``points: (n, 2)``; owners are 0..n-1 in order."""
    n = len(points)
    everyone = np.arange(n)
    if n <= TEAM_CANDIDATES + 1:
        return build_cells(points, everyone, np.broadcast_to(everyone, (n, n)), domain)
    tree = cKDTree(points)
    distance, nearest = tree.query(points, k=TEAM_CANDIDATES + 1)
    batch = build_cells_in_chunks(points, everyone, nearest, domain)
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


def build_cells_in_chunks(
    points: np.ndarray, owners: np.ndarray, candidates: np.ndarray, domain: CoverageDomain
) -> CellBatch:
    """``build_cells`` of many cells, BATCH_CELLS at a time: candidates (K, D), each chunk
    trimmed to its widest row (a row's -1 padding at its end)."""
    if len(owners) <= BATCH_CELLS:
        return build_cells(points, owners, candidates, domain)
    parts = []
    for s in range(0, len(owners), BATCH_CELLS):
        rows = candidates[s : s + BATCH_CELLS]
        width = max(int((rows >= 0).sum(axis=1).max()), 1)
        parts.append(build_cells(points, owners[s : s + BATCH_CELLS], rows[:, :width], domain))
    return concatenate_cells(parts)


# Nearest robots of its view offered first to each cell by ``local_cells``; a cell that needs
# more is rebuilt with twice as many, or LOCAL_GROWTH times as many when fewer than
# PRUNED_CELLS cells need more. A near-CVT cell's neighbours are its ~6 nearest.
LOCAL_CANDIDATES = 8
# The few cells left open near a CVT (boundary cells, reaching to the edges of S) are so
# rebuilt in one round more, not two: a round's numpy calls cost more than the pairs of 4x
# the lines for those few cells; many open cells (a layout far from a CVT) grow 2x, as 4x
# lines cost more there. Measured on a 500-brain pack's batches: 3 % faster from tick 25
# on, 2 % slower in its first 16 ticks than 2x always (4x always: 8 % slower there).
LOCAL_GROWTH = 4
# Relative to the size of S: a robot left out of a cell whose bisector passes within this
# of one of its vertices may cut it, and the cell is rebuilt with it (``_reached``).
LOCAL_MARGIN = 1e-9
# Fewer cells than this are built with every candidate at once: for one robot's step the
# numpy calls of the pruning cost more than the arithmetic they save.
PRUNED_CELLS = 32


def local_cells(
    points: np.ndarray,
    owners: np.ndarray,
    candidates: np.ndarray,
    domain: CoverageDomain,
) -> CellBatch:
    """The cells of ``owners`` (K,), each among its own ``candidates`` (K, D) only, or (1, D)
    shared (robot indices in increasing order, -1 padding at the end of a row):
    ``build_cells``' cells.

    The half-plane intersection costs L^2 per cell for L lines, so each cell is first built
    from its LOCAL_CANDIDATES nearest candidates (kept in index order, so that coincident
    robots tie-break as with all of them), and rebuilt with more (see LOCAL_GROWTH), and so
    on, while a candidate left out may cut it: it is within twice the cell's radius (only a
    robot that near can, as in ``team_cells``) and its bisector reaches one of the cell's
    vertices (``_reached``), which spares most of the rounds that test alone would take.
    """
    width = candidates.shape[1]
    if width <= LOCAL_CANDIDATES or len(owners) < PRUNED_CELLS:
        return build_cells_in_chunks(points, owners, candidates, domain)
    if len(candidates) != len(owners):  # one row shared by every cell
        candidates = np.broadcast_to(candidates, (len(owners), width))
    where = as_complex(points)
    distance = np.abs(where[candidates] - where[owners][:, None])
    distance[candidates < 0] = np.inf
    order = np.argsort(distance, axis=1)
    rows, batch = np.arange(len(owners)), None
    unclosed, taken = rows, LOCAL_CANDIDATES
    while len(unclosed):
        if taken >= width:
            cells = build_cells_in_chunks(points, owners[unclosed], candidates[unclosed], domain)
            return cells if batch is None else _replace(batch, unclosed, cells)
        nearest = np.sort(order[unclosed, :taken], axis=1)
        cells = build_cells_in_chunks(
            points, owners[unclosed], candidates[unclosed[:, None], nearest], domain
        )
        batch = cells if batch is None else _replace(batch, unclosed, cells)
        beyond = distance[unclosed, order[unclosed, taken]]  # the nearest one left out
        near = beyond <= 2.0 * cell_radius(cells, points) + domain.tol
        if near.any():  # near enough to cut: does one of them reach a vertex?
            left, rest = unclosed[near], order[unclosed[near], taken:]
            near[near] = _reached(
                cells.start[near],
                cells.present[near],
                where[owners[left]],
                where[candidates[left[:, None], rest]],
                distance[left[:, None], rest],
                LOCAL_MARGIN * domain.size,
            )
        unclosed = unclosed[near]
        taken *= LOCAL_GROWTH if len(unclosed) < PRUNED_CELLS else 2
    return batch


def _reached(
    start: np.ndarray,
    present: np.ndarray,
    me: np.ndarray,
    others: np.ndarray,
    distance: np.ndarray,
    margin: float,
) -> np.ndarray:
    """(U,) bool: may a robot of ``others`` cut each cell, built without them?

    start, present: (U, W) the cells' vertices (complex, m) and which are; me: (U,) their
    owners; others: (U, R) the robots left out and distance: (U, R) their distances from
    the owner (inf for padding). Robot j's bisector cuts the cell only if a vertex v lies
    beyond it, (v - p) . (q_j - p) > |q_j - p|^2 / 2; within ``margin`` (m) of it counts as
    beyond, so that a robot said to miss the cell changes none of its pieces' bounds, and
    so does a robot within 2 margin (a coincident rival may own the cell).
    """
    about = np.where(present, start - me[:, None], 0.0)[:, None, :]
    reach = ((others - me[:, None]).conj()[:, :, None] * about).real.max(axis=2, initial=0.0)
    return (reach > distance * (0.5 * distance - margin)).any(axis=1)


# CellBatch fields with one entry per line, (K, L, ...); the others are per cell.
_LINE_FIELDS = ("start", "end", "labels", "present")


def concatenate_cells(parts: list[CellBatch]) -> CellBatch:
    """The cells of ``parts`` in order, padded to the widest part's lines."""
    if len(parts) == 1:
        return parts[0]
    width = max(part.labels.shape[1] for part in parts)
    return CellBatch(
        **{
            name: np.concatenate([_widen(part, name, width) for part in parts])
            for name in CellBatch.__dataclass_fields__
        }
    )


def _widen(batch: CellBatch, name: str, width: int) -> np.ndarray:
    """Field ``name`` of ``batch``, a per-line field padded with absent lines to ``width``."""
    array = getattr(batch, name)
    if name not in _LINE_FIELDS or array.shape[1] == width:
        return array
    # Zeros (False) and a slice assignment: np.pad costs ~10x more at a local step's sizes.
    wide = np.zeros((len(array), width, *array.shape[2:]), dtype=array.dtype)
    wide[:, : array.shape[1]] = array
    return wide


def _replace(batch: CellBatch, rows: np.ndarray, rebuilt: CellBatch) -> CellBatch:
    """``batch`` with ``rows`` replaced by ``rebuilt`` (either may have more lines per cell)."""
    width = max(batch.labels.shape[1], rebuilt.labels.shape[1])
    fields = {}
    for name in CellBatch.__dataclass_fields__:
        merged = _widen(batch, name, width).copy()
        merged[rows] = _widen(rebuilt, name, width)
        fields[name] = merged
    return CellBatch(**fields)


def nearest_point(domain: CoverageDomain, point: np.ndarray) -> tuple[np.ndarray, int, float]:
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
    domain: CoverageDomain, point: np.ndarray
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


def jacobian_blocks(batch: CellBatch, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form blocks of dc/dp for the batch's rows (non-empty cells).

    Returns off: (K, L, 2, 2), dc_i/dp_j by eq. (6) (Section 2.3) for the edge shared
    with robot labels[k, l] (zero where there is none), and diagonal: (K, 2, 2), dc_i/dp_i
    by eq. (7). Empty cells get zero blocks.

    Along a shared edge from v1 to v2 (d = v2 - v1) the Lemma's integral of
    (q - c)(q - a)^T ds is |d| [u w^T + (u d^T + d w^T) / 2 + d d^T / 3] with u = v1 - c,
    w = v1 - a: with a = p_i it gives dc_i/dp_i, and with a = p_j it is the same plus
    |d| (u + d / 2)(p_i - p_j)^T, so one bracket serves both blocks.
    """
    where = as_complex(points)
    me = where[batch.owners][:, None]
    # Polygon labels read wrapped rows, masked by the weight.
    gap = me - np.take(where, batch.labels, mode="wrap")
    d = batch.end - batch.start
    weight = _shared_weight(batch, d, gap)
    u, w = as_vectors(batch.start - batch.centroid[:, None]), as_vectors(batch.start - me)
    d, gap = as_vectors(d), as_vectors(gap)
    half = 0.5 * d
    about_me = _outer(u, w + half) + _outer(d, 0.5 * w + d / 3.0)
    diagonal = np.einsum("kl,klab->kab", weight, about_me)
    off = -weight[..., None, None] * (about_me + _outer(u + half, gap))
    return off, diagonal


def _shared_weight(batch: CellBatch, d: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """|d| / (m_i |p_i - p_j|) on shared edges, 0 elsewhere (and for empty cells), (K, L).

    d: (K, L) the edges; gap: (K, L) p_i - p_j for the robot j each line comes from.
    """
    return np.divide(
        np.abs(d),
        np.abs(gap) * batch.mass[:, None],
        out=np.zeros(d.shape),
        where=batch.present & (batch.labels >= 0),
    )


def jacobian_times(
    batch: CellBatch, points: np.ndarray, own: np.ndarray, others: np.ndarray
) -> np.ndarray:
    """(dc/dp r)_i = sum_j dc_i/dp_j r_j for the batch's rows, (K,), without the blocks.

    own: (K,) r_i; others: (K, L) r_j of the robot each line comes from (read only on shared
    edges); vectors as complex numbers. The closed form of ``jacobian_blocks`` (eqs. (6),
    (7)) applied to vectors: with the bracket's u w^T + ... written as
    u (A . v) + d (B . v), each shared edge adds |d| / (m_i |p_i - p_j|)
    [u (A . (r_i - r_j)) + d (B . (r_i - r_j)) - (u + d / 2) ((p_i - p_j) . r_j)],
    A = w + d / 2, B = w / 2 + d / 3. TVD-D1 needs only this product, at a fraction of the
    cost of the 2 x 2 blocks.
    """
    return apply_jacobian(jacobian_terms(batch, points), own, others)


class JacobianTerms(NamedTuple):
    """What ``jacobian_times`` computes before it reads r, (K, L) each, complex unless said:
    weight (real) |d| / (m_i |p_i - p_j|), 0 off shared edges; u; d; gap = p_i - p_j;
    along_u = A; along_d = B; across = u + d / 2. The rows of a slice of each are the terms
    of those rows.
    """

    weight: np.ndarray
    u: np.ndarray
    d: np.ndarray
    gap: np.ndarray
    along_u: np.ndarray
    along_d: np.ndarray
    across: np.ndarray


def jacobian_terms(batch: CellBatch, points: np.ndarray) -> JacobianTerms:
    """``jacobian_times``' terms of ``batch``: computed once for a batch whose product is
    taken with several r (TVD-DA: its motion field v, then its references)."""
    # Plane vectors as complex numbers: a . b = Re(a conj(b)).
    where = as_complex(points)
    me = where[batch.owners][:, None]
    start = batch.start
    d = batch.end - start
    gap = me - np.take(where, batch.labels, mode="wrap")  # polygon labels: masked by weight
    u = start - batch.centroid[:, None]
    w = start - me
    half = 0.5 * d
    weight = _shared_weight(batch, d, gap)
    return JacobianTerms(weight, u, d, gap, w + half, 0.5 * w + d / 3.0, u + half)


def apply_jacobian(terms: JacobianTerms, own: np.ndarray, others: np.ndarray) -> np.ndarray:
    """``jacobian_times`` from its ``terms`` (K, L): own (K,), others (K, L) -> (K,)."""
    theirs = others.conj()
    delta = own.conj()[:, None] - theirs
    products = (
        terms.u * (terms.along_u * delta).real
        + terms.d * (terms.along_d * delta).real
        - terms.across * (terms.gap * theirs).real
    )
    return (terms.weight * products).sum(axis=1)


def as_complex(vectors: np.ndarray) -> np.ndarray:
    """Stacked 2-vectors (..., 2) as complex numbers (...), a view when contiguous."""
    if not vectors.flags.c_contiguous:
        vectors = np.ascontiguousarray(vectors)
    numbers = vectors.view(np.complex128)
    return numbers.reshape(numbers.shape[:-1])


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stacked outer products (..., 2) x (..., 2) -> (..., 2, 2)."""
    return a[..., :, None] * b[..., None, :]


def boundary_rates(batch: CellBatch, points: np.ndarray, domain: CoverageDomain) -> np.ndarray:
    """dc_i/dt of Proposition 1 for the batch's cells, (K,) complex.

    The boundary term: on a cell edge lying on edge l of S the outward normal speed nu is
    linear in position (vertex velocities interpolate linearly), so with h half the edge,
    q_m its midpoint and nu(q_m -+ h) = nu_m -+ delta at its ends,
    integral (q - c) nu ds = 2 |h| [ (q_m - c) nu_m + h delta / 3 ].
    An empty cell gets the velocity of its nearest point of S.
    """
    labels = batch.labels
    boundary = batch.present & (labels < 0)
    rates = np.zeros(len(labels), dtype=np.complex128)
    if boundary.any():  # cells inside S have no boundary term
        # Plane vectors as complex numbers: a . b = Re(a conj(b)). Label -(l + 1) is edge
        # l, i.e. ~label; other lines read edge 0, masked by ``length`` (not a wrapped take:
        # numpy wraps a large negative index by adding k in a loop, slow for large labels).
        edge = np.where(boundary, ~labels, 0)
        gradient = domain.speed_gradient[edge].conj()
        half = 0.5 * (batch.end - batch.start)
        middle = batch.start + half
        nu = domain.speed_offset[edge] + (gradient * middle).real
        delta = (gradient * half).real
        length = np.abs(half, out=np.zeros(labels.shape), where=boundary)
        integral = length * (nu * (middle - batch.centroid[:, None]) + delta / 3.0 * half)
        rates = 2.0 * integral.sum(axis=1)
    empty = batch.empty
    rates /= np.where(empty, 1.0, batch.mass)
    for i in np.flatnonzero(empty):
        rates[i] = complex(*nearest_point_derivatives(domain, points[batch.owners[i]])[2])
    return rates


def tessellate(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray | None = None,
    density: DensityModel | None = None,
) -> tuple[np.ndarray, CoverageDomain, CellBatch]:
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


def neighbour_pairs(
    positions: np.ndarray,
    polygon: np.ndarray,
    min_edge: float = 0.0,
    still: np.ndarray | None = None,
    within: float = math.inf,
) -> np.ndarray:
    """The pairs of robots at most ``within`` m apart whose cells in S share an edge at
    least ``min_edge`` m long.

    positions: (n, 2) m; polygon: (k, 2) vertices of S; still: (n,) bool, robots that stand
    still (covswarm.tvd.control's module notes): generators of the cells, in no pair
    themselves. Returns (m, 2) int indices, each row i < j, rows sorted. A robot with an
    empty cell (outside S and dominated) is in no pair.
    """
    points, _, batch = tessellate(positions, polygon)
    fixed = still_mask(still, len(points))
    length = np.abs(batch.end - batch.start)
    rows, lines = np.nonzero(batch.shared & (length >= min_edge))
    pairs = np.sort(np.stack([batch.owners[rows], batch.labels[rows, lines]], axis=1), axis=1)
    if fixed is not None:
        pairs = pairs[~(fixed[pairs[:, 0]] | fixed[pairs[:, 1]])]
    apart = np.hypot(*(points[pairs[:, 0]] - points[pairs[:, 1]]).T)
    return np.unique(pairs[apart <= within].reshape(-1, 2), axis=0).astype(np.int64)


def mass_centroid(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Mass m_i and centroid c_i of every cell (Section 4.2; closed forms, with a density too:
    covswarm.tvd.density).

    positions: (n, 2); polygon: (k, 2). Returns mass (n,) and centroid (n, 2); an empty
    cell has mass 0 and the nearest point of S as its centroid.
    """
    _, _, batch = tessellate(positions, polygon, density=density)
    return batch.mass.copy(), as_vectors(batch.centroid).copy()


def neighbors(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> list[set[int]]:
    """The Voronoi neighbours of each robot: those whose shared cell edge inside S has
    positive length (read off the cells' edges; no Delaunay triangulation).

    positions: (n, 2); polygon: (k, 2). Returns n sets of robot indices.
    """
    check_density(density)
    points, _, batch = tessellate(positions, polygon)
    return [set(batch.labels[i][batch.shared[i]].tolist()) for i in range(len(points))]


def centroid_jacobian(
    positions: np.ndarray, polygon: np.ndarray, density: DensityModel | None = None
) -> np.ndarray:
    """dc/dp, eqs. (6)/(7) (Section 2.3), in closed form (with a density too:
    covswarm.tvd.density).

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
    """dc/dt of Proposition 1 (Section 3, eq. (9)): the boundary term, plus the dphi/dt term.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2). For an empty cell
    it is the velocity of the nearest point of S.
    """
    points, domain, batch = tessellate(positions, polygon, polygon_velocity, density)
    return as_vectors(cell_rates(batch, points, domain, density))


def aggregate_error(
    positions: np.ndarray,
    polygon: np.ndarray,
    density: DensityModel | None = None,
    still: np.ndarray | None = None,
) -> float:
    """Aggregated CVT error e_a = ||p - c(p, t)|| over the whole team (Section 5), metres.

    still: (n,) bool, robots that stand still (covswarm.tvd.control's module notes): they
    bound the others' cells, and e_a is taken over the others (None: every robot counts).
    """
    points, _, batch = tessellate(positions, polygon, density=density)
    offsets = points - as_vectors(batch.centroid)
    fixed = still_mask(still, len(points))
    return float(np.linalg.norm(offsets if fixed is None else offsets[~fixed]))
