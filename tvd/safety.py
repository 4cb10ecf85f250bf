"""Collision avoidance: decentralised barrier certificates on single-integrator velocities.

Robots are disks. A pair (i, j) is safe while h_ij = |p_i - p_j|^2 - D_s^2 >= 0, D_s the safe
distance between the points that the controller steers. Ames et al.'s control barrier
function condition for single integrators, dh/dt >= -gamma h, reads

    -2 (p_i - p_j) . (u_i - u_j) <= gamma h_ij,

and in the decentralised form the Robotarium uses (Wang, Ames & Egerstedt, "Safety barrier
certificates for collisions-free multirobot systems", IEEE T-RO 2017) each robot takes half
of it, with its neighbour's velocity left out:

    a_ij . u_i <= b_ij,   a_ij = -2 (p_i - p_j),   b_ij = gamma h_ij / 2.

If both robots satisfy their halves, the pair satisfies the whole. Each robot then solves a
QP in the plane, min |u - u_hat|^2 subject to one such row per neighbour, here exactly (see
:func:`closest_feasible`), never by an iterative solver.

Linear class-K function (gamma h, not the Robotarium's gamma h^3) on purpose: with velocities
held over a sampling period T (zero-order hold, the agents' control period),
h(t + s) = h + 2 s d.(u_i - u_j) + s^2 |u_i - u_j|^2 >= (1 - gamma s) h, so for gamma T <= 1
a pair that satisfies the condition at the sample never closes below D_s before the next
one: the continuous-time guarantee survives sampling exactly (for single integrators).

Pure numpy, no I/O. Distances in m, velocities in m/s, gamma in 1/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# 1/s: the barrier's decay rate. gamma T <= 1 is what keeps the guarantee at a sampling
# period T (module docstring), so this is safe for control rates of 5 Hz and faster; an agent
# running slower caps it (see barrier_gain).
DEFAULT_GAMMA = 5.0
# m: distance between robot centres kept beyond the body diameter, for what the model does
# not know (pose noise, a neighbour's dead-reckoning error, the arc a unicycle drives
# between two commands).
DEFAULT_MARGIN = 0.02
FEASIBILITY_TOL = 1e-9  # m^2/s: slack allowed on a row when checking a candidate


@dataclass(frozen=True)
class FilterResult:
    """One robot's filtered velocity and what the filter did.

    velocity: (2,) m/s. active: rows tight at the solution (0: the nominal velocity was
    safe). relaxed: the rows could not all hold (robots already closer than the safe
    distance, boxed in), so every row's bound was raised to 0 ("do not close any further"),
    which u = 0 always satisfies.
    """

    velocity: np.ndarray
    active: int
    relaxed: bool


def barrier_gain(gamma: float, period: float) -> float:
    """The decay rate to use at a sampling period of ``period`` s: min(gamma, 1 / period),
    the largest that keeps the sampled guarantee of the module docstring."""
    if period <= 0.0:
        return gamma
    return min(gamma, 1.0 / period)


def body_safe_distance(
    body_diameter: float, projection_distance: float, margin: float = DEFAULT_MARGIN
) -> float:
    """Safe distance D_s between a unicycle's steered point and its neighbours' centres.

    A differential-drive robot steers the point q = p + l (cos th, sin th) ahead of its axle
    centre p (covswarm.tvd.drive, l = ``projection_distance``), and knows its neighbours'
    centres p_j (their AgentStates). Since |p - p_j| >= |q - p_j| - l, keeping
    |q - p_j| >= diameter + l + margin keeps the two bodies ``margin`` apart.
    """
    return body_diameter + projection_distance + margin


def pair_constraints(
    position: np.ndarray, neighbors: np.ndarray, safe_distance: float, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """One robot's half of each pair's barrier condition: rows (A (m, 2), b (m,)), A u <= b.

    position: (2,) m; neighbors: (m, 2) m. a_j = -2 (p - p_j), b_j = gamma (|p - p_j|^2 -
    safe_distance^2) / 2.
    """
    offset = np.asarray(position, dtype=float).reshape(2) - np.asarray(
        neighbors, dtype=float
    ).reshape(-1, 2)
    h = np.einsum("ij,ij->i", offset, offset) - safe_distance**2
    return -2.0 * offset, 0.5 * gamma * h


def closest_feasible(nominal: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """argmin |u - nominal|^2 subject to A u <= b in the plane, exactly; (u, tight rows).

    nominal: (2,); A: (m, 2); b: (m,). The optimum of a strictly convex QP in R^2 is the
    nominal point, the projection onto one row's line, or the intersection of two rows'
    lines (at most two independent rows are active in the plane), so the feasible one of
    these O(m^2) candidates closest to ``nominal`` is the optimum. ValueError if no
    candidate is feasible: the rows have no common point (to FEASIBILITY_TOL). Rows with
    a = 0 (coincident robots) are checked as 0 <= b.
    """
    nominal = np.asarray(nominal, dtype=float).reshape(2)
    A = np.asarray(A, dtype=float).reshape(-1, 2)
    b = np.asarray(b, dtype=float).reshape(-1)
    if A.shape[0] == 0 or np.all(A @ nominal <= b + FEASIBILITY_TOL):
        return nominal, 0
    norm2 = np.einsum("ij,ij->i", A, A)
    usable = norm2 > 1e-24
    if np.any(~usable & (b < -FEASIBILITY_TOL)):
        raise ValueError("a coincident neighbour's row 0 <= b cannot hold")
    Au, bu, nu = A[usable], b[usable], norm2[usable]
    # Projections onto each line a.u = b.
    excess = (Au @ nominal - bu) / nu
    singles = nominal[None, :] - excess[:, None] * Au
    # Intersections of each pair of non-parallel lines (Cramer's rule).
    i, j = np.triu_indices(len(Au), k=1)
    det = Au[i, 0] * Au[j, 1] - Au[i, 1] * Au[j, 0]
    keep = np.abs(det) > 1e-12 * np.sqrt(nu[i] * nu[j])
    i, j, det = i[keep], j[keep], det[keep]
    pairs = np.stack(
        [
            (bu[i] * Au[j, 1] - bu[j] * Au[i, 1]) / det,
            (Au[i, 0] * bu[j] - Au[j, 0] * bu[i]) / det,
        ],
        axis=1,
    )
    candidates = np.concatenate([singles, pairs])
    slack = candidates @ A.T - b[None, :]  # (k, m), every row including unusable ones
    tol = FEASIBILITY_TOL * np.maximum(1.0, np.abs(b))[None, :]
    feasible = np.all(slack <= tol, axis=1)
    if not np.any(feasible):
        raise ValueError("the barrier rows have no common point")
    cost = np.where(feasible, np.sum((candidates - nominal) ** 2, axis=1), np.inf)
    best = int(np.argmin(cost))
    tight = int(np.sum(np.abs(slack[best]) <= 1e-9 * np.maximum(1.0, np.abs(b))))
    return candidates[best], max(tight, 1)


def safe_velocity(
    position: np.ndarray,
    nominal: np.ndarray,
    neighbors: np.ndarray,
    safe_distance: float,
    gamma: float = DEFAULT_GAMMA,
) -> FilterResult:
    """The velocity closest to ``nominal`` that keeps this robot's half of every pair safe.

    position: (2,) m, the steered point of this robot; nominal: (2,) m/s, the coverage
    law's velocity; neighbors: (m, 2) m, the other robots' points this robot knows;
    safe_distance: m between two robots' points; gamma: 1/s (:func:`barrier_gain`).
    Non-finite neighbours are ignored; a non-finite position or nominal velocity gives 0.
    When the rows cannot all hold (a pair already inside the safe distance and boxed in),
    the bounds are raised to 0, which the zero velocity satisfies: the robot then gets the
    velocity closest to ``nominal`` that closes on no neighbour (``relaxed``).
    """
    if safe_distance < 0.0 or gamma <= 0.0:
        raise ValueError(f"need safe_distance >= 0 and gamma > 0, got {safe_distance}, {gamma}")
    position = np.asarray(position, dtype=float).reshape(2)
    nominal = np.asarray(nominal, dtype=float).reshape(2)
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(nominal))):
        return FilterResult(np.zeros(2), 0, False)
    neighbors = np.asarray(neighbors, dtype=float).reshape(-1, 2)
    neighbors = neighbors[np.all(np.isfinite(neighbors), axis=1)]
    A, b = pair_constraints(position, neighbors, safe_distance, gamma)
    try:
        velocity, active = closest_feasible(nominal, A, b)
        return FilterResult(velocity, active, False)
    except ValueError:
        velocity, active = closest_feasible(nominal, A, np.maximum(b, 0.0))
        return FilterResult(velocity, active, True)
