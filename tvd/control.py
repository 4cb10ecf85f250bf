"""Coverage control laws over a time-varying domain: TVD-C, TVD-D1 and one robot's local step.

With r = kappa (c - p) + dc/dt (dc/dt of Proposition 1; dropped when ``feedforward=False``):

- TVD-C (eq. TVD-C): pdot = (I - dc/dp)^-1 r, solved, never inverted;
- TVD-D1 (eq. TVD-D1): pdot = (I + dc/dp) r, the one-term Neumann truncation, whose row i
  needs only robot i's cell and its neighbours' cells.

Guards, because far from a CVT the spectral radius of dc/dp is 2 to 5 and I - dc/dp can be
near singular:

- a TVD-D1 row whose speed exceeds ``max_amplification`` times the largest |r_j| among the
  robot and its neighbours is rescaled to that speed, keeping its direction (near-coincident
  robots make dc/dp blow up as 1 / |p_i - p_j|);
- TVD-C falls back to the guarded TVD-D1 velocities when the solve fails, gives a non-finite
  result, or amplifies any robot's speed beyond ``max_amplification`` times max |r|.

With a density (a snapshot at the current time, covswarm.tvd.density.Density) c, dc/dp and dc/dt
are those of phi, dc/dt with both terms of Proposition 1.

A robot with an empty cell (outside S and dominated, or a coincident duplicate) gets
pdot = kappa (c_S - p) + dc_S/dt, c_S the centroid of the whole of S: it heads into S and
owns a cell as soon as it is in (or a duplicate is apart). Aiming at the nearest point of S
instead, as ``mass_centroid`` reports for such a cell, lets a robot left behind by a moving
domain ride just outside its edge, and several at one corner merge into one point; that
happened in the ``circle`` scenario.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from covswarm.tvd.coverage import (
    CellBatch,
    DensityModel,
    Domain,
    as_complex,
    as_vectors,
    build_cells,
    cell_jacobian_blocks,
    cell_neighbors,
    cell_rates,
    check_density,
    jacobian_times,
    make_domain,
    tessellate,
    validate_positions,
)

MAX_AMPLIFICATION = 10.0


@dataclass(frozen=True)
class LocalStep:
    """One robot's control step from its local view.

    velocity: (2,) TVD-D1 velocity; neighbors: ids of its Voronoi neighbours (positive-length
    shared edge); centroid: (2,) c_i; mass: m_i (0 for an empty cell).
    """

    velocity: np.ndarray
    neighbors: frozenset
    centroid: np.ndarray
    mass: float


def _references(
    batch: CellBatch,
    points: np.ndarray,
    domain: Domain,
    kappa: float,
    feedforward: bool,
    density: DensityModel | None,
) -> np.ndarray:
    """r_i = kappa (c_i - p_i) + dc_i/dt for the batch's cells, (K,) complex: what both laws
    act on.

    A robot with an empty cell aims at the centroid of the whole of S instead (module notes).
    """
    target = batch.centroid
    rate = cell_rates(batch, points, domain, density) if feedforward else None
    empty = batch.empty
    if empty.any():
        whole_centroid, whole_rate = _whole_domain(domain, density)
        target = np.where(empty, whole_centroid, target)
        if rate is not None:
            rate = np.where(empty, whole_rate, rate)
    reference = kappa * (target - as_complex(points)[batch.owners])
    return reference if rate is None else reference + rate


def _whole_domain(domain: Domain, density: DensityModel | None) -> tuple[complex, complex]:
    """Centroid of all of S and its rate: the cell of a robot alone in S."""
    alone = domain.vertices.mean(axis=0, keepdims=True)
    cell = _weigh(build_cells(alone, np.array([0]), np.full((1, 1), -1), domain), density)
    return cell.centroid[0], cell_rates(cell, alone, domain, density)[0]


def _d1_rows(
    batch: CellBatch,
    points: np.ndarray,
    own: np.ndarray,
    neighbor_references: np.ndarray,
    max_amplification: float,
    density: DensityModel | None,
) -> np.ndarray:
    """Rows of (I + dc/dp) r for the batch's robots, with the amplification guard, (K,).

    own: (K,) r_i; neighbor_references: (K, L) r_j of the robot each line comes from
    (ignored where the line is not a shared edge); vectors as complex numbers. Empty cells
    keep r_i.
    """
    others = np.where(batch.shared, neighbor_references, 0.0)
    if density is None:
        velocity = own + jacobian_times(batch, points, own, others)
    else:
        off, diagonal = density.jacobian_blocks(batch, points)
        velocity = own + as_complex(
            np.einsum("kab,kb->ka", diagonal, as_vectors(own))
            + np.einsum("klab,klb->ka", off, as_vectors(others))
        )
    scale = np.maximum(np.abs(own), np.abs(others).max(axis=1))
    factor = np.minimum(1.0, max_amplification * scale / np.maximum(np.abs(velocity), 1e-300))
    return np.where(batch.empty, own, velocity * factor)


def _check_kappa(kappa: float) -> None:
    if not (math.isfinite(kappa) and kappa > 0.0):
        raise ValueError(f"kappa must be a positive finite gain, got {kappa!r}")


def _team(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool,
    density: DensityModel | None,
) -> tuple[np.ndarray, CellBatch, np.ndarray]:
    _check_kappa(kappa)
    points, domain, batch = tessellate(positions, polygon, polygon_velocity, density)
    return points, batch, _references(batch, points, domain, kappa, feedforward, density)


def tvd_d1(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """TVD-D1 velocities pdot = (I + dc/dp)(kappa (c - p) + dc/dt) for the whole team.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2).
    """
    points, batch, references = _team(
        positions, polygon, polygon_velocity, kappa, feedforward, density
    )
    return as_vectors(_team_d1(batch, points, references, max_amplification, density))


def _team_d1(
    batch: CellBatch,
    points: np.ndarray,
    references: np.ndarray,
    max_amplification: float,
    density: DensityModel | None,
) -> np.ndarray:
    """TVD-D1 rows of the whole team from its cells and its r, (n,) complex."""
    neighbor_references = references[np.maximum(batch.labels, 0)]
    return _d1_rows(batch, points, references, neighbor_references, max_amplification, density)


def _control_jacobian(
    batch: CellBatch, points: np.ndarray, density: DensityModel | None
) -> scipy.sparse.csr_array:
    """Sparse dc/dp with the rows of empty cells zero (those robots do not use it)."""
    off, diagonal = cell_jacobian_blocks(batch, points, density)
    shared = batch.shared
    block_rows = np.concatenate(
        [batch.owners, np.broadcast_to(batch.owners[:, None], shared.shape)[shared]]
    )
    block_cols = np.concatenate([batch.owners, batch.labels[shared]])
    blocks = np.concatenate([diagonal, off[shared]])
    a, b = np.meshgrid(np.arange(2), np.arange(2), indexing="ij")
    rows = (2 * block_rows[:, None, None] + a).ravel()
    cols = (2 * block_cols[:, None, None] + b).ravel()
    n2 = 2 * len(points)
    return scipy.sparse.csr_array((blocks.ravel(), (rows, cols)), shape=(n2, n2))


def tvd_c(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """TVD-C velocities: solve (I - dc/dp) pdot = kappa (c - p) + dc/dt for the whole team.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2). Falls back to the
    guarded TVD-D1 velocities when I - dc/dp is numerically singular or the solution
    amplifies a robot's speed beyond ``max_amplification`` times max |r| (module notes).
    """
    points, batch, references = _team(
        positions, polygon, polygon_velocity, kappa, feedforward, density
    )
    jacobian = _control_jacobian(batch, points, density)
    system = scipy.sparse.eye_array(jacobian.shape[0], format="csc") - jacobian.tocsc()
    rhs = as_vectors(references).ravel()
    try:
        solution = scipy.sparse.linalg.splu(system).solve(rhs)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        solution = None
    if solution is not None:
        velocities = solution.reshape(-1, 2)
        bound = max_amplification * float(np.max(np.abs(references)))
        speeds = np.linalg.norm(velocities, axis=1)
        if np.all(np.isfinite(speeds)) and np.all(speeds <= bound):
            return velocities
    return as_vectors(_team_d1(batch, points, references, max_amplification, density))


def local_step(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> LocalStep:
    """One robot's TVD-D1 step from the robots it knows: itself, its neighbours, theirs.

    positions: {id: (2,)} including ``me``. Builds only the cells of ``me`` and of its
    neighbours (a local partial Voronoi diagram); equals row ``me`` of ``tvd_d1`` on the full
    team whenever ``positions`` contains the true two-hop neighbourhood. A robot whose cell
    is empty (outside S, every point of S closer to someone else) has no neighbours inside
    S; it is exact when ``positions`` holds the robots whose Voronoi regions in the plane
    border its own, and a robot that sees nobody takes all of S as its cell and heads for
    its centroid, which also brings it into S.
    """
    check_density(density)
    _check_kappa(kappa)
    if me not in positions:
        raise ValueError(f"positions must include the robot itself ({me!r})")
    ids = _ordered_ids(positions)
    points = validate_positions(np.array([positions[key] for key in ids], dtype=np.float64))
    domain = make_domain(polygon, polygon_velocity)
    index = ids.index(me)
    everyone = np.arange(len(ids))[None]
    # Our neighbours first (the half-plane intersection alone), then our cell and theirs in
    # one vectorised pass: one robot's step is a few dozen numpy calls on small arrays, so
    # calls count as much as cells, and the outer ring's cells are not needed.
    owners = np.concatenate(([index], cell_neighbors(points, index, domain)))
    batch = _weigh(build_cells(points, owners, everyone, domain), density)
    references = _references(batch, points, domain, kappa, feedforward, density)
    by_robot = np.zeros(len(ids), dtype=np.complex128)
    by_robot[owners] = references
    mine = _rows(batch, slice(0, 1))
    velocity = _d1_rows(
        mine,
        points,
        references[:1],
        by_robot[np.maximum(mine.labels, 0)],
        max_amplification,
        density,
    )
    neighbor_indices = mine.labels[0][mine.shared[0]]
    return LocalStep(
        velocity=as_vectors(velocity)[0],
        neighbors=frozenset(ids[j] for j in neighbor_indices.tolist()),
        centroid=as_vectors(mine.centroid)[0],
        mass=float(mine.mass[0]),
    )


def local_velocity(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """Robot ``me``'s TVD-D1 velocity (2,) from its two-hop neighbourhood; see ``local_step``."""
    return local_step(
        me, positions, polygon, polygon_velocity, kappa, feedforward, density, max_amplification
    ).velocity


def _weigh(batch: CellBatch, density: DensityModel | None) -> CellBatch:
    """The batch with the masses and centroids of phi (unchanged for uniform density)."""
    return batch if density is None else density.weigh(batch)


def _rows(batch: CellBatch, rows: np.ndarray | slice) -> CellBatch:
    """The cells at positions ``rows`` (indices (R,) or a slice) of ``batch``."""
    return CellBatch(
        **{name: getattr(batch, name)[rows] for name in CellBatch.__dataclass_fields__}
    )


def _ordered_ids(positions: Mapping[Hashable, np.ndarray]) -> list:
    """Ids sorted when they can be (so coincident robots tie-break as in the full team)."""
    try:
        return sorted(positions)
    except TypeError:
        return list(positions)
