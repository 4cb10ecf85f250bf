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

A robot with an empty cell (outside S and dominated, or a coincident duplicate) gets
pdot = kappa (q - p) + dq/dt, q the nearest point of S: it heads for S, tracking the
point of S it aims at, and a duplicate inside S holds still until it owns a cell.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from agent.coverage import (
    Cell,
    Domain,
    _domain,
    _require_uniform,
    _tessellate,
    cell_neighbors,
    clipped_cell,
    distance_order,
    jacobian_blocks,
    validate_positions,
)
from agent.coverage import boundary_rate as _boundary_rate
from agent.coverage import nearest_point_derivatives as _nearest_point_derivatives

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


def _reference(
    index: int, cell: Cell, points: np.ndarray, domain: Domain, kappa: float, feedforward: bool
) -> np.ndarray:
    """r_i = kappa (c_i - p_i) + dc_i/dt: the term TVD-C and TVD-D1 both act on, (2,)."""
    if cell.empty:
        target, _, rate = _nearest_point_derivatives(domain, points[index])
    else:
        target, rate = cell.centroid, _boundary_rate(cell, domain)
    reference = kappa * (target - points[index])
    return reference + rate if feedforward else reference


def _d1_row(
    reference: np.ndarray,
    diagonal: np.ndarray,
    off: np.ndarray,
    neighbor_references: np.ndarray,
    max_amplification: float,
) -> np.ndarray:
    """Row i of (I + dc/dp) r with the amplification guard.

    reference: (2,) r_i; diagonal: (2, 2) dc_i/dp_i; off: (E, 2, 2) dc_i/dp_j;
    neighbor_references: (E, 2) r_j.
    """
    velocity = reference + diagonal @ reference + np.einsum("eab,eb->a", off, neighbor_references)
    scale = max(
        float(np.linalg.norm(reference)),
        float(np.max(np.linalg.norm(neighbor_references, axis=1), initial=0.0)),
    )
    return _limit(velocity, max_amplification * scale)


def _limit(velocity: np.ndarray, bound: float) -> np.ndarray:
    speed = float(np.linalg.norm(velocity))
    if not np.isfinite(speed):
        return np.zeros(2)
    return velocity * (bound / speed) if speed > bound else velocity


def _team_terms(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool,
) -> tuple[np.ndarray, list[Cell], np.ndarray]:
    _check_kappa(kappa)
    points, domain, all_cells = _tessellate(positions, polygon, polygon_velocity)
    references = np.array(
        [
            _reference(i, cell, points, domain, kappa, feedforward)
            for i, cell in enumerate(all_cells)
        ]
    ).reshape(-1, 2)
    return points, all_cells, references


def _check_kappa(kappa: float) -> None:
    if not (np.isfinite(kappa) and kappa > 0.0):
        raise ValueError(f"kappa must be a positive finite gain, got {kappa!r}")


