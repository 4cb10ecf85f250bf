"""Collision avoidance: decentralised barrier certificates on single-integrator velocities.

Robots are disks. A pair (i, j) is safe while h_ij = |p_i - p_j|^2 - D_s^2 >= 0, p the robots'
centres and D_s the safe distance between them (a diameter plus a margin). Ames et al.'s
control barrier function condition for single integrators, dh/dt >= -gamma h, reads

    -2 (p_i - p_j) . (u_i - u_j) <= gamma h_ij,

and in the decentralised form the Robotarium uses (Wang, Ames & Egerstedt, "Safety barrier
certificates for collisions-free multirobot systems", IEEE T-RO 2017) each robot takes half
of it, with its neighbour's velocity left out:

    a_ij . u_i <= b_ij,   a_ij = -2 (p_i - p_j),   b_ij = gamma h_ij / 2.

If both robots satisfy their halves, the pair satisfies the whole. That split is
conservative for robots moving together: a robot following another at the domain's speed
may not close on it at all, whatever the leader does, and on the passage it held the team
back by e_a ~0.2 m. So when both robots' current velocities v_i, v_j are known (our last
command, the neighbour's reported one), each takes half of the *change* instead:

    a_ij . u_i <= gamma h_ij / 2 + c_ij,   c_ij = clip(a_ij . (v_i + v_j) / 2, +-gamma h_ij / 2),

and the two halves (robot j's row has a_ji = -a_ij, the same v_i, v_j, so c_ji = -c_ij) still
sum to the pair's condition. The clip keeps both bounds in [0, gamma h]: u = 0 meets every
row while h >= 0, so the QP is never infeasible for robots that are apart, and neither robot
is asked to flee. With v = 0 it is the Robotarium's split.

The clip still caps a follower's closing speed at gamma h / (2 d) whatever its leader does,
so a robot also adds RECEDE_SHARE of a neighbour's reported speed away from it,
a_ij . v_j when positive, to its bound, at most gamma (D_s^2 - (D_s - RECEDE_SLACK)^2) / 2
(:func:`pair_constraints`). Not the guarantee below at D_s: a neighbour that stops (or
reports a stale velocity) lets the pair close inside D_s; but with both credits so capped
the two rows sum to the condition on D_s - RECEDE_SLACK, which the guarantee then keeps.

Each robot then solves a QP in the plane, min |u - u_hat|^2 subject to one such row per
neighbour, here exactly (see :func:`closest_feasible`), never by an iterative solver.

Differential-drive robots (:func:`unicycle_rows`): the wheels move the axle centre p only
along the heading e, with speed v = e . u for the steered velocity u (covswarm.tvd.drive),
so dp/dt = e e^T u and a row a . dp/dt <= b is the row (a . e) e^T u <= b on u: exact for
the body centre, and every row then limits only the forward speed (turning in place never
moves the centre), so the QP keeps the turn and clamps the speed to an interval.

Static obstacles and walls (:func:`obstacle_constraints`): for a convex obstacle O (a polygon)
the robot keeps h_O(p) = dist(p, O) - r - margin >= 0, r its body radius, with the row

    grad h_O(p) . u >= -gamma h_O(p),   i.e.   -grad h_O . u <= gamma h_O,

the robot taking the whole condition (an obstacle does not move, nobody shares it); each
wall of the rectangular workspace is a half-plane with h = (distance to the wall) - r -
margin. grad h_O is the unit vector from O's nearest point to p (the outward edge normal
inside O: covswarm.tvd.geometry.point_polygon_distance_grad). dist(p, O) is convex in p,
so h_O(p + s u) >= h_O + s grad h_O . u >= (1 - gamma s) h_O: the sampled guarantee below
holds for obstacles too, and exactly for walls (h affine). u = 0 meets every obstacle row
while h_O >= 0, so obstacles never make the QP infeasible for a robot that is clear of them.

Linear class-K function (gamma h, not the Robotarium's gamma h^3) on purpose: with velocities
held over a sampling period T (zero-order hold, the agents' control period),
h(t + s) = h + 2 s d.(u_i - u_j) + s^2 |u_i - u_j|^2 >= (1 - gamma s) h, so for gamma T <= 1
a pair that satisfies the condition at the sample never closes below D_s before the next
one: the continuous-time guarantee survives sampling exactly (for single integrators).

Pure numpy, no I/O. Distances in m, velocities in m/s, gamma in 1/s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from covswarm.tvd.arrays import as_point, as_rows, as_values

# (xmin, xmax, ymin, ymax) m: a rectangular workspace, the robots' centres inside.
Box = tuple[float, float, float, float]

# 1/s: the barrier's decay rate. gamma T <= 1 is what keeps the guarantee at a sampling
# period T (module docstring): this is the largest for the agents' 10 Hz, and an agent
# running slower caps it (barrier_gain). Smaller is more cautious and costs coverage: on the
# passage (deploy.netsim, 10 robots, the agents then on TVD-D1) e_a's second-half mean was
# 0.069 m at 10/s against 0.115 m at 5/s and 0.055 m without the filter.
DEFAULT_GAMMA = 10.0
FAR_AWAY = 1.0e15  # m: where a robot without a finite position is put in a neighbour search
# m: distance between robot centres kept beyond the body diameter, for what the model does
# not know (pose noise, a neighbour's dead-reckoning error, the arc a unicycle drives
# between two commands instead of the straight line of the rows).
DEFAULT_MARGIN = 0.02
FEASIBILITY_TOL = 1e-9  # m^2/s: slack allowed on a row when checking a candidate
# m: robots within this distance of a robot enter its safety filter (an agent also follows
# their AgentStates when they are not Voronoi neighbours: robots outside S, with empty
# cells, have none). The safe distance (0.16 m) plus what two robots at the wheels' top
# speed (0.8 m/s each) close in two 10 Hz periods (0.32 m). Farther is not safer, only
# dearer: at 1 m, a 100-robot circle run (0.2 m spacing) followed ~75 states per agent,
# 436 messages/s, missed 18 % of its deadlines and lost the domain (e_a 2.3 m); at 0.5 m the
# followed set is about the two-hop set, which the coverage step follows anyway. Slower
# steps or a command latency are covered by driving slower instead (unseen_speed_limit).
SAFETY_RADIUS = 0.5
# Fraction of a neighbour's speed away from us (its reported velocity along the pair,
# a_ij . v_j when positive) that a robot may add to its bound (pair_constraints): the
# split's clip alone caps a follower's closing speed at gamma h / (2 d) whatever its leader
# does, so a robot behind another at S's speed (0.19 m/s) could not hold under 0.18 m
# (gamma 10) and, once behind S, did not catch up (circle-1000, covswarm sim, unicycles at
# 10 Hz, seeds 0-2: e_a's second-half mean 0.037 m without, 0.020 m with).
RECEDE_SHARE = 0.5
# m: how far inside the safe distance D that credit can take a pair, whatever the neighbour
# then does (stops dead, or its reported velocity is stale or wrong): each robot's credit
# is at most gamma (D^2 - (D - RECEDE_SLACK)^2) / 2, so a pair's two rows still sum to the
# sampled barrier condition on |p_i - p_j| >= D - RECEDE_SLACK (module docstring). Part of
# DEFAULT_MARGIN; a single follower uses about half of it (a leader standing still while
# reported receding at 0.8 m/s: closest 0.153 m at D = 0.16; uncapped, 0.120 m).
RECEDE_SLACK = 0.015


def _recede_credit(
    a: np.ndarray,
    v_other: np.ndarray,
    share: np.ndarray,
    safe_distance: float | np.ndarray,
    gamma: float | np.ndarray,
) -> np.ndarray:
    """Each row's extra bound for a neighbour moving away: RECEDE_SHARE max(a . v_j, 0), at
    most gamma (D^2 - (D - RECEDE_SLACK)^2) / 2, and none for a pair without a share left
    (h <= 0). a: (m, 2) rows; v_other: (m, 2) m/s; share, safe_distance, gamma: (m,) or
    scalars."""
    away = np.maximum(np.einsum("ij,ij->i", a, v_other), 0.0)
    inner = np.maximum(safe_distance - RECEDE_SLACK, 0.0)
    cap = 0.5 * gamma * (safe_distance**2 - inner**2)
    return np.where(share > 0.0, np.minimum(RECEDE_SHARE * away, cap), 0.0)


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


def body_safe_distance(body_diameter: float, margin: float = DEFAULT_MARGIN) -> float:
    """Safe distance between two robots' centres: a body diameter (two radii) plus
    ``margin``, m."""
    return body_diameter + margin


def wall_distance(body_diameter: float, margin: float = DEFAULT_MARGIN) -> float:
    """Distance kept between a robot's centre and an obstacle or wall: a body radius plus
    ``margin``, m (the same margin as between two robots)."""
    return 0.5 * body_diameter + margin


def barrier_gain(gamma: float, period: float) -> float:
    """The decay rate to use at a sampling period of ``period`` s: min(gamma, 1 / period),
    the largest that keeps the sampled guarantee of the module docstring."""
    if period <= 0.0:
        return gamma
    return min(gamma, 1.0 / period)


def unseen_speed_limit(
    radius: float, safe_distance: float, position_error: float, hold: float, latency: float
) -> float:
    """m/s: the fastest a robot may drive so that no robot it does not filter against yet
    comes within ``safe_distance`` m before its next command acts.

    A robot filters against the robots it knows within ``radius`` m (SAFETY_RADIUS), each
    known to within ``position_error`` m plus what it drove since it last said where it
    was (once per step: at most v ``hold``). One known farther away is at least
    radius - position_error - v hold away; until our next command acts, ``hold`` s of
    driving and ``latency`` s of commands in flight later, each of the two closes at
    most v (hold + latency). Both at speed v stay apart by the safe distance while
    radius - position_error - D >= v (3 hold + 2 latency); the next step has the other
    robot among its rows, and the barrier keeps the pair apart from there (module
    docstring). ``hold``: s each command drives (a control period, or the robot's
    command timeout when steps come later); 0 or less: no limit (inf)."""
    span = 3.0 * hold + 2.0 * latency
    if span <= 0.0:
        return math.inf
    return max(radius - position_error - safe_distance, 0.0) / span


def pair_constraints(
    position: np.ndarray,
    neighbors: np.ndarray,
    safe_distance: float,
    gamma: float | np.ndarray,
    velocity: np.ndarray | None = None,
    neighbor_velocities: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One robot's half of each pair's barrier condition: rows (A (m, 2), b (m,)), A u <= b.

    position: (2,) m; neighbors: (m, 2) m; velocity: (2,) m/s, this robot's current one, and
    neighbor_velocities: (m, 2) m/s, theirs (None: zero, the Robotarium's split); gamma:
    1/s, one for all rows or (m,), one per row.
    a_j = -2 (p - p_j), b_j = gamma h_j / 2 + clip(a_j . (v + v_j) / 2, +-gamma h_j / 2) with
    h_j = |p - p_j|^2 - safe_distance^2 (no share for a pair already inside, h_j < 0).
    """
    offset = np.asarray(position, dtype=float).reshape(2) - np.asarray(
        neighbors, dtype=float
    ).reshape(-1, 2)
    h = np.einsum("ij,ij->i", offset, offset) - safe_distance**2
    A, b = -2.0 * offset, 0.5 * gamma * h
    if velocity is not None or neighbor_velocities is not None:
        mean = np.zeros((len(A), 2))
        if velocity is not None:
            mean = mean + 0.5 * np.asarray(velocity, dtype=float).reshape(1, 2)
        theirs = None
        if neighbor_velocities is not None:
            theirs = np.asarray(neighbor_velocities, dtype=float).reshape(-1, 2)
            mean = mean + 0.5 * theirs
        share = np.maximum(b, 0.0)
        b = b + np.clip(np.einsum("ij,ij->i", A, mean), -share, share)
        if theirs is not None:
            b = b + _recede_credit(A, theirs, share, safe_distance, gamma)
    return A, b


