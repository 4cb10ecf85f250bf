"""Robots that stand still as generators of the diagram (covswarm.tvd.control, ``still``).

A still robot (a dead brain's) keeps its cell and has pdot = 0, so each law is taken over
the moving robots alone: with J_mm the moving robots' block of dc/dp, TVD-D1 is
(I + J_mm) r_m, TVD-DA v + (I + J_mm)(kappa (c - p) + rho) with rho = dc/dt - (I - J_mm) v
(v read as 0 at still robots), TVD-C (I - J_mm)^-1 r_m. The references here are dense,
built from covswarm.tvd.coverage's r and dc/dp (each checked on its own against shapely and
central finite differences in test_coverage_reference and test_derivatives), with numpy's
dense solve for TVD-C.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference import KINDS, motion, random_convex_polygon, random_robots, scale_of, two_hop
from tvd_checks import pieces

from covswarm.tvd import control, coverage

A = control.MAX_AMPLIFICATION


def random_case(rng: np.random.Generator, n_max: int = 30):
    """(positions, polygon, V, kappa, still) with 1 to n/3 robots still."""
    polygon = random_convex_polygon(rng)
    n = int(rng.integers(4, n_max + 1))
    positions = random_robots(rng, polygon, n, outside_fraction=0.1)
    _, V = motion(KINDS[int(rng.integers(len(KINDS)))], polygon, rng)
    kappa = float(10 ** rng.uniform(-1, 1))
    still = np.zeros(n, dtype=bool)
    still[rng.choice(n, size=int(rng.integers(1, n // 3 + 1)), replace=False)] = True
    return positions, polygon, V, kappa, still


def guarded(raw: np.ndarray, values: np.ndarray, nb: list[set[int]]) -> np.ndarray:
    """The amplification guard: row i rescaled to A max(|w_i|, |w_j| of its neighbours)."""
    out = raw.copy()
    speeds = np.linalg.norm(values, axis=1)
    for i in range(len(raw)):
        bound = A * max(speeds[[i, *nb[i]]])
        if np.linalg.norm(raw[i]) > bound:
            out[i] = raw[i] * bound / np.linalg.norm(raw[i])
    return out


def neumann(w: np.ndarray, J: np.ndarray, nb: list[set[int]]) -> np.ndarray:
    """Guarded rows of (I + J) w, (n, 2)."""
    return guarded((w.ravel() + J @ w.ravel()).reshape(-1, 2), w, nb)


def d1_reference(positions, polygon, V, kappa, still):
    r, J, nb = pieces(positions, polygon, V, kappa)
    return neumann(np.where(still[:, None], 0.0, r), J, nb)


def da_reference(positions, polygon, V, kappa, still):
    r, J, nb = pieces(positions, polygon, V, kappa)
    feedback, _, _ = pieces(positions, polygon, V, kappa, feedforward=False)
    rate = r - feedback
    v = control.affine_field(polygon, V)(positions)
    w = np.where(still[:, None], 0.0, v)
    rho = rate - w + (J @ w.ravel()).reshape(-1, 2)
    u = np.where(still[:, None], 0.0, feedback + rho)
    return v + neumann(u, J, nb)


def c_reference(positions, polygon, V, kappa, still):
    r, J, _ = pieces(positions, polygon, V, kappa)
    moving = np.repeat(~still, 2)
    M = np.eye(int(moving.sum())) - J[np.ix_(moving, moving)]
    out = np.zeros_like(positions)
    out[~still] = np.linalg.solve(M, r.ravel()[moving]).reshape(-1, 2)
    return out, r, np.linalg.cond(M)


def scale(polygon, V, kappa) -> float:
    return kappa * scale_of(polygon) + float(np.max(np.abs(V)))


@pytest.mark.parametrize("law", ["d1", "da"])
def test_neumann_laws_over_the_moving_robots(law: str) -> None:
    rng = np.random.default_rng(["d1", "da"].index(law) + 40)
    reference = d1_reference if law == "d1" else da_reference
    for _ in range(25):
        positions, polygon, V, kappa, still = random_case(rng)
        step = control.team_step(law, positions, polygon, V, kappa, still=still)
        expected = reference(positions, polygon, V, kappa, still)
        assert np.all(step.velocity[still] == 0.0) and not step.guarded[still].any()
        error = np.linalg.norm(step.velocity[~still] - expected[~still])
        assert error <= 1e-9 * max(np.linalg.norm(expected), scale(polygon, V, kappa))


def test_tvd_c_solves_the_moving_block() -> None:
    rng = np.random.default_rng(42)
    solved = 0
    for _ in range(25):
        positions, polygon, V, kappa, still = random_case(rng)
        step = control.team_step("c", positions, polygon, V, kappa, damping=0.0, still=still)
        expected, r, cond = c_reference(positions, polygon, V, kappa, still)
        bound = A * np.max(np.linalg.norm(np.where(still[:, None], 0.0, r), axis=1))
        if step.fallback or cond > 1e8 or np.linalg.norm(expected, axis=1).max() > 0.99 * bound:
            continue
        solved += 1
        assert np.all(step.velocity[still] == 0.0)
        error = np.linalg.norm(step.velocity - expected)
        assert error <= 1e-12 * max(cond, 1e3) * max(np.linalg.norm(expected), bound)
    assert solved >= 10


def test_damped_tvd_c_keeps_still_robots_still_and_the_rest_as_the_moving_block() -> None:
    rng = np.random.default_rng(43)
    for _ in range(10):
        positions, polygon, V, kappa, still = random_case(rng)
        step = control.team_step("c", positions, polygon, V, kappa, still=still)
        assert np.all(step.velocity[still] == 0.0) and np.all(np.isfinite(step.velocity))
        # The damped least squares over the moving block, densely.
        r, J, _ = pieces(positions, polygon, V, kappa)
        feedback, _, _ = pieces(positions, polygon, V, kappa, feedforward=False)
        moving = np.repeat(~still, 2)
        M = np.eye(int(moving.sum())) - J[np.ix_(moving, moving)]
        prior = control.affine_field(polygon, V)(positions).ravel()[moving]
        rhs = (r - feedback).ravel()[moving] - M @ prior
        normal = M.T @ M + control.DAMPING**2 * np.eye(len(M))
        x = prior + np.linalg.solve(normal, M.T @ rhs)
        expected = feedback.ravel()[moving] + x
        if step.guarded.any():
            continue
        got = step.velocity.ravel()[moving]
        assert np.linalg.norm(got - expected) <= 1e-8 * scale(polygon, V, kappa)


def test_error_is_over_the_moving_robots() -> None:
    rng = np.random.default_rng(44)
    positions, polygon, V, kappa, still = random_case(rng)
    step = control.team_step("da", positions, polygon, V, kappa, still=still)
    _, centroids = coverage.mass_centroid(positions, polygon)
    expected = np.linalg.norm((positions - centroids)[~still])
    assert abs(step.error - expected) <= 1e-9 * scale_of(polygon)


def test_no_still_robot_is_the_law_to_the_bit() -> None:
    rng = np.random.default_rng(45)
    positions, polygon, V, kappa, _ = random_case(rng)
    none = np.zeros(len(positions), dtype=bool)
    for law in ("c", "d1", "da"):
        plain = control.team_step(law, positions, polygon, V, kappa)
        again = control.team_step(law, positions, polygon, V, kappa, still=none)
        np.testing.assert_array_equal(plain.velocity, again.velocity)


@pytest.mark.parametrize("law", ["d1", "da"])
def test_local_steps_with_still_robots_equal_the_team_rows(law: str) -> None:
    rng = np.random.default_rng(["d1", "da"].index(law) + 50)
    for _ in range(6):
        positions, polygon, V, kappa, still = random_case(rng, n_max=40)
        team = control.team_step(law, positions, polygon, V, kappa, still=still).velocity
        mass, _ = coverage.mass_centroid(positions, polygon)
        nb = coverage.neighbors(positions, polygon)
        mes = [i for i in np.flatnonzero((mass > 0) & ~still)][:8]
        views = []
        for me in mes:
            known = two_hop(nb, int(me)) | {int(me)}
            mapping = {j: positions[j].copy() for j in known}
            held = frozenset(j for j in known if still[j])
            views.append(control.LocalView(int(me), mapping, polygon, V, kappa, still=held))
            one = control.local_step(int(me), mapping, polygon, V, kappa, law=law, still=held)
            error = np.linalg.norm(one.velocity - team[me])
            assert error <= 1e-9 * max(np.linalg.norm(team[me]), scale(polygon, V, kappa))
            assert one.neighbors == frozenset(nb[me])  # still ones included: they bound it
        batch = control.local_steps(views, law=law)
        for view, step in zip(views, batch, strict=True):
            one = control.local_step(
                view.me, view.positions, polygon, V, kappa, law=law, still=view.still
            )
            assert np.linalg.norm(step.velocity - one.velocity) <= 1e-9 * scale(polygon, V, kappa)


def test_a_still_robot_is_refused_as_the_view_owner_and_masks_are_checked() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    here = {1: np.array([0.3, 0.5]), 2: np.array([0.7, 0.5])}
    with pytest.raises(ValueError, match="cannot stand still"):
        control.local_step(1, here, square, np.zeros((4, 2)), 1.0, still=frozenset({1}))
    points = np.array([[0.3, 0.5], [0.7, 0.5]])
    with pytest.raises(ValueError, match="bool array"):
        control.team_step("da", points, square, np.zeros((4, 2)), 1.0, still=np.array([1, 0]))
    with pytest.raises(ValueError, match="every robot"):
        control.team_step("da", points, square, np.zeros((4, 2)), 1.0, still=np.ones(2, bool))
    # e_a is over the moving robots too: of none, it is no 0 m
    with pytest.raises(ValueError, match="every robot"):
        coverage.aggregate_error(points, square, still=np.ones(2, bool))
    none_still = coverage.aggregate_error(points, square, still=np.zeros(2, bool))
    assert none_still == coverage.aggregate_error(points, square) > 0.0


def test_lloyd_steps_leave_a_still_robot_its_cell() -> None:
    """Static S, a still robot at its centre, one robot beside it and eight on a ring: the
    others converge to a CVT around it (e_a of the moving robots -> 0), none nearer to it
    than a third of a metre; with the still robot out of the diagram, the robot beside it
    converges onto it (its centroid, the centre of S, is where the still robot stands)."""
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    ring = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    start = np.vstack([[0.0, 0.0], [0.05, 0.0], 0.7 * np.c_[np.cos(ring), np.sin(ring)]])
    still = np.zeros(len(start), dtype=bool)
    still[0] = True
    nearest, error = {}, {}
    for kept in (True, False):
        positions = start.copy()
        for _ in range(400):
            if kept:
                step = control.team_step("d1", positions, square, 0 * square, 2.0, still=still)
                positions = positions + 0.05 * step.velocity
            else:
                step = control.team_step("d1", positions[1:], square, 0 * square, 2.0)
                positions[1:] += 0.05 * step.velocity
        assert np.array_equal(positions[0], start[0])
        nearest[kept] = float(np.linalg.norm(positions[1:] - positions[0], axis=1).min())
        error[kept] = step.error
    assert nearest[True] > 0.3 and error[True] < 1e-4  # measured 0.393 m, 7e-9 m
    assert nearest[False] < 0.05 and error[False] < 1e-3  # measured 0.006 m
