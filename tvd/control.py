"""Coverage control laws over a time-varying domain: TVD-C, TVD-D1, TVD-DA, one robot's step
and the steps of many robots at once (``local_steps``, one vectorised batch).

With r = kappa (c - p) + dc/dt (dc/dt of Proposition 1) and J = dc/dp:

- TVD-D1 (eq. (5), Section 2.3): pdot = (I + J) r, the one-term Neumann truncation, whose
  row i needs only robot i's cell and its neighbours' cells.
- TVD-DA (domain-motion feedforward, docs/tracking.md): with v(q) = A q + b the affine field
  fitted (least squares) to S's vertex velocities (near a density's bumps, blended with the
  bumps' own motion: ``motion_field``),

      pdot = v(p) + (I + J) (kappa (c - p) + rho),   rho = dc/dt - (I - J) v(p),

  i.e. TVD-D1 applied to r - (I - J) v(p), plus v(p). At a CVT of a domain moving by a
  similarity (translation, rotation, uniform scaling) with uniform density, v(p) solves
  (I - J) x = dc/dt exactly, so rho = 0 and the feedforward is TVD-C's; the one-hop
  correction (I + J) rho carries whatever the affine guess misses (non-affine vertex motion,
  a moving density, shear). Same information as a TVD-D1 step. The feedback kappa (c - p)
  goes inside (I + J) too, rather than beside it as Lloyd's plain feedback: the Neumann
  factor halves the decay time of the slow modes, 1.4 to 9 times lower errors measured
  (docs/tracking.md; scripts/da_variants.py "lloyd").
- TVD-C (eq. (4), Section 2.3): the exact law pdot = (I - J)^-1 r is kept as ``damping=0``; by
  default the feedback stays outside the inverse and only the feedforward is solved, damped
  (Tikhonov / Levenberg-Marquardt) toward a prior x0: pdot = kappa (c - p) + x with
  x = argmin |(I - J) x - dc/dt|^2 + damping^2 |x - x0|^2. I - J is near singular close to a
  CVT of a large team (the slow "sliding" modes of Lloyd's algorithm), which made the exact
  law fall back to TVD-D1 almost always; the damped solve is bounded,
  |x - x0| <= |dc/dt - (I - J) x0| / (2 damping). The prior is the affine field v(p)
  (``prior="affine"``, the default: exact at a CVT of a similarity motion, where it is the
  solution) or zero (``prior="zero"``, plain Tikhonov, which drops the feedforward along the
  sliding modes: for a translating team that is most of it; docs/tracking.md).

Without feedforward (``feedforward=False``) dc/dt and v are dropped: TVD-D1 and TVD-DA are
(I + J) kappa (c - p), the damped TVD-C is Lloyd's kappa (c - p), the exact TVD-C
(I - J)^-1 kappa (c - p).

Guards, counted (``TeamStep.guarded``, ``TeamStep.fallback``, ``LocalStep.guarded``), because
far from a CVT the spectral radius of J is 1.7 to 31 (median 4.4, 20 random robots in a
square: docs/library.md) and near-coincident robots make J grow as
1 / |p_i - p_j|:

- a row of (I + J) r (TVD-D1) or of (I + J) (kappa (c - p) + rho) (TVD-DA) whose speed
  exceeds ``max_amplification`` times the largest |r_j| (resp. |kappa (c_j - p_j) + rho_j|)
  among the robot and its neighbours is rescaled to that speed, keeping its direction;
- damped TVD-C: a row of x faster than ``max_amplification`` times max |dc/dt| is rescaled
  likewise; if the solve fails the feedforward is dropped for that step (a fallback);
- exact TVD-C: falls back to the guarded TVD-D1 velocities when the solve fails, gives a
  non-finite result, or amplifies any robot's speed beyond ``max_amplification`` max |r|.

With a density (a snapshot at the current time, covswarm.tvd.density.Density) c, dc/dp and
dc/dt are those of phi, dc/dt with both terms of Proposition 1.

Robots that stand still (``still``: a dead brain's robot, which no law moves) are generators
of the diagram with pdot = 0: the others' cells end where theirs begin, so no robot's
centroid falls on one. Their velocities are known, so each law is taken over the moving
robots alone: J's columns of still robots multiply zero (their r, rho and v read as 0 by
their neighbours' rows: (I + J_mm) for TVD-D1 and TVD-DA, (I - J_mm)^-1 for TVD-C, J_mm
the moving robots' block of dc/dp), and their rows are 0. Without still robots (the
default) every law is as above, to the bit.

A robot with an empty cell (outside S and dominated, or a coincident duplicate) gets
pdot = kappa (c_S - p) + dc_S/dt, c_S the centroid of the whole of S, under every law: it
heads into S and owns a cell as soon as it is in (or a duplicate is apart). Aiming at the
nearest point of S instead, as ``mass_centroid`` reports for such a cell, lets a robot left
behind by a moving domain ride just outside its edge, and several at one corner merge into
one point; that happened in the ``circle`` scenario.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from itertools import accumulate, chain

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from covswarm.tvd.arrays import still_mask
from covswarm.tvd.coverage import (
    PRUNED_CELLS,
    CellBatch,
    CoverageDomain,
    DensityModel,
    JacobianTerms,
    apply_jacobian,
    as_complex,
    as_vectors,
    build_cells,
    cell_jacobian_blocks,
    cell_rates,
    check_density,
    concatenate_cells,
    jacobian_terms,
    jacobian_times,
    local_cells,
    make_domain,
    neighbor_candidates,
    tessellate,
)
from covswarm.tvd.density import Density

MAX_AMPLIFICATION = 10.0
# Tikhonov damping of TVD-C's feedforward solve (dimensionless, like I - J): singular
# directions of I - J below it are attenuated toward the prior x0, so
# |x - x0| <= |dc/dt - (I - J) x0| / (2 DAMPING). With the affine prior circle/100 gives
# the same e_a at 0.05 and 0.01 (docs/tracking.md, section 4).
DAMPING = 0.05
LAWS = ("c", "d1", "da")
PRIORS = ("affine", "zero")


@dataclass(frozen=True)
class LocalStep:
    """One robot's control step from its local view.

    velocity: (2,) the law's velocity; neighbors: ids of its Voronoi neighbours
    (positive-length shared edge); centroid: (2,) c_i; mass: m_i (0 for an empty cell);
    guarded: the amplification guard rescaled this robot's row (module notes); area: the
    cell's area in m^2 (its mass when the density is uniform).
    """

    velocity: np.ndarray
    neighbors: frozenset
    centroid: np.ndarray
    mass: float
    guarded: bool = False
    area: float = 0.0


@dataclass(frozen=True)
class TeamStep:
    """One full-team step of a law.

    velocity: (n, 2) m/s; guarded: (n,) rows rescaled by the amplification guard;
    fallback: the team-wide fallback was taken (exact TVD-C: guarded TVD-D1 instead; damped
    TVD-C: the solve failed, so only the prior is fed forward); error: e_a = ||p - c(p, t)||
    (m) at the positions stepped from, of the cells the step used (as
    covswarm.tvd.coverage.aggregate_error; NaN when not computed), over the moving robots
    when some stand still.
    """

    velocity: np.ndarray
    guarded: np.ndarray
    fallback: bool = False
    error: float = math.nan


@dataclass(frozen=True)
class AffineField:
    """v(q) = matrix (q - origin) + velocity: an affine velocity field of the plane.

    matrix: (2, 2) 1/s (A of docs/tracking.md); origin: (2,) m; velocity: (2,) m/s, the
    field at ``origin`` (b = velocity - matrix origin).
    """

    matrix: np.ndarray
    origin: np.ndarray
    velocity: np.ndarray

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """v at ``points`` (..., 2) -> (..., 2) m/s."""
        return (points - self.origin) @ self.matrix.T + self.velocity


def affine_field(polygon: np.ndarray, polygon_velocity: np.ndarray) -> AffineField:
    """The affine field v(q) = A q + b fitted by least squares to S's vertex velocities.

    polygon, polygon_velocity: (k, 2), k >= 3 (validated: not collinear, so the fit is
    unique). Exact for translation, rotation, uniform scaling and any affine motion of S;
    for other vertex motions it is the best affine guess, and TVD-DA's residual term
    carries the rest.
    """
    return _fit(make_domain(polygon, polygon_velocity))


def _fit(domain: CoverageDomain) -> AffineField:
    """Least squares about the vertices' mean q0: the centred design [q - q0, 1] has its
    last column orthogonal to the others, so b0 = mean velocity and A^T = (Q^T Q)^-1 Q^T V
    (2 x 2, written out: this runs in every robot's step)."""
    weight = 1.0 / len(domain.vertices)
    origin = domain.vertices.sum(axis=0) * weight
    centred = domain.vertices - origin
    (sxx, sxy), (_, syy) = centred.T @ centred
    moments = centred.T @ domain.velocities  # (2, 2): rows x, y; columns vx, vy
    det = sxx * syy - sxy * sxy  # > 0: a valid polygon's vertices are not collinear
    inverse = np.array([[syy, -sxy], [-sxy, sxx]]) / det
    return AffineField(
        matrix=(inverse @ moments).T, origin=origin, velocity=domain.velocities.sum(axis=0) * weight
    )


# m/s: where S's affine field is slower than this, it gives no direction to face
# (:func:`field_directions`: near the centre of a turning S, or anywhere in a still one).
MIN_FIELD_SPEED = 0.005


def field_directions(
    field: AffineField, points: np.ndarray, min_speed: float = MIN_FIELD_SPEED
) -> np.ndarray:
    """The direction, rad, of ``field`` at ``points`` (P, 2) m: (P,), NaN where it is slower
    than ``min_speed`` m/s (or not finite). What a robot that drives forwards faces to be
    carried along with S (covswarm.agent.brain: robots turn to face S's start motion while
    the mission waits)."""
    velocity = field(np.asarray(points, dtype=float))
    directions = np.arctan2(velocity[:, 1], velocity[:, 0])
    return np.where(np.hypot(velocity[:, 0], velocity[:, 1]) >= min_speed, directions, np.nan)


def motion_field(
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    points: np.ndarray,
    density: DensityModel | None = None,
) -> np.ndarray:
    """TVD-DA's guess of the feedforward at ``points`` (P, 2): (P, 2) m/s.

    Uniform density: S's affine field v_S (``affine_field``). With Gaussian bumps
    (covswarm.tvd.density.Density), each bump b's share of phi pulls the guess toward the
    bump's own motion, its mean's drift plus S's stretch and turn about the mean:

        v(q) = (floor v_S(q) + sum_b |w_b| g_b(q) (mu_dot_b + A (q - mu_b)))
               / (floor + sum_b |w_b| g_b(q)),

    so a bump that rides with S gives v_S exactly. Any guess is corrected by TVD-DA's
    residual term; on ``formation`` this one gives 0.0118 m, S's field alone 0.0121 m
    (docs/tracking.md).
    """
    return as_vectors(_motion_field(make_domain(polygon, polygon_velocity), points, density))


def _motion_field(
    domain: CoverageDomain, points: np.ndarray, density: DensityModel | None
) -> np.ndarray:
    """``motion_field`` of a validated domain, (P,) complex."""
    field = _fit(domain)
    guess = field(points)
    if isinstance(density, Density) and len(density.weights):
        offset = points[:, None, :] - density.means  # (P, B, 2)
        spread = np.einsum("pbi,bij,pbj->pb", offset, density.precisions, offset)
        share = np.abs(density.weights) * np.exp(-0.5 * spread)  # (P, B)
        bump = density.mean_rates + offset @ field.matrix.T  # (P, B, 2)
        total = density.floor + share.sum(axis=1)
        guess = (density.floor * guess + np.einsum("pb,pbi->pi", share, bump)) / total[:, None]
    return as_complex(np.ascontiguousarray(guess))


def _check_kappa(kappa: float) -> None:
    real = (int, float, np.floating, np.integer)
    number = not isinstance(kappa, bool) and isinstance(kappa, real)
    if not (number and math.isfinite(kappa) and kappa > 0.0):
        raise ValueError(f"kappa must be a positive finite gain, got {kappa!r}")


def _check_local_law(law: str, max_amplification: float) -> None:
    if law not in ("d1", "da"):
        raise ValueError(
            f"a local step's law must be 'd1' or 'da' (TVD-C is centralised), got {law!r}"
        )
    _check_law(law, max_amplification)


def _check_law(law: str, max_amplification: float = MAX_AMPLIFICATION) -> None:
    """ValueError for an unknown law or a guard that is not a finite positive factor (a
    negative one reversed every robot's velocity, NaN turned the guard off)."""
    if law not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, got {law!r}")
    if not (math.isfinite(max_amplification) and max_amplification > 0.0):
        raise ValueError(
            f"max_amplification must be a finite number > 0, got {max_amplification!r}"
        )


def _targets(
    batch: CellBatch,
    points: np.ndarray,
    domain: CoverageDomain,
    feedforward: bool,
    density: DensityModel | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(K,) complex centroids c_i and (K,) dc_i/dt (None without feedforward).

    A robot with an empty cell aims at the centroid of the whole of S and takes its rate
    (module notes).
    """
    target = batch.centroid
    rate = cell_rates(batch, points, domain, density) if feedforward else None
    empty = batch.empty
    if empty.any():
        whole_centroid, whole_rate = _whole_domain(domain, density)
        target = np.where(empty, whole_centroid, target)
        if rate is not None:
            rate = np.where(empty, whole_rate, rate)
    return target, rate


def _whole_domain(domain: CoverageDomain, density: DensityModel | None) -> tuple[complex, complex]:
    """Centroid of all of S and its rate: the cell of a robot alone in S."""
    alone = domain.vertices.mean(axis=0, keepdims=True)
    cell = _weigh(build_cells(alone, np.array([0]), np.full((1, 1), -1), domain), density)
    return cell.centroid[0], cell_rates(cell, alone, domain, density)[0]


Blocks = tuple[np.ndarray, np.ndarray]
# What a product with J of a batch's rows reads besides the vectors: a density's blocks,
# the terms of uniform density's closed form.
Prepared = Blocks | JacobianTerms


def _jacobian_product(
    batch: CellBatch,
    points: np.ndarray,
    own: np.ndarray,
    others: np.ndarray,
    density: DensityModel | None,
    prepared: Prepared | None,
) -> np.ndarray:
    """(J w)_i = sum_j dc_i/dp_j w_j for the batch's rows, (K,) complex.

    own: (K,) w_i; others: (K, L) w_j of the robot each line comes from (read on shared
    edges only). ``prepared`` (:func:`_prepare`, of these rows; computed here when None):
    uniform density's JacobianTerms, for its closed form; else the density's blocks (off,
    diagonal).
    """
    if density is None:
        others = np.where(batch.shared, others, 0.0)
        if prepared is None:
            return jacobian_times(batch, points, own, others)
        return apply_jacobian(prepared, own, others)
    if prepared is None:
        return density.jacobian_times(batch, points, own, others)
    off, diagonal = prepared
    return as_complex(
        np.einsum("kab,kb->ka", diagonal, as_vectors(own))
        + np.einsum("klab,klb->ka", off, as_vectors(np.where(batch.shared, others, 0.0)))
    )


def _prepare(batch: CellBatch, points: np.ndarray, density: DensityModel | None) -> Prepared:
    """What the products with J of ``batch`` read (TVD-DA takes two): the density's blocks,
    or uniform density's JacobianTerms."""
    if density is None:
        return jacobian_terms(batch, points)
    return density.jacobian_blocks(batch, points)


def _head(prepared: Prepared, count: int) -> Prepared:
    """``_prepare``'s arrays of the first ``count`` rows."""
    if isinstance(prepared, JacobianTerms):
        return JacobianTerms(*(terms[:count] for terms in prepared))
    return prepared[0][:count], prepared[1][:count]


def _neumann_rows(
    batch: CellBatch,
    points: np.ndarray,
    own: np.ndarray,
    neighbor_values: np.ndarray,
    max_amplification: float,
    density: DensityModel | None,
    prepared: Prepared | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of (I + J) w for the batch's robots, with the amplification guard.

    own: (K,) w_i; neighbor_values: (K, L) w_j of the robot each line comes from (ignored
    where the line is not a shared edge); vectors as complex numbers. Returns the rows (K,)
    and which were rescaled (K,) bool. Empty cells keep w_i.
    """
    others = np.where(batch.shared, neighbor_values, 0.0)
    velocity = own + _jacobian_product(batch, points, own, others, density, prepared)
    scale = np.maximum(np.abs(own), np.abs(others).max(axis=1, initial=0.0))
    speed = np.abs(velocity)
    limit = max_amplification * scale
    guarded = (speed > limit) & ~batch.empty
    factor = np.where(guarded, limit / np.maximum(speed, 1e-300), 1.0)
    return np.where(batch.empty, own, velocity * factor), guarded


def _team_cells(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    density: DensityModel | None,
) -> tuple[np.ndarray, CoverageDomain, CellBatch]:
    _check_kappa(kappa)
    return tessellate(positions, polygon, polygon_velocity, density)


def team_step(
    law: str,
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
    damping: float = DAMPING,
    prior: str = "affine",
    still: np.ndarray | None = None,
) -> TeamStep:
    """One full-team step of ``law`` ("c", "d1" or "da"), with its guard counts.

    positions: (n, 2) m; polygon, polygon_velocity: (k, 2) m and m/s; kappa 1/s.
    ``damping`` and ``prior`` apply to "c" only (damping 0: the exact TVD-C with its
    fallback). still: (n,) bool, the robots that stand still (module notes; None: none):
    generators with velocity 0, the law taken over the others.
    """
    _check_law(law, max_amplification)
    if prior not in PRIORS:
        raise ValueError(f"prior must be one of {PRIORS}, got {prior!r}")
    if not (math.isfinite(damping) and damping >= 0.0):
        raise ValueError(f"damping must be a finite number >= 0, got {damping!r}")
    points, domain, batch = _team_cells(positions, polygon, polygon_velocity, kappa, density)
    fixed = still_mask(still, len(points))
    target, rate = _targets(batch, points, domain, feedforward, density)
    feedback = kappa * (target - as_complex(points))
    if fixed is not None:  # read as 0 by the neighbours' rows: pdot = 0 there
        feedback = np.where(fixed, 0.0, feedback)
        rate = None if rate is None else np.where(fixed, 0.0, rate)
    if law == "d1":
        references = feedback if rate is None else feedback + rate
        step = _team_d1(batch, points, references, max_amplification, density)
    elif law == "da":
        step = _team_da(batch, points, domain, feedback, rate, max_amplification, density, fixed)
    elif damping == 0.0:
        step = _team_c_exact(batch, points, feedback, rate, max_amplification, density, fixed)
    else:
        field = as_complex(_fit(domain)(points)) if prior == "affine" else None
        if field is not None and fixed is not None:
            field = np.where(fixed, 0.0, field)
        step = _team_c_damped(
            batch, points, feedback, rate, max_amplification, density, damping, field, fixed
        )
    # e_a of these cells: a simulator's log then needs no tessellation of its own.
    offsets = points - as_vectors(batch.centroid)
    if fixed is not None:
        offsets = offsets[~fixed]
        step = replace(
            step,
            velocity=np.where(fixed[:, None], 0.0, step.velocity),
            guarded=step.guarded & ~fixed,
        )
    return replace(step, error=float(np.linalg.norm(offsets)))


def _team_d1(
    batch: CellBatch,
    points: np.ndarray,
    references: np.ndarray,
    max_amplification: float,
    density: DensityModel | None,
) -> TeamStep:
    """TVD-D1 of the whole team from its cells and its r."""
    rows, guarded = _neumann_rows(
        batch,
        points,
        references,
        references[np.maximum(batch.labels, 0)],
        max_amplification,
        density,
    )
    return TeamStep(as_vectors(rows), guarded)


def _team_da(
    batch: CellBatch,
    points: np.ndarray,
    domain: CoverageDomain,
    feedback: np.ndarray,
    rate: np.ndarray | None,
    max_amplification: float,
    density: DensityModel | None,
    fixed: np.ndarray | None = None,
) -> TeamStep:
    """TVD-DA of the whole team: v(p) + (I + J) (kappa (c - p) + rho). ``fixed``: (n,) bool,
    the robots standing still (their v read as 0 by their neighbours' rows), or None."""
    if rate is None:
        return _team_d1(batch, points, feedback, max_amplification, density)
    prepared = _prepare(batch, points, density)
    field = _motion_field(domain, points, density)
    labels = np.maximum(batch.labels, 0)
    theirs = field[labels] if fixed is None else np.where(fixed, 0.0, field)[labels]
    references = feedback + _residual(batch, points, rate, field, theirs, density, prepared)
    if fixed is not None:
        references = np.where(fixed, 0.0, references)
    rows, guarded = _neumann_rows(
        batch, points, references, references[labels], max_amplification, density, prepared
    )
    return TeamStep(as_vectors(field + rows), guarded)


def _residual(
    batch: CellBatch,
    points: np.ndarray,
    rate: np.ndarray,
    own_field: np.ndarray,
    neighbor_field: np.ndarray,
    density: DensityModel | None,
    prepared: Prepared | None,
) -> np.ndarray:
    """rho_i = dc_i/dt - v(p_i) + (J v)_i for the batch's rows, (K,) complex: what the affine
    guess v misses of TVD-C's feedforward (zero at a CVT of a similarity motion).

    own_field: (K,) v(p_i); neighbor_field: (K, L) v(p_j) of the robot each line comes from.
    An empty cell's row of J is zero, so its rho is dc_S/dt - v(p_i).
    """
    product = _jacobian_product(batch, points, own_field, neighbor_field, density, prepared)
    return rate - own_field + product


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


def _control_matrix(
    batch: CellBatch, points: np.ndarray, density: DensityModel | None
) -> scipy.sparse.csc_array:
    """I - dc/dp, sparse (2n, 2n)."""
    jacobian = _control_jacobian(batch, points, density)
    return scipy.sparse.eye_array(jacobian.shape[0], format="csc") - jacobian.tocsc()


def _moving_block(
    matrix: scipy.sparse.csc_array, fixed: np.ndarray | None
) -> tuple[scipy.sparse.csc_array, np.ndarray | None]:
    """(``matrix``'s rows and columns of the moving robots (the coordinates of robots not
    ``fixed``), those coordinates (2m,)); the whole matrix and None when none is fixed."""
    if fixed is None:
        return matrix, None
    coordinates = (2 * np.flatnonzero(~fixed)[:, None] + np.arange(2)).ravel()
    return matrix[coordinates][:, coordinates].tocsc(), coordinates


def _on_moving(values: np.ndarray, coordinates: np.ndarray | None) -> np.ndarray:
    """(2n,) ``values`` at the moving robots' coordinates (all when None)."""
    return values if coordinates is None else values[coordinates]


def _from_moving(solution: np.ndarray, coordinates: np.ndarray | None, n: int) -> np.ndarray:
    """(n, 2) from a solution over the moving robots' coordinates, 0 for the still ones."""
    if coordinates is None:
        return solution.reshape(-1, 2)
    out = np.zeros(2 * n)
    out[coordinates] = solution
    return out.reshape(-1, 2)


def _solve(system: scipy.sparse.csc_array, rhs: np.ndarray) -> np.ndarray | None:
    """Sparse LU solve, None when it fails or is not finite."""
    try:
        solution = scipy.sparse.linalg.splu(system).solve(rhs)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return None
    return solution if np.all(np.isfinite(solution)) else None


def _team_c_exact(
    batch: CellBatch,
    points: np.ndarray,
    feedback: np.ndarray,
    rate: np.ndarray | None,
    max_amplification: float,
    density: DensityModel | None,
    fixed: np.ndarray | None = None,
) -> TeamStep:
    """The paper's TVD-C, (I - J)^-1 r, or guarded TVD-D1 when that is unusable; over the
    moving robots (``fixed``: (n,) bool, those standing still, or None)."""
    references = feedback if rate is None else feedback + rate
    matrix, coordinates = _moving_block(_control_matrix(batch, points, density), fixed)
    solution = _solve(matrix, _on_moving(as_vectors(references).ravel(), coordinates))
    if solution is not None:
        velocities = _from_moving(solution, coordinates, len(points))
        bound = max_amplification * float(np.max(np.abs(references)))
        if np.all(np.linalg.norm(velocities, axis=1) <= bound):
            return TeamStep(velocities, np.zeros(len(points), dtype=bool))
    d1 = _team_d1(batch, points, references, max_amplification, density)
    return TeamStep(d1.velocity, d1.guarded, fallback=True)


def _team_c_damped(
    batch: CellBatch,
    points: np.ndarray,
    feedback: np.ndarray,
    rate: np.ndarray | None,
    max_amplification: float,
    density: DensityModel | None,
    damping: float,
    prior: np.ndarray | None,
    fixed: np.ndarray | None = None,
) -> TeamStep:
    """kappa (c - p) + x, x the solution of (I - J) x = dc/dt damped toward ``prior`` ((n,)
    complex, None for zero); a correction x - prior faster than ``max_amplification`` times
    max |dc/dt| is rescaled to that speed. Over the moving robots (``fixed``: (n,) bool,
    those standing still, or None)."""
    n = len(points)
    if rate is None:
        return TeamStep(as_vectors(feedback), np.zeros(n, dtype=bool))
    matrix, coordinates = _moving_block(_control_matrix(batch, points, density), fixed)
    size = matrix.shape[0]
    normal = (matrix.T @ matrix + damping**2 * scipy.sparse.eye_array(size)).tocsc()
    rhs = _on_moving(as_vectors(rate).ravel(), coordinates)
    if prior is not None:
        rhs = rhs - matrix @ _on_moving(as_vectors(prior).ravel(), coordinates)
    solution = _solve(normal, matrix.T @ rhs)
    if solution is None:
        fallback = feedback if prior is None else feedback + prior
        return TeamStep(as_vectors(fallback), np.zeros(n, dtype=bool), fallback=True)
    correction = as_complex(_from_moving(solution, coordinates, n))
    limit = max_amplification * float(np.max(np.abs(rate)))
    speed = np.abs(correction)
    guarded = speed > limit
    correction = np.where(guarded, correction * limit / np.maximum(speed, 1e-300), correction)
    feedforward = correction if prior is None else prior + correction
    return TeamStep(as_vectors(feedback + feedforward), guarded)


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
    return team_step(
        "d1", positions, polygon, polygon_velocity, kappa, feedforward, density, max_amplification
    ).velocity


def tvd_da(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
) -> np.ndarray:
    """TVD-DA velocities v(p) + (I + dc/dp)(kappa (c - p) + rho) for the whole team.

    v: the affine field fitted to S's vertex velocities (``affine_field``); rho = dc/dt -
    (I - dc/dp) v(p), the residual of the affine guess. positions: (n, 2) m; polygon,
    polygon_velocity: (k, 2). Returns (n, 2) m/s.
    """
    return team_step(
        "da", positions, polygon, polygon_velocity, kappa, feedforward, density, max_amplification
    ).velocity


def tvd_c(
    positions: np.ndarray,
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
    damping: float = DAMPING,
    prior: str = "affine",
) -> np.ndarray:
    """TVD-C velocities for the whole team (module notes).

    Default: kappa (c - p) + x, x = argmin |(I - dc/dp) x - dc/dt|^2 + damping^2 |x - x0|^2,
    x0 the affine field v(p) (``prior="affine"``) or 0 (``prior="zero"``).
    ``damping=0``: the paper's exact (I - dc/dp)^-1 (kappa (c - p) + dc/dt), falling back
    to the guarded TVD-D1 velocities when I - dc/dp is numerically singular or the solution
    amplifies a robot's speed beyond ``max_amplification`` times max |r|.
    positions: (n, 2); polygon, polygon_velocity: (k, 2). Returns (n, 2).
    """
    return team_step(
        "c",
        positions,
        polygon,
        polygon_velocity,
        kappa,
        feedforward,
        density,
        max_amplification,
        damping,
        prior,
    ).velocity


def local_step(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
    law: str = "d1",
    still: frozenset = frozenset(),
) -> LocalStep:
    """One robot's step of ``law`` ("d1" or "da") from the robots it knows: itself, its
    neighbours, theirs.

    positions: {id: (2,)} including ``me``; still: the ids among them of robots that stand still
    (generators with velocity 0, module notes), never ``me``. Builds only the cells of ``me``
    and of its neighbours (a local partial Voronoi diagram); equals row ``me`` of ``tvd_d1``
    (``tvd_da``) on the full team whenever ``positions`` contains the true two-hop
    neighbourhood. A robot whose cell is empty (outside S, every point of S closer to someone
    else) has no neighbours inside S; it is exact when ``positions`` holds the robots whose
    Voronoi regions in the plane border its own, and a robot that sees nobody takes all of S as
    its cell and heads for its centroid, which also brings it into S. ``local_steps`` with one
    view (the same code).
    """
    _check_local_law(law, max_amplification)
    check_density(density)
    _check_kappa(kappa)
    ids = _ordered_known(me, positions)
    _check_still(me, still)
    points = _view_points(positions, ids)  # checked there, finite, ``me`` among them
    domain = make_domain(polygon, polygon_velocity)
    fixed = _fixed([ids], [still]) if still else None
    known = _Known([ids], points, [0], [ids.index(me)], [float(kappa)], fixed)
    return _batch_steps(known, domain, density, feedforward, max_amplification, law)[0]


@dataclass(frozen=True)
class LocalView:
    """One robot's inputs to ``local_step``.

    me: its id; positions: {id: (2,) m} including ``me`` (its two-hop neighbourhood);
    polygon, polygon_velocity: (M, 2) m and m/s, S as this robot holds it; kappa: 1/s;
    density: the density snapshot it holds (None: uniform); still: the ids of ``positions``
    that stand still (generators with velocity 0, module notes), never ``me``.
    """

    me: Hashable
    positions: Mapping[Hashable, np.ndarray]
    polygon: np.ndarray
    polygon_velocity: np.ndarray
    kappa: float
    density: DensityModel | None = None
    still: frozenset = frozenset()


def local_steps(
    views: Sequence[LocalView],
    feedforward: bool = True,
    max_amplification: float = MAX_AMPLIFICATION,
    law: str = "d1",
) -> list[LocalStep]:
    """``local_step`` of every view, in order: the brains of one process due in one tick.

    Equal to ``[local_step(v.me, v.positions, v.polygon, v.polygon_velocity, v.kappa,
    feedforward, v.density, max_amplification, law) for v in views]`` (to rounding). Views
    that hold the same S (equal polygon and vertex velocities) and the same density object
    are stepped together: their local point sets stacked as disjoint blocks of one array,
    every cell of every view built in one vectorised pass, each clipped only by its own
    view's robots, so a tick costs ~50 numpy calls per group instead of per robot. A view
    with invalid input raises ValueError (TypeError for a density that is not a
    DensityModel) naming its index and ``me``; the caller can then step the views one by one.
    """
    _check_local_law(law, max_amplification)
    orders: list[list] = []  # each view's ids in point order
    groups: dict[tuple, list[int]] = {}
    keys: dict[tuple, tuple] = {}  # S and density by identity -> by value
    for index, view in enumerate(views):
        try:
            check_density(view.density)
            _check_kappa(view.kappa)
            orders.append(_ordered_known(view.me, view.positions))
            _check_still(view.me, view.still)
            same = (id(view.polygon), id(view.polygon_velocity), id(view.density))
            key = keys.get(same)
            if key is None:
                polygon = np.asarray(view.polygon, dtype=np.float64)
                velocity = np.asarray(view.polygon_velocity, dtype=np.float64)
                shape = (polygon.shape, velocity.shape)
                key = keys[same] = (shape, polygon.tobytes(), velocity.tobytes(), id(view.density))
        except (ValueError, TypeError) as error:
            raise _named(error, index, view) from error
        groups.setdefault(key, []).append(index)
    if not views:
        return []
    points = _batch_points(views, orders)
    fixed = None
    if any(view.still for view in views):
        fixed = _fixed(orders, [view.still for view in views])
    sizes = [len(ids) for ids in orders]
    starts = list(accumulate(sizes, initial=0))
    steps: list = [None] * len(views)
    for key, members in groups.items():
        first = views[members[0]]
        try:
            domain = _domain_of(*key[:3])
        except ValueError as error:
            raise _named(error, members[0], first) from error
        if len(members) == len(views):  # one S for all (a pack's brains): no copy
            known = _Known(
                orders,
                points,
                starts[:-1],
                [start + orders[i].index(views[i].me) for i, start in enumerate(starts[:-1])],
                [float(view.kappa) for view in views],
                fixed,
            )
        else:
            known = _subset(views, orders, points, starts, members, fixed)
        group = _batch_steps(known, domain, first.density, feedforward, max_amplification, law)
        for index, step in zip(members, group, strict=True):
            steps[index] = step
    return steps


@lru_cache(maxsize=4)
def _domain_of(shapes: tuple, polygon: bytes, velocity: bytes) -> CoverageDomain:
    """``make_domain`` of S as ``local_steps`` keys it (shapes, float64 bytes): the brains of
    a pack hold one S, so a tick validates and derives it once, not once per batch."""
    return make_domain(
        np.frombuffer(polygon).reshape(shapes[0]), np.frombuffer(velocity).reshape(shapes[1])
    )


def _named(error: Exception, index: int, view: LocalView) -> Exception:
    """``error`` (a ValueError or TypeError) again, with the view's index and ``me`` in front."""
    return type(error)(f"view {index} (me={view.me!r}): {error}")


@dataclass(frozen=True)
class _Known:
    """Validated views of one S and density, stacked: ids: each view's ids (V lists) in
    point order; points: (N, 2) m, the views' blocks in turn; starts: (V,) each block's
    first row; mes: (V,) each view's own robot's row; kappa: (V,) 1/s; fixed: (N,) bool,
    the points that stand still, or None for none."""

    ids: list[list]
    points: np.ndarray
    starts: list[int]
    mes: list[int]
    kappa: list[float]
    fixed: np.ndarray | None = None


def _check_still(me: Hashable, still: frozenset) -> None:
    """ValueError when a view's own robot is among its still ones."""
    if me in still:
        raise ValueError(f"the robot itself ({me!r}) cannot stand still in its own view")


def _fixed(orders: list[list], stills: Sequence[frozenset]) -> np.ndarray:
    """(N,) bool over the stacked points of views with these ids (in point order): the
    robots each view holds still."""
    return np.array(
        [key in still for ids, still in zip(orders, stills, strict=True) for key in ids],
        dtype=bool,
    )


def _ordered_known(me: Hashable, positions: Mapping[Hashable, np.ndarray]) -> list:
    """A view's ids in point order (``_ordered_ids``); ValueError when ``me`` is missing."""
    if not isinstance(positions, Mapping):
        raise ValueError(
            f"positions must be a mapping {{id: (x, y)}}, not a {type(positions).__name__}"
        )
    if me not in positions:
        raise ValueError(f"positions must include the robot itself ({me!r})")
    return _ordered_ids(positions)


def _view_points(positions: Mapping[Hashable, np.ndarray], ids: list) -> np.ndarray:
    """A view's positions (n, 2) m in the order of ``ids``; ValueError naming the robots
    (by id) whose positions are not finite (x, y) pairs."""
    try:
        points = np.array([positions[key] for key in ids], dtype=np.float64)
        paired = points.shape == (len(ids), 2)
    except (ValueError, TypeError):
        paired = False
    if not paired:
        raise ValueError(
            f"positions must be (x, y) pairs, not those of robots {_unpaired(positions, ids)}"
        )
    if not np.isfinite(points).all():
        bad = [key for key, ok in zip(ids, np.isfinite(points).all(axis=1), strict=True) if not ok]
        raise ValueError(f"positions contain NaN or inf (robots {bad})")
    return points


def _unpaired(positions: Mapping[Hashable, np.ndarray], ids: list) -> list:
    """The ids among ``ids`` whose positions are not two real numbers."""
    bad = []
    for key in ids:
        try:
            pair = np.asarray(positions[key], dtype=np.float64)
        except (ValueError, TypeError):
            pair = None
        if pair is None or pair.shape != (2,):
            bad.append(key)
    return bad


def _batch_points(views: Sequence[LocalView], orders: list[list]) -> np.ndarray:
    """Every view's positions as blocks of one array (N, 2) m, converted in one call; a
    view whose positions are not 2-vectors or not finite raises ValueError naming it."""
    count = sum(len(ids) for ids in orders)
    try:
        points = np.array(
            [view.positions[key] for view, ids in zip(views, orders, strict=True) for key in ids],
            dtype=np.float64,
        )
        stacked = points.shape == (count, 2)
    except (ValueError, TypeError):
        stacked = False
    if not stacked:  # one by one, so that the view at fault is named
        blocks = []
        for index, (view, ids) in enumerate(zip(views, orders, strict=True)):
            try:
                blocks.append(_view_points(view.positions, ids))
            except (ValueError, TypeError) as error:
                raise _named(error, index, view) from error
        points = np.concatenate(blocks)
    if not np.isfinite(points).all():
        for index, (view, ids) in enumerate(zip(views, orders, strict=True)):
            try:
                _view_points(view.positions, ids)
            except ValueError as error:
                raise _named(error, index, view) from error
    return points


def _subset(
    views: Sequence[LocalView],
    orders: list[list],
    points: np.ndarray,
    starts: list[int],
    members: list[int],
    fixed: np.ndarray | None,
) -> _Known:
    """The views ``members`` of a batch (``local_steps``' points, block starts and still
    points) as their own stack."""
    rows = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in members])
    ids = [orders[i] for i in members]
    offsets = list(accumulate((len(block) for block in ids), initial=0))[:-1]
    return _Known(
        ids,
        points[rows],
        offsets,
        [start + orders[i].index(views[i].me) for i, start in zip(members, offsets, strict=True)],
        [float(views[i].kappa) for i in members],
        None if fixed is None else fixed[rows],
    )


def _batch_steps(
    views: _Known,
    domain: CoverageDomain,
    density: DensityModel | None,
    feedforward: bool,
    max_amplification: float,
    law: str,
) -> list[LocalStep]:
    """The local steps of validated views of one S and density, as one batch.

    Each view's points are a block of the points array, and each view's cells take only
    its block as candidates, so they are the cells of its own local diagram. The batch's
    rows: every view's own cell first (so that they are its leading rows, which a density
    reuses its integrals for), then its neighbours' cells (``_view_cells``), which (I + J)
    needs the references of: r (TVD-D1), or kappa (c - p) + rho (TVD-DA; a neighbour's
    row of J needs its neighbours' v, in the two-hop view). A still robot's r, rho and v
    are read as 0 (module notes).
    """
    count = len(views.ids)
    points, candidates, mes = _stack(views)
    cells, of_view = _view_cells(points, mes, candidates, domain)  # mass: area, until weighed
    owners = cells.owners
    kappa = views.kappa[0]
    if count > 1:  # each cell's own view's gain
        kappa = np.array(views.kappa)[np.concatenate((np.arange(count), of_view))]
    batch = _weigh(cells, density)
    target, rate = _targets(batch, points, domain, feedforward, density)
    feedback = kappa * (target - as_complex(points)[owners])
    mine = _rows(batch, slice(0, count))
    field = prepared = None
    references = feedback
    if rate is not None and law == "d1":
        references = feedback + rate
    elif rate is not None:
        field = _motion_field(domain, points, density)
        prepared = _prepare(batch, points, density)
        theirs = field if views.fixed is None else np.where(views.fixed, 0.0, field)
        references = feedback + _residual(
            batch,
            points,
            rate,
            field[owners],
            theirs[np.maximum(batch.labels, 0)],
            density,
            prepared,
        )
    by_robot = np.zeros(len(points), dtype=np.complex128)
    by_robot[owners] = references
    if views.fixed is not None:
        by_robot[views.fixed] = 0.0
    rows, guarded = _neumann_rows(
        mine,
        points,
        references[:count],
        by_robot[np.maximum(mine.labels, 0)],
        max_amplification,
        density,
        None if prepared is None else _head(prepared, count),
    )
    velocity = as_vectors(rows if field is None else field[mes] + rows)
    centroid = as_vectors(mine.centroid)
    # Python lists: a few numpy calls for the whole batch, not per view. The neighbours'
    # labels (rows of the stacked points) row by row, each view's in turn, as robot ids.
    every = list(chain.from_iterable(views.ids))
    names = list(map(every.__getitem__, mine.labels[mine.shared].tolist()))
    ends = list(accumulate(mine.shared.sum(axis=1).tolist()))
    neighbors = [frozenset(names[a:b]) for a, b in zip([0, *ends[:-1]], ends, strict=True)]
    masses, guards, areas = mine.mass.tolist(), guarded.tolist(), cells.mass[:count].tolist()
    # LocalStep(velocity, neighbors, centroid, mass, guarded, area), the arrays' rows.
    return list(map(LocalStep, velocity, neighbors, centroid, masses, guards, areas))


def _view_cells(
    points: np.ndarray, mes: np.ndarray, candidates: np.ndarray, domain: CoverageDomain
) -> tuple[CellBatch, np.ndarray]:
    """The cells of the views' own robots ``mes`` (V,), then those of their neighbours, each
    among its own view's ``candidates`` (V, D) (or (1, D) for one view) only; and the view
    (R,) of each neighbour's row. Mass: area.

    The neighbours are found in one of two ways, the cheaper at that many views: below
    PRUNED_CELLS views, by the half-plane intersection alone (``neighbor_candidates``, which
    may add robots that only touch a cell; their rows are never read) and every cell built
    in one pass; from PRUNED_CELLS on, as the robots our cells share an edge with, once our
    cells are built (with pruned candidates: a few lines each instead of the whole view).
    """
    count = len(mes)
    if count < PRUNED_CELLS:
        of_view, column = np.nonzero(neighbor_candidates(points, mes, candidates, domain))
        owners = np.concatenate((mes, candidates[of_view, column]))
        if count > 1:  # each cell among its own view's robots
            candidates = candidates[np.concatenate((np.arange(count), of_view))]
        return local_cells(points, owners, candidates, domain), of_view
    mine = local_cells(points, mes, candidates, domain)
    of_view, column = np.nonzero(mine.shared)
    if not len(of_view):
        return mine, of_view
    theirs = local_cells(points, mine.labels[of_view, column], candidates[of_view], domain)
    return concatenate_cells([mine, theirs]), of_view


def _stack(views: _Known) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The views' points as disjoint blocks of one array: (points (N, 2), candidates (V, D)
    each view's point indices padded with -1, mes (V,) each view's own robot)."""
    if len(views.ids) == 1:
        return views.points, np.arange(len(views.points))[None], np.array(views.mes)
    sizes = np.array([len(ids) for ids in views.ids])
    starts = np.array(views.starts)
    candidates = np.arange(sizes.max()) + starts[:, None]
    candidates[candidates >= (starts + sizes)[:, None]] = -1
    return views.points, candidates, np.array(views.mes)


def local_velocity(
    me: Hashable,
    positions: Mapping[Hashable, np.ndarray],
    polygon: np.ndarray,
    polygon_velocity: np.ndarray,
    kappa: float,
    feedforward: bool = True,
    density: DensityModel | None = None,
    max_amplification: float = MAX_AMPLIFICATION,
    law: str = "d1",
) -> np.ndarray:
    """Robot ``me``'s velocity (2,) from its two-hop neighbourhood; see ``local_step``."""
    return local_step(
        me,
        positions,
        polygon,
        polygon_velocity,
        kappa,
        feedforward,
        density,
        max_amplification,
        law,
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
