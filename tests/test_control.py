"""TVD-C, TVD-D1 and the local step of covswarm.tvd.control against dense formulas built here.

r = kappa (c - p) + dc/dt (no dc/dt when feedforward=False), with c, dc/dp, dc/dt from
covswarm.tvd.coverage (verified independently in test_coverage_reference / test_derivatives).
A robot with an empty cell (mass 0) heads for the centroid c_S of the whole of S, with
dc_S/dt as feedforward: its row of the control matrix is dropped (pdot_i = r_i), as
documented in agent/control.py. c_S comes from shapely here; dc_S/dt is the rate of a lone
robot's cell (which is S), verified in test_derivatives.

Documented guards (agent/control.py) are part of what is checked, not hidden:
- TVD-D1 row i whose speed exceeds A * max(|r_j|, j in {i} u N(i)) is rescaled to that
  speed, direction kept (A = control.MAX_AMPLIFICATION);
- TVD-C returns the dense solution unless it is non-finite or some speed exceeds
  A * max|r|, in which case it returns the guarded TVD-D1 velocities.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference import (
    SKEW,
    as_cw,
    motion,
    random_convex_polygon,
    random_robots,
    scale_of,
    two_hop,
)
from tvd_checks import pieces

from covswarm.tvd import control, coverage

A = control.MAX_AMPLIFICATION  # a renamed constant fails here, never turns into inf


def d1_reference(positions, polygon, V, kappa, feedforward=True):
    r, J, nb = pieces(positions, polygon, V, kappa, feedforward)
    raw = (r.ravel() + J @ r.ravel()).reshape(-1, 2)
    out = raw.copy()
    speeds = np.linalg.norm(r, axis=1)
    for i in range(len(positions)):
        bound = A * max(speeds[[i, *nb[i]]])
        s = np.linalg.norm(raw[i])
        if s > bound:
            out[i] = raw[i] * bound / s
    return out, raw, r


def c_reference(positions, polygon, V, kappa, feedforward=True):
    r, J, _ = pieces(positions, polygon, V, kappa, feedforward)
    M = np.eye(J.shape[0]) - J
    sol = np.linalg.solve(M, r.ravel()).reshape(-1, 2)
    return sol, r, np.linalg.cond(M)


def random_case(rng, nmax=30, outside=0.1):
    polygon = random_convex_polygon(rng)
    n = int(rng.integers(1, nmax + 1))
    positions = random_robots(rng, polygon, n, outside_fraction=outside)
    kind = ["translate", "scale", "rotate", "combo", "affine", "vertexwise"][rng.integers(6)]
    _, V = motion(kind, polygon, rng)
    if rng.random() < 0.5:
        polygon, V = as_cw(polygon, V, shift=int(rng.integers(len(polygon))))
    kappa = float(10 ** rng.uniform(-1, 1))
    return positions, polygon, V, kappa


def close(a, b, scale, rel=1e-9):
    return np.linalg.norm(a - b) <= rel * max(np.linalg.norm(b), scale)


@pytest.mark.parametrize("feedforward", [True, False])
def test_tvd_d1_formula(feedforward: bool) -> None:
    rng = np.random.default_rng(10 + feedforward)
    rescaled = 0
    for _ in range(25):
        positions, polygon, V, kappa = random_case(rng)
        got = control.tvd_d1(positions, polygon, V, kappa, feedforward=feedforward)
        assert got.shape == positions.shape and got.dtype == np.float64
        expected, raw, r = d1_reference(positions, polygon, V, kappa, feedforward)
        rescaled += int(np.any(expected != raw))
        scale = kappa * scale_of(polygon) + np.max(np.abs(V))
        assert close(got, expected, scale), np.c_[got, expected]
    assert rescaled < 25  # the unguarded formula itself is exercised


@pytest.mark.parametrize("feedforward", [True, False])
def test_tvd_c_dense_solve(feedforward: bool) -> None:
    rng = np.random.default_rng(20 + feedforward)
    solved = 0
    for _ in range(25):
        positions, polygon, V, kappa = random_case(rng)
        got = control.tvd_c(positions, polygon, V, kappa, feedforward=feedforward, damping=0.0)
        assert got.shape == positions.shape and np.all(np.isfinite(got))
        sol, r, cond = c_reference(positions, polygon, V, kappa, feedforward)
        rmax = np.max(np.linalg.norm(r, axis=1))
        speeds = np.linalg.norm(sol, axis=1)
        if np.all(np.isfinite(sol)) and np.all(speeds <= 0.99 * A * rmax) and cond < 1e8:
            solved += 1
            # residual of the linear system and agreement with the dense solve
            assert close(got, sol, rmax, rel=1e-12 * max(cond, 1e3)), (cond, got, sol)
        elif not np.all(speeds <= 1.01 * A * rmax):
            guarded, _, _ = d1_reference(positions, polygon, V, kappa, feedforward)
            assert close(got, guarded, rmax, rel=1e-9)
    assert solved >= 10


def test_feedforward_false_drops_rate() -> None:
    rng = np.random.default_rng(3)
    positions, polygon, V, kappa = random_case(rng, nmax=15)
    a = control.tvd_d1(positions, polygon, V, kappa, feedforward=False)
    b = control.tvd_d1(positions, polygon, np.zeros_like(V), kappa, feedforward=True)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * kappa * scale_of(polygon))
    for damping in (0.0, control.DAMPING):
        a = control.tvd_c(positions, polygon, V, kappa, feedforward=False, damping=damping)
        b = control.tvd_c(positions, polygon, 0 * V, kappa, feedforward=True, damping=damping)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * kappa * scale_of(polygon))


def test_cvt_is_a_fixed_point_of_static_coverage() -> None:
    """At a CVT of a static S both laws give zero velocity (p = c, dc/dt = 0)."""
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    g = np.array([[x + 0.5, y + 0.5] for y in range(2) for x in range(2)])
    for law in (control.tvd_c, control.tvd_d1):
        v = law(g, square, np.zeros_like(square), 1.0)
        np.testing.assert_allclose(v, 0, atol=1e-12)


def ids_for(style: str, n: int) -> list:
    """n distinct ids."""
    if style == "int":
        return list(range(n))
    if style == "str":
        return [f"robot-{n - i:03d}" for i in range(n)]  # sorted order != index order
    if style == "tuple":
        return [("kh4", 100 - i) for i in range(n)]
    return [1000 + 13 * (n - i) for i in range(n)]


@pytest.mark.parametrize("style", ["int", "str", "tuple", "sparse-int"])
@pytest.mark.parametrize("feedforward", [True, False])
def test_local_velocity_equals_team_row(style: str, feedforward: bool) -> None:
    rng = np.random.default_rng(
        ["int", "str", "tuple", "sparse-int"].index(style) * 2 + feedforward
    )
    for _ in range(4):
        positions, polygon, V, kappa = random_case(rng, nmax=40, outside=0.1)
        n = len(positions)
        team = control.tvd_d1(positions, polygon, V, kappa, feedforward=feedforward)
        mass, cen = coverage.mass_centroid(positions, polygon)
        nb = coverage.neighbors(positions, polygon)
        ids = ids_for(style, n)
        far = polygon.mean(axis=0) + 50 * scale_of(polygon) * rng.normal(size=(3, 2))
        scale = kappa * scale_of(polygon) + np.max(np.abs(V))
        owners = np.flatnonzero(mass > 0)  # empty cells: see the test below
        for me in rng.choice(owners, size=min(len(owners), 8), replace=False):
            known = two_hop(nb, int(me))
            extra = rng.choice(n, size=min(n, 3), replace=False)
            known |= {int(e) for e in extra}
            mapping = {ids[j]: positions[j].copy() for j in known}
            for k, q in enumerate(far):
                mapping[f"stranger-{k}"] = q
            keys = list(mapping)
            rng.shuffle(keys)
            mapping = {k: mapping[k] for k in keys}
            step = control.local_step(ids[me], mapping, polygon, V, kappa, feedforward)
            v = control.local_velocity(ids[me], mapping, polygon, V, kappa, feedforward)
            assert v.shape == (2,) and np.all(np.isfinite(v))
            np.testing.assert_array_equal(v, step.velocity)
            assert close(v, team[me], scale), (v, team[me])
            assert step.neighbors == frozenset(ids[j] for j in nb[me])
            assert abs(step.mass - mass[me]) <= 1e-9 * scale_of(polygon) ** 2
            assert np.linalg.norm(step.centroid - cen[me]) <= 1e-9 * scale_of(polygon)


def test_local_step_requires_me() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(ValueError):
        control.local_step("a", {"b": np.array([0.5, 0.5])}, square, np.zeros((4, 2)), 1.0)


SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


@pytest.mark.parametrize("gap", [0.0, 1e-15, 1e-12, 1e-9, 1e-6])
def test_singular_control_matrix(gap: float) -> None:
    """Two robots at (1/2 -+ d/2, y) in the unit square: dc/dp has the y-block
    (1/(6d)) [[1, -1], [-1, 1]], eigenvalue 1 at d = 1/3, so I - dc/dp is singular."""
    d = 1 / 3 + gap
    for y in (0.5, 0.3):
        p = np.array([[0.5 - d / 2, y], [0.5 + d / 2, y]])
        J = coverage.centroid_jacobian(p, SQUARE)
        assert abs(np.linalg.eigvalsh(J[1::2, 1::2]).max() - 1 / (3 * d)) < 1e-9
        V = np.tile([0.1, 0.2], (4, 1)) + 0.3 * SQUARE @ SKEW.T
        for law in (control.tvd_c, control.tvd_d1):
            for ff in (True, False):
                v = law(p, SQUARE, V, 1.0, feedforward=ff)
                assert np.all(np.isfinite(v)), (law.__name__, v)
                r, _, _ = pieces(p, SQUARE, V, 1.0, ff)
                bound = A * np.max(np.linalg.norm(r, axis=1))
                assert np.all(np.linalg.norm(v, axis=1) <= bound * (1 + 1e-9)), v


@pytest.mark.parametrize("gap", [1e-14, 1e-11, 1e-8, 1e-5])
def test_nearly_coincident_robots_bounded(gap: float) -> None:
    rng = np.random.default_rng(int(-np.log10(gap)))
    polygon = random_convex_polygon(rng)
    positions = random_robots(rng, polygon, 12)
    positions[5] = positions[4] + gap * scale_of(polygon) * np.array([0.6, 0.8])
    V = rng.normal(size=polygon.shape)
    for law in (control.tvd_c, control.tvd_d1):
        v = law(positions, polygon, V, 2.0)
        assert np.all(np.isfinite(v))
        r, _, _ = pieces(positions, polygon, V, 2.0)
        bound = A * np.max(np.linalg.norm(r, axis=1))
        assert np.all(np.linalg.norm(v, axis=1) <= bound * (1 + 1e-9))


def test_local_velocity_dominated_robot_outside_s() -> None:
    """A robot outside S whose cell is empty has no Voronoi neighbours inside S, so its
    two-hop neighbourhood is itself alone. An empty cell aims at the centroid of S, and a
    robot that sees nobody takes S as its cell and heads for its centroid too, so both
    views agree; knowing its planar Voronoi neighbours it matches the team row as well.

    S = unit square, robot 0 at the centre, robot 1 at (0.5, -5): cell 1 is empty,
    pdot_1 = kappa (c_S - p_1) = (0, 5.5).
    """
    p = np.array([[0.5, 0.5], [0.5, -5.0]])
    V = np.zeros((4, 2))
    mass, _ = coverage.mass_centroid(p, SQUARE)
    assert mass[1] == 0
    assert coverage.neighbors(p, SQUARE)[1] == set()
    team = control.tvd_d1(p, SQUARE, V, 1.0)
    np.testing.assert_allclose(team[1], [0.0, 5.5], atol=1e-12)
    alone = control.local_velocity(1, {1: p[1]}, SQUARE, V, 1.0)
    np.testing.assert_allclose(alone, team[1], atol=1e-12)
    planar_neighbors = {0}  # the only other robot borders robot 1's region in the plane
    view = {j: p[j] for j in planar_neighbors | {1}}
    np.testing.assert_allclose(control.local_velocity(1, view, SQUARE, V, 1.0), team[1], atol=1e-9)


def test_local_velocity_dominated_robot_with_whole_team() -> None:
    p = np.array([[0.5, 0.5], [0.5, -5.0], [0.2, 0.9]])
    V = np.tile([0.1, -0.2], (4, 1))
    team = control.tvd_d1(p, SQUARE, V, 1.5)
    for me in range(3):
        v = control.local_velocity(me, dict(enumerate(p)), SQUARE, V, 1.5)
        np.testing.assert_allclose(v, team[me], atol=1e-12)


def test_two_coincident_robots_alone_stay_together_and_a_third_parts_them() -> None:
    # docs/library.md's defined behaviour: the duplicate heads for S's centroid, which is
    # the owner's target too when the owner's cell is all of S.
    from covswarm.tvd import control

    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    for start, apart in (
        ([[0.5, 0.5], [0.5, 0.5]], False),
        ([[0.5, 0.5], [0.5, 0.5], [-0.5, -0.5]], True),
    ):
        p = np.array(start)
        for _ in range(500):
            p = p + 0.02 * control.tvd_da(p, square, np.zeros((4, 2)), kappa=2.0)
        gap = float(np.linalg.norm(p[0] - p[1]))
        assert (gap > 0.1) == apart, (start, gap)