def tvd_d1(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: object = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """TVD-D1 velocities pdot = (I + dc/dp)(kappa (c - p) + dc/dt) for the whole team.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2).
    """
    _require_uniform(density)
    points, all_cells, references = _team_terms(
        positions, polygon, polygon_velocity, kappa, feedforward
    )
    velocities = references.copy()
    for i, cell in enumerate(all_cells):
        if cell.empty:
            continue
        columns, off, diagonal = jacobian_blocks(i, cell, points)
        velocities[i] = _d1_row(
            references[i], diagonal, off, references[columns], max_amplification
        )
    return velocities


def _control_jacobian(points: np.ndarray, all_cells: list[Cell]) -> scipy.sparse.csr_array:
    """Sparse dc/dp with the rows of empty cells zero (those robots do not use it)."""
    rows, cols, values = [], [], []
    for i, cell in enumerate(all_cells):
        if cell.empty:
            continue
        columns, off, diagonal = jacobian_blocks(i, cell, points)
        blocks = np.concatenate([diagonal[None], off])
        block_columns = np.concatenate([[i], columns])
        a, b = np.meshgrid(np.arange(2), np.arange(2), indexing="ij")
        rows.append(np.broadcast_to(2 * i + a, blocks.shape).ravel())
        cols.append((2 * block_columns[:, None, None] + b[None]).ravel())
        values.append(blocks.ravel())
    n2 = 2 * len(points)
    if not rows:
        return scipy.sparse.csr_array((n2, n2))
    return scipy.sparse.csr_array(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(n2, n2)
    )


def tvd_c(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: object = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """TVD-C velocities: solve (I - dc/dp) pdot = kappa (c - p) + dc/dt for the whole team.

    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2). Falls back to the
    guarded TVD-D1 velocities when I - dc/dp is numerically singular or the solution
    amplifies a robot's speed beyond ``max_amplification`` times max |r| (module notes).
    """
    _require_uniform(density)
    points, all_cells, references = _team_terms(
        positions, polygon, polygon_velocity, kappa, feedforward
    )
    jacobian = _control_jacobian(points, all_cells)
    system = scipy.sparse.eye_array(jacobian.shape[0], format="csc") - jacobian.tocsc()
    rhs = references.ravel()
    try:
        if len(points) <= 200:
            solution = scipy.linalg.solve(system.toarray(), rhs, check_finite=False)
        else:
            solution = scipy.sparse.linalg.splu(system).solve(rhs)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        solution = None
    if solution is not None:
        velocities = solution.reshape(-1, 2)
        bound = max_amplification * float(np.max(np.linalg.norm(references, axis=1)))
        if np.all(np.isfinite(velocities)) and np.all(
            np.linalg.norm(velocities, axis=1) <= bound
        ):
            return velocities
    return tvd_d1(
        points, polygon, polygon_velocity, kappa, feedforward, max_amplification=max_amplification
    )


def local_step(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: object = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> LocalStep:
    """One robot's TVD-D1 step from the robots it knows: itself, its neighbours, theirs.

    positions: {id: (2,)} including ``me``. Builds only the cells of ``me`` and of its
    neighbours (a local partial Voronoi diagram); equals row ``me`` of ``tvd_d1`` on the full
    team whenever ``positions`` contains the true two-hop neighbourhood.
    """
    _require_uniform(density)
    _check_kappa(kappa)
    if me not in positions:
        raise ValueError(f"positions must include the robot itself ({me!r})")
    ids = _ordered_ids(positions)
    points = validate_positions(np.array([positions[key] for key in ids], dtype=np.float64))
    domain = _domain(polygon, polygon_velocity)
    index = ids.index(me)
    everyone = np.arange(len(ids))

    def cell_of(i: int) -> Cell:
        return clipped_cell(i, points, distance_order(points, i, everyone), domain)

    cell = cell_of(index)
    reference = _reference(index, cell, points, domain, kappa, feedforward)
    if cell.empty:
        return LocalStep(reference, frozenset(), cell.centroid, 0.0)
    columns, off, diagonal = jacobian_blocks(index, cell, points)
    references = {
        int(j): _reference(int(j), cell_of(int(j)), points, domain, kappa, feedforward)
        for j in np.unique(columns)
    }
    neighbor_references = np.array([references[int(j)] for j in columns]).reshape(-1, 2)
    velocity = _d1_row(reference, diagonal, off, neighbor_references, max_amplification)
    neighbor_ids = frozenset(ids[j] for j in cell_neighbors(cell, domain.tol))
    return LocalStep(velocity, neighbor_ids, cell.centroid.copy(), cell.mass)


def local_velocity(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: object = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """Robot ``me``'s TVD-D1 velocity (2,) from its two-hop neighbourhood; see ``local_step``."""
    return local_step(
        me, positions, polygon, polygon_velocity, kappa, feedforward, density, max_amplification
    ).velocity


def _ordered_ids(positions: Mapping[Hashable, np.ndarray]) -> list:
    """Ids sorted when they can be (so coincident robots tie-break as in the full team)."""
    try:
        return sorted(positions)
    except TypeError:
        return list(positions)