def polygon_distance_grads(
    point: np.ndarray, polygons: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`covswarm.tvd.geometry.point_polygon_distance_grad` of ``point`` (2,) m to each
    of m convex CCW polygons (k_j, 2) m at once: (signed distances (m,) m, gradients (m, 2)).
    ``point`` may also be (m, 2), a point per polygon (several robots' obstacles at once).

    One numpy pass over the polygons padded to the most vertices K (a short one repeats its
    last vertex: zero-length edges, which the nearest point ignores by ties and the depth by
    a mask), instead of a call per polygon, whose overhead dominated an agent's filter near
    a map's many pieces. The same formulas edge by edge (equal to rounding).
    """
    p = np.asarray(point, dtype=float).reshape(-1, 2)
    px, py = p[:, :1], p[:, 1:]  # (1, 1) or (m, 1): broadcast over the polygons' vertices
    m = len(polygons)
    sizes = {len(q) for q in polygons}
    if len(sizes) == 1:  # all boxes, say: no padding
        a = np.array(polygons, dtype=float).reshape(m, -1, 2)
    else:
        a = np.empty((m, max(sizes), 2))
        for j, q in enumerate(polygons):
            n = len(q)
            a[j, :n], a[j, n:] = q, q[n - 1]
    # Components on (m, K) arrays: faster than einsum over a last axis of 2.
    ax, ay = a[..., 0], a[..., 1]
    dx, dy = np.roll(ax, -1, axis=1) - ax, np.roll(ay, -1, axis=1) - ay  # K-1 closes
    rx, ry = px - ax, py - ay
    length2 = dx * dx + dy * dy
    valid = length2 > 0.0
    safe2 = np.where(valid, length2, 1.0)
    inside = np.all(dx * ry - dy * rx >= 0.0, axis=1)
    t = np.clip((rx * dx + ry * dy) / safe2, 0.0, 1.0)
    gx, gy = rx - t * dx, ry - t * dy  # p - nearest point of each edge
    d2 = gx * gx + gy * gy
    best = np.argmin(d2, axis=1)
    rows = np.arange(m)
    dist = np.sqrt(d2[rows, best])
    outside = ~inside & (dist > 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        grad = np.stack([gx[rows, best], gy[rows, best]], axis=1) / dist[:, None]
    signed = dist.copy()
    if not outside.all():
        # Inside or on the boundary: the deepest edge line (the first of equals), as
        # geometry's, on the outward unit normals.
        norm = np.sqrt(safe2)
        nx, ny = dy / norm, -dx / norm
        depth = np.where(valid, nx * rx + ny * ry, -np.inf)
        deepest = np.argmax(depth, axis=1)
        normal = np.stack([nx[rows, deepest], ny[rows, deepest]], axis=1)
        grad[~outside] = normal[~outside]
        signed[~outside] = np.minimum(depth[rows, deepest], 0.0)[~outside]
    return signed, grad


def obstacle_constraints(
    position: np.ndarray,
    obstacles: Sequence[np.ndarray],
    workspace: Box | None,
    distance: float,
    gamma: float,
    reach: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """This robot's barrier rows for static obstacles and walls: (A (m, 2), b (m,)), A u <= b.

    position: (2,) m, the robot's centre; obstacles: convex polygons (k, 2) m, CCW;
    workspace: the walls (xmin, xmax, ymin, ymax) m, or None; distance: m kept between the
    centre and an obstacle (:func:`wall_distance`); reach: m, obstacles and walls farther
    than this from the centre get no row. Per obstacle or wall, h = dist - ``distance`` and
    the row -grad h . u <= gamma h (module docstring), the whole condition.
    """
    p = np.asarray(position, dtype=float).reshape(2)
    rows: list[np.ndarray] = []
    bounds: list[float] = []
    if len(obstacles):
        signed, grad = polygon_distance_grads(p, obstacles)
        near = signed <= reach
        rows.extend(-grad[near])
        bounds.extend(gamma * (signed[near] - distance))
    if workspace is not None:
        xmin, xmax, ymin, ymax = (float(v) for v in workspace)
        if not (xmin < xmax and ymin < ymax):
            raise ValueError(f"workspace must be (xmin, xmax, ymin, ymax), got {workspace!r}")
        # Inward normals of the left, right, bottom and top walls, and each wall's distance.
        inward = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        gaps = np.array([p[0] - xmin, xmax - p[0], p[1] - ymin, ymax - p[1]])
        near = gaps <= reach
        rows.extend(-inward[near])
        bounds.extend(gamma * (gaps[near] - distance))
    return np.array(rows, dtype=float).reshape(-1, 2), np.array(bounds, dtype=float)


def unicycle_rows(A: np.ndarray, heading: float) -> np.ndarray:
    """Rows on the steered velocity u of a differential-drive robot heading ``heading``
    (rad) from rows ``A`` (m, 2) on its centre's velocity: (A e) e^T (module docstring)."""
    e = np.array([np.cos(heading), np.sin(heading)])
    return (np.asarray(A, dtype=float).reshape(-1, 2) @ e)[:, None] * e[None, :]


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
    *,
    heading: float | None = None,
    velocity: np.ndarray | None = None,
    neighbor_velocities: np.ndarray | None = None,
    obstacles: Sequence[np.ndarray] = (),
    workspace: Box | None = None,
    obstacle_distance: float | None = None,
    reach: float = np.inf,
    obstacle_gamma: float | None = None,
    neighbor_gammas: np.ndarray | None = None,
) -> FilterResult:
    """The velocity closest to ``nominal`` that keeps this robot's half of every pair safe.

    position: (2,) m, this robot's centre; nominal: (2,) m/s, the coverage law's velocity;
    neighbors: (m, 2) m, the other robots' centres this robot knows; safe_distance: m
    between two centres (:func:`body_safe_distance`); gamma: 1/s (:func:`barrier_gain`).
    heading: rad, for a differential-drive robot whose steered point moves with ``nominal``
    (:func:`unicycle_rows`; None: a single integrator). velocity, neighbor_velocities: the
    current centre velocities for the reciprocal split (:func:`pair_constraints`).
    obstacles (convex polygons (k, 2) m), workspace (walls (xmin, xmax, ymin, ymax) m): one
    row each within ``reach`` m (:func:`obstacle_constraints`), keeping the centre
    ``obstacle_distance`` m from them (:func:`wall_distance`; required with either), at the
    decay rate ``obstacle_gamma`` 1/s (None: ``gamma``; smaller leaves room for command
    latency, covswarm.agent.brain.WALL_GAMMA_FRACTION). With neither, the rows and the
    result are exactly those of the robots alone. neighbor_gammas: (m,) 1/s, each pair
    row's own decay rate in place of ``gamma`` (None: ``gamma`` for all).
    Non-finite neighbours are ignored; a non-finite position, heading or nominal velocity
    gives 0. When the rows cannot all hold (``relaxed``: a pair already inside the safe
    distance, boxed in), every bound is raised to max(gamma h / 2, 0), which the zero
    velocity meets: the robot closes on no one that way, but the pair's guarantee is gone
    until it is apart again; an obstacle's or wall's bound is raised to max(gamma h, 0)
    likewise. Callers count these.
    """
    if safe_distance < 0.0 or gamma <= 0.0:
        raise ValueError(f"need safe_distance >= 0 and gamma > 0, got {safe_distance}, {gamma}")
    walled = len(obstacles) > 0 or workspace is not None
    if walled and not (obstacle_distance is not None and obstacle_distance >= 0.0):
        raise ValueError(f"obstacles need obstacle_distance >= 0, got {obstacle_distance!r}")
    if obstacle_gamma is not None and not obstacle_gamma > 0.0:
        raise ValueError(f"need obstacle_gamma > 0, got {obstacle_gamma!r}")
    position = as_point(position, "position")
    nominal = as_point(nominal, "nominal")
    neighbors = as_rows(neighbors, "neighbors")
    if neighbor_velocities is not None:
        neighbor_velocities = as_rows(neighbor_velocities, "neighbor_velocities", len(neighbors))
    finite = np.all(np.isfinite(position)) and np.all(np.isfinite(nominal))
    if not finite or (heading is not None and not np.isfinite(heading)):
        return FilterResult(np.zeros(2), 0, False)
    keep = np.all(np.isfinite(neighbors), axis=1)
    if neighbor_velocities is not None:
        keep &= np.all(np.isfinite(neighbor_velocities), axis=1)
        neighbor_velocities = neighbor_velocities[keep]
    if velocity is not None and not np.all(np.isfinite(velocity)):
        velocity = None
    pair_gamma: float | np.ndarray = gamma
    if neighbor_gammas is not None:
        given = np.asarray(neighbor_gammas, dtype=float).reshape(-1)
        if len(given) != len(keep):
            raise ValueError(f"need one of neighbor_gammas per neighbour, got {len(given)}")
        pair_gamma = given[keep]
        if not np.all(pair_gamma > 0.0):  # NaN too
            raise ValueError("need neighbor_gammas > 0 (not NaN)")
    A, b = pair_constraints(
        position, neighbors[keep], safe_distance, pair_gamma, velocity, neighbor_velocities
    )
    offset = position - neighbors[keep]
    h = np.einsum("ij,ij->i", offset, offset) - safe_distance**2
    relaxed = np.maximum(0.5 * pair_gamma * h, 0.0)
    if walled:
        wall_gamma = gamma if obstacle_gamma is None else obstacle_gamma
        A_o, b_o = obstacle_constraints(
            position, obstacles, workspace, float(obstacle_distance), wall_gamma, reach
        )
        A, b = np.concatenate([A, A_o]), np.concatenate([b, b_o])
        relaxed = np.concatenate([relaxed, np.maximum(b_o, 0.0)])
    if heading is not None:
        A = unicycle_rows(A, heading)
    try:
        velocity, active = closest_feasible(nominal, A, b)
        return FilterResult(velocity, active, False)
    except ValueError:
        pass
    velocity, active = closest_feasible(nominal, A, relaxed)
    return FilterResult(velocity, active, True)


def team_safe_velocities(
    positions: np.ndarray,
    nominal: np.ndarray,
    safe_distance: float,
    gamma: float,
    radius: float,
    *,
    headings: np.ndarray | None = None,
    velocities: np.ndarray | None = None,
    nearby_obstacles: Callable[[np.ndarray, float], Sequence[np.ndarray]] | None = None,
    workspace: Box | None = None,
    obstacle_distance: float | None = None,
    subset: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every robot's :func:`safe_velocity` against the others within ``radius`` m, as each
    agent filters its own (the in-process simulator's team at once).

    positions: (n, 2) m; nominal: (n, 2) m/s; headings: (n,) rad for differential-drive
    robots (None: single integrators); velocities: (n, 2) m/s, the centres' current ones for
    the reciprocal split (None: the Robotarium's). nearby_obstacles(point (2,), radius): the
    obstacles (convex polygons) within radius m of a point, say
    covswarm.world.model.World.nearby; workspace, obstacle_distance: as in
    :func:`safe_velocity`; each robot gets rows for those within ``radius``. Returns
    (velocities (n, 2), active (n,) rows tight per robot, relaxed (n,) bool). With headings
    the team is filtered in one batch (:func:`safe_unicycle_velocities`). subset: indices of
    the single integrators to filter (None: all); the others keep their nominal velocity,
    0 rows and not relaxed (the simulator's slides: covswarm.tvd.drive.steer).
    """
    from scipy.spatial import cKDTree

    positions = as_rows(positions, "positions")
    n = len(positions)
    nominal = as_rows(nominal, "nominal", n)
    if velocities is not None:
        velocities = as_rows(velocities, "velocities", n)
    if headings is not None:
        headings = as_values(headings, "headings", n)
    out = np.empty((n, 2))
    active = np.zeros(n, dtype=int)
    relaxed = np.zeros(n, dtype=bool)
    # A robot whose position is not finite gets 0 (safe_velocity's rule) and is nobody's
    # neighbour: the tree holds it far beyond every radius.
    finite = np.isfinite(positions).all(axis=1)
    searched = np.where(finite[:, None], positions, FAR_AWAY)
    tree = cKDTree(searched)
    if headings is not None:  # differential drive: the whole team in one batch
        if subset is not None:
            raise ValueError("subset is for single integrators (headings=None)")
        # Each robot's neighbours as slices of one array (a fancy index per robot cost a
        # tenth of covswarm sim at 1000 robots); their order does not change the result.
        pairs = tree.query_pairs(radius, output_type="ndarray")
        owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
        other = np.concatenate([pairs[:, 1], pairs[:, 0]])[np.argsort(owner, kind="stable")]
        cuts = np.cumsum(np.bincount(owner, minlength=n))[:-1]
        return safe_unicycle_velocities(
            positions,
            nominal,
            headings,
            np.split(positions[other], cuts),
            safe_distance,
            gamma,
            velocities=velocities,
            neighbor_velocities=None
            if velocities is None
            else np.split(np.asarray(velocities, dtype=float)[other], cuts),
            obstacles=None
            if nearby_obstacles is None
            else [nearby_obstacles(p, radius) for p in positions],
            workspace=workspace,
            obstacle_distance=obstacle_distance,
            reach=radius,
        )
    robots = np.arange(n) if subset is None else np.asarray(subset, dtype=int).reshape(-1)
    out[:] = nominal
    near = tree.query_ball_point(searched[robots], radius)
    for i, around in zip(robots.tolist(), near, strict=True):
        others = [j for j in around if j != i and finite[j]]
        result = safe_velocity(
            positions[i],
            nominal[i],
            positions[others],
            safe_distance,
            gamma,
            velocity=None if velocities is None else velocities[i],
            neighbor_velocities=None if velocities is None else velocities[others],
            obstacles=() if nearby_obstacles is None else nearby_obstacles(positions[i], radius),
            workspace=workspace,
            obstacle_distance=obstacle_distance,
            reach=radius,
        )
        out[i], active[i], relaxed[i] = result.velocity, result.active, result.relaxed
    return out, active, relaxed


def safe_unicycle_velocities(
    positions: np.ndarray,
    nominal: np.ndarray,
    headings: np.ndarray,
    neighbors: Sequence[np.ndarray],
    safe_distance: float | np.ndarray,
    gamma: float | np.ndarray = DEFAULT_GAMMA,
    *,
    velocities: np.ndarray | None = None,
    neighbor_velocities: Sequence[np.ndarray] | None = None,
    obstacles: Sequence[Sequence[np.ndarray]] | None = None,
    workspace: Box | Sequence[Box | None] | None = None,
    obstacle_distance: float | np.ndarray | None = None,
    reach: float = np.inf,
    obstacle_gamma: float | np.ndarray | None = None,
    neighbor_gammas: Sequence[np.ndarray | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`safe_velocity` of R differential-drive robots at once (the brains of one process
    due in one tick): robot r's result equals ``safe_velocity(positions[r], nominal[r],
    neighbors[r], safe_distance, gamma, heading=headings[r], velocity=velocities[r],
    neighbor_velocities=neighbor_velocities[r], obstacles=obstacles[r], workspace=workspace,
    obstacle_distance=..., reach=reach, obstacle_gamma=...,
    neighbor_gammas=neighbor_gammas[r])`` to rounding.

    positions, nominal: (R, 2) m, m/s; headings: (R,) rad; neighbors: R arrays (m_r, 2) m;
    velocities: (R, 2) m/s or None; neighbor_velocities: R arrays (m_r, 2) m/s or None;
    neighbor_gammas: R arrays (m_r,) 1/s (or None each: ``gamma``), or None;
    obstacles: R sequences of convex polygons or None; workspace: one box for all, or a box
    or None per robot; safe_distance, gamma, obstacle_distance, obstacle_gamma: one value
    or (R,) values. Returns (velocities (R, 2) m/s, active (R,) rows tight, relaxed (R,)
    bool; callers count these); a robot whose position, nominal velocity or heading is not
    finite gets 0, as from safe_velocity.

    With the heading e given every row is (a . e) e^T u <= b (:func:`unicycle_rows`), a
    bound on the forward speed s = e . u alone, so the QP keeps the sideways part of the
    nominal velocity and clips s to the interval the rows leave: [max b/alpha over
    alpha = a . e < 0, min b/alpha over alpha > 0], checked with :func:`closest_feasible`'s
    tolerances (an empty interval: the relaxed bounds, as there). Every robot's rows in one
    padded (R, M) array: a few dozen numpy calls for the whole batch.
    """
    gamma = np.asarray(gamma, dtype=float)
    safe_distance = np.asarray(safe_distance, dtype=float)
    if np.any(safe_distance < 0.0) or np.any(gamma <= 0.0):
        raise ValueError(f"need safe_distance >= 0 and gamma > 0, got {safe_distance}, {gamma}")
    walled = obstacles is not None or workspace is not None
    if walled and not (
        obstacle_distance is not None and np.all(np.asarray(obstacle_distance) >= 0.0)
    ):
        raise ValueError(f"obstacles need obstacle_distance >= 0, got {obstacle_distance!r}")
    if obstacle_gamma is not None and not np.all(np.asarray(obstacle_gamma) > 0.0):
        raise ValueError(f"need obstacle_gamma > 0, got {obstacle_gamma!r}")
    p = as_rows(positions, "positions")
    count = len(p)
    nominal = as_rows(nominal, "nominal", count)
    headings = as_values(headings, "headings", count)
    if len(neighbors) != count:
        raise ValueError(f"neighbors must hold one array per robot ({count}), got {len(neighbors)}")
    ok = np.isfinite(p).all(axis=1) & np.isfinite(nominal).all(axis=1) & np.isfinite(headings)
    # A robot with bad input gets 0 (its rows are left out); computed as a still one.
    nominal, headings = np.where(ok[:, None], nominal, 0.0), np.where(ok, headings, 0.0)
    gamma, safe_distance = np.broadcast_to(gamma, count), np.broadcast_to(safe_distance, count)
    wall_gamma = gamma if obstacle_gamma is None else np.broadcast_to(obstacle_gamma, count)
    rows = [
        _pair_rows(
            p, ok, neighbors, safe_distance, gamma, velocities, neighbor_velocities, neighbor_gammas
        )
    ]
    if walled:
        distance = np.broadcast_to(np.asarray(obstacle_distance, dtype=float), count)
        rows.append(_obstacle_rows(p, ok, obstacles, workspace, distance, wall_gamma, reach))
    owner, a, b, relaxed_b = (np.concatenate(parts) for parts in zip(*rows, strict=True))
    e = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    speed = np.einsum("ri,ri->r", e, nominal)
    alpha = np.einsum("ti,ti->t", a, e[owner])
    # Padded to (R, M): a padding row is 0 <= inf, which nothing violates.
    order = np.argsort(owner, kind="stable")
    owner, alpha, b, relaxed_b = owner[order], alpha[order], b[order], relaxed_b[order]
    first = np.searchsorted(owner, np.arange(count))
    slot = np.arange(len(owner)) - first[owner]
    width = int(slot.max(initial=-1)) + 1
    padded_alpha = np.zeros((count, width))
    padded_alpha[owner, slot] = alpha
    padded_b, padded_relaxed = np.full((count, width), np.inf), np.full((count, width), np.inf)
    padded_b[owner, slot], padded_relaxed[owner, slot] = b, relaxed_b
    forward, active, feasible = _clip_speed(speed, padded_alpha, padded_b)
    relaxed = ~feasible
    if relaxed.any():
        again = _clip_speed(speed[relaxed], padded_alpha[relaxed], padded_relaxed[relaxed])
        forward[relaxed], active[relaxed] = again[0], again[1]
    velocity = nominal + (forward - speed)[:, None] * e
    return (
        np.where(ok[:, None], velocity, 0.0),
        np.where(ok, active, 0),
        relaxed & ok,
    )


def _clip_speed(
    speed: np.ndarray, alpha: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The forward speed nearest ``speed`` (R,) with alpha s <= b on every row (R, M):
    (speed (R,), tight rows (R,), feasible (R,) bool), :func:`closest_feasible` on rows
    alpha e^T: a nominal within FEASIBILITY_TOL of every row is kept (0 rows tight), rows
    with |alpha| <= 1e-12 only bound the feasibility (0 <= b), and the nearest end of the
    interval must meet every row to FEASIBILITY_TOL max(1, |b|)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        kept = np.all(alpha * speed[:, None] - b <= FEASIBILITY_TOL, axis=1)
        usable = alpha * alpha > 1e-24
        bound = b / alpha
        upper = np.where(usable & (alpha > 0.0), bound, np.inf).min(axis=1, initial=np.inf)
        lower = np.where(usable & (alpha < 0.0), bound, -np.inf).max(axis=1, initial=-np.inf)
        forward = np.where(kept, speed, np.minimum(np.maximum(speed, lower), upper))
        slack = alpha * forward[:, None] - b
        tol = FEASIBILITY_TOL * np.maximum(1.0, np.abs(b))
        feasible = kept | (
            np.all(slack <= tol, axis=1)
            & ~np.any(~usable & (b < -FEASIBILITY_TOL), axis=1)
            & np.isfinite(forward)
        )
        tight = np.maximum(np.sum((np.abs(slack) <= tol) & (b < np.inf), axis=1), 1)
    return forward, np.where(kept, 0, tight), feasible


Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _workspaces(
    workspace: Box | Sequence[Box | None] | None, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """The robots with walls (W,) and their boxes (W, 4): ``workspace`` is one box for all,
    or one box or None per robot. ValueError for a box that is not xmin < xmax, ymin < ymax."""
    if workspace is None:
        return np.zeros(0, dtype=int), np.zeros((0, 4))
    try:
        shared = [float(v) for v in workspace]
    except TypeError:  # a box or None per robot
        robots = [r for r, box in enumerate(workspace) if box is not None]
        boxes = [[float(v) for v in workspace[r]] for r in robots]
    else:
        robots, boxes = list(range(count)), [shared] * count
    for box in boxes:
        if not (len(box) == 4 and box[0] < box[1] and box[2] < box[3]):
            raise ValueError(f"workspace must be (xmin, xmax, ymin, ymax), got {box!r}")
    return np.array(robots, dtype=int), np.array(boxes, dtype=float).reshape(-1, 4)


def _pair_rows(
    p: np.ndarray,
    ok: np.ndarray,
    neighbors: Sequence[np.ndarray],
    safe_distance: np.ndarray,
    gamma: np.ndarray,
    velocities: np.ndarray | None,
    neighbor_velocities: Sequence[np.ndarray] | None,
    neighbor_gammas: Sequence[np.ndarray | None] | None = None,
) -> Rows:
    """Every robot's :func:`pair_constraints` rows, flat: (owner (T,), A (T, 2), b (T,),
    relaxed bounds (T,)); neighbours (or their velocities) not finite are left out, as a
    velocity of our own that is not finite (then zero)."""
    arrays = [np.asarray(x, dtype=float).reshape(-1, 2) for x in neighbors]
    owner = np.repeat(np.arange(len(p)), [len(x) for x in arrays])
    q = np.concatenate([np.zeros((0, 2)), *arrays])
    keep = ok[owner] & np.isfinite(q).all(axis=1)
    row_gamma = gamma[owner]
    if neighbor_gammas is not None:
        row_gamma = np.concatenate(
            [
                row_gamma[:0],
                *(
                    np.broadcast_to(gamma[r], len(x))
                    if g is None
                    else np.asarray(g, dtype=float).reshape(len(x))
                    for r, (x, g) in enumerate(zip(arrays, neighbor_gammas, strict=True))
                ),
            ]
        )
        if not np.all(row_gamma[keep] > 0.0):  # NaN too
            raise ValueError("need neighbor_gammas > 0 (not NaN)")
    mean = np.zeros((len(q), 2))
    vq = None
    if neighbor_velocities is not None:
        theirs = [np.asarray(x, dtype=float).reshape(-1, 2) for x in neighbor_velocities]
        vq = np.concatenate([np.zeros((0, 2)), *theirs])
        keep &= np.isfinite(vq).all(axis=1)
        mean = 0.5 * vq
    if velocities is not None:
        own = np.asarray(velocities, dtype=float).reshape(-1, 2)
        own = np.where(np.isfinite(own).all(axis=1)[:, None], own, 0.0)
        mean = 0.5 * own[owner] + mean
    owner, q, mean, row_gamma = owner[keep], q[keep], mean[keep], row_gamma[keep]
    offset = p[owner] - q
    h = np.einsum("ij,ij->i", offset, offset) - safe_distance[owner] ** 2
    a = -2.0 * offset
    half = 0.5 * row_gamma * h
    share = np.maximum(half, 0.0)
    b = half + np.clip(np.einsum("ij,ij->i", a, mean), -share, share)
    if vq is not None:
        b = b + _recede_credit(a, vq[keep], share, safe_distance[owner], row_gamma)
    return owner, a, b, share


def _obstacle_rows(
    p: np.ndarray,
    ok: np.ndarray,
    obstacles: Sequence[Sequence[np.ndarray]] | None,
    workspace: Box | Sequence[Box | None] | None,
    distance: np.ndarray,
    gamma: np.ndarray,
    reach: float,
) -> Rows:
    """Every robot's :func:`obstacle_constraints` rows, flat, as ``_pair_rows``."""
    parts: list[Rows] = []
    if obstacles is not None:
        polygons = [poly for r, near in enumerate(obstacles) if ok[r] for poly in near]
        owner = np.repeat(
            np.arange(len(p)), [len(near) if ok[r] else 0 for r, near in enumerate(obstacles)]
        )
        if polygons:
            signed, grad = polygon_distance_grads(p[owner], polygons)
            near = signed <= reach
            owner, b = owner[near], gamma[owner[near]] * (signed[near] - distance[owner[near]])
            parts.append((owner, -grad[near], b, np.maximum(b, 0.0)))
    robots, boxes = _workspaces(workspace, len(p))
    if len(robots):
        robots, boxes = robots[ok[robots]], boxes[ok[robots]]
        inward = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        x, y = p[robots, :1], p[robots, 1:]
        gaps = np.concatenate([x, boxes[:, 1:2], y, boxes[:, 3:]], axis=1) - np.concatenate(
            [boxes[:, :1], x, boxes[:, 2:3], y], axis=1
        )  # (R', 4): left, right, bottom, top
        near = gaps <= reach
        owner = np.broadcast_to(robots[:, None], gaps.shape)[near]
        wall = np.broadcast_to(np.arange(4), gaps.shape)[near]
        b = gamma[owner] * (gaps[near] - distance[owner])
        parts.append((owner, -inward[wall], b, np.maximum(b, 0.0)))
    empty: Rows = (np.zeros(0, dtype=int), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    owner, a, b, relaxed = (np.concatenate(x) for x in zip(empty, *parts, strict=True))
    return owner, a, b, relaxed
