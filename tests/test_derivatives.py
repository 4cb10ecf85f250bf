"""centroid_jacobian and centroid_rate of covswarm.tvd.coverage against central finite differences.

Measure: ||analytic - FD||_F <= 1e-5 * max(||FD||_F, floor), with floor = 1 for dc/dp
(dimensionless) and the largest vertex speed for dc/dt.

FD is only meaningful where the combinatorial structure of the clipped Voronoi diagram does
not change within the FD step; configurations are skipped by the documented criterion
reference.fd_valid (every cell edge, robot-boundary distance and robot-robot distance
>= 1e-3 diam(S), FD step 1e-6 diam(S)) plus, for robots with an empty cell, that the cell
stays empty and the nearest point of S stays on the same edge / vertex (see
empty_rows_valid). The tests assert that most random configurations pass the criterion so
that the check is not vacuous.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from reference import (
    KINDS,
    SKEW,
    as_cw,
    fd_jacobian,
    fd_rate,
    fd_valid,
    motion,
    nearest_point,
    random_convex_polygon,
    random_robots,
    reference_cells,
    rot,
    scale_of,
)
from shapely.geometry import Polygon

from covswarm.tvd import coverage

TOL = 1e-5
DELTA = 1e-3  # criterion distance, in units of diam(S)
H = 1e-6  # FD step: positions in units of diam(S); time with vertex speeds ~ diam(S)


def empty_rows_valid(positions: np.ndarray, polygon: np.ndarray) -> bool:
    """Robots with an empty reference cell keep it empty and keep their nearest feature.

    Empty stays empty: the unclipped Voronoi region of the robot (intersected with a large
    box) is farther than DELTA diam(S) from S. Same nearest feature: the nearest-point map
    is affine (exactly symmetric differences) over +-DELTA diam(S) along both axes.
    """
    diam = scale_of(polygon)
    S = Polygon(polygon)
    ref = reference_cells(positions, polygon)
    c = polygon.mean(axis=0)
    R = 100.0 * (diam + np.max(np.linalg.norm(positions - c, axis=1)))
    box = shapely.box(c[0] - R, c[1] - R, c[0] + R, c[1] + R)
    for i, cell in enumerate(ref):
        if cell is not None:
            continue
        others = np.delete(positions, i, axis=0)
        region = box
        for q in others:
            m = 0.5 * (positions[i] + q)
            d = (q - positions[i]) / np.linalg.norm(q - positions[i])
            t = np.array([-d[1], d[0]])
            hp = Polygon([m + R * t, m + R * t - 4 * R * d, m - R * t - 4 * R * d, m - R * t])
            region = region.intersection(hp)
        if region.distance(S) < DELTA * diam:
            return False
        c0 = nearest_point(polygon, positions[i])
        for e in np.eye(2):
            step = DELTA * diam * e
            cp = nearest_point(polygon, positions[i] + step)
            cm = nearest_point(polygon, positions[i] - step)
            if np.linalg.norm(cp + cm - 2 * c0) > 1e-9 * diam:
                return False
    return True


def centroids(polygon):
    return lambda p: coverage.mass_centroid(p, polygon)[1]


def rel_err(a: np.ndarray, b: np.ndarray, floor: float) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), floor))


def configurations(seed: int, count: int, nmax: int, outside: float):
    """Random (positions, polygon) pairs passing the FD criterion, and the number skipped."""
    rng = np.random.default_rng(seed)
    out = []
    skipped = 0
    while len(out) < count:
        polygon = random_convex_polygon(rng)
        n = int(rng.integers(1, nmax + 1))
        positions = random_robots(rng, polygon, n, outside_fraction=outside, margin=DELTA)
        if not (fd_valid(positions, polygon, DELTA) and empty_rows_valid(positions, polygon)):
            skipped += 1
            continue
        if rng.random() < 0.5:
            polygon = as_cw(polygon, shift=int(rng.integers(len(polygon))))
        out.append((positions, polygon, rng))
    return out, skipped


@pytest.mark.parametrize("seed", range(4))
def test_jacobian_matches_finite_differences(seed: int) -> None:
    confs, skipped = configurations(3000 + seed, 12, 15, outside=0.15)
    assert skipped <= len(confs), f"FD criterion rejects too much ({skipped})"
    for positions, polygon, _ in confs:
        n = len(positions)
        J = coverage.centroid_jacobian(positions, polygon)
        assert J.shape == (2 * n, 2 * n) and J.dtype == np.float64
        assert np.all(np.isfinite(J))
        Jfd = fd_jacobian(centroids(polygon), positions, H * scale_of(polygon))
        err = rel_err(J, Jfd, 1.0)
        assert err <= TOL, f"n={n}: dc/dp off by {err:.3g}\n{np.round(J - Jfd, 6)}"


@pytest.mark.parametrize("kind", KINDS)
def test_rate_matches_finite_differences(kind: str) -> None:
    confs, skipped = configurations(4000 + KINDS.index(kind), 10, 15, outside=0.15)
    assert skipped <= len(confs), f"FD criterion rejects too much ({skipped})"
    for positions, polygon, rng in confs:
        P, V = motion(kind, polygon, rng)
        rate = coverage.centroid_rate(positions, polygon, V)
        assert rate.shape == (len(positions), 2) and rate.dtype == np.float64
        fd = fd_rate(centroids_at(positions), P, H)
        floor = float(np.max(np.linalg.norm(V, axis=1)))
        err = rel_err(rate, fd, floor)
        assert err <= TOL, f"{kind}: dc/dt off by {err:.3g}\n{rate}\n{fd}"


def centroids_at(positions):
    return lambda polygon: coverage.mass_centroid(positions, polygon)[1]


def test_rate_zero_for_static_polygon() -> None:
    rng = np.random.default_rng(5)
    polygon = random_convex_polygon(rng)
    positions = random_robots(rng, polygon, 20, outside_fraction=0.2)
    rate = coverage.centroid_rate(positions, polygon, np.zeros_like(polygon))
    assert np.all(rate == 0.0) or np.max(np.abs(rate)) <= 1e-12 * scale_of(polygon)


def test_rate_exact_rigid_and_scaling_single_robot() -> None:
    """One robot owns S, so c = centroid(S) and dc/dt is known in closed form."""
    rng = np.random.default_rng(6)
    for _ in range(10):
        polygon = random_convex_polygon(rng)
        p = random_robots(rng, polygon, 1)
        c0 = np.array(Polygon(polygon).centroid.coords[0])
        diam = scale_of(polygon)
        o = rng.normal(size=2) * diam
        v, s, w = rng.normal(size=2), rng.normal(), rng.normal()
        cases = [
            (np.tile(v, (len(polygon), 1)), v),
            (s * (polygon - o), s * (c0 - o)),
            (w * (polygon - o) @ SKEW.T, w * SKEW @ (c0 - o)),
        ]
        for V, expected in cases:
            got = coverage.centroid_rate(p, polygon, V)[0]
            cw, Vcw = as_cw(polygon, V, shift=2)
            got_cw = coverage.centroid_rate(p, cw, Vcw)[0]
            scale = max(np.linalg.norm(expected), np.max(np.linalg.norm(V, axis=1)))
            assert np.linalg.norm(got - expected) <= 1e-9 * scale, (got, expected)
            assert np.linalg.norm(got_cw - expected) <= 1e-9 * scale, (got_cw, expected)


def test_rigid_motion_of_everything_is_consistent() -> None:
    """Moving S rigidly with the robots fixed equals moving the robots the opposite way:
    dc/dt (translation v) = v - J (1 kron v), and the same for rotation about a point."""
    confs, _ = configurations(77, 8, 12, outside=0.0)
    for positions, polygon, rng in confs:
        n = len(positions)
        J = coverage.centroid_jacobian(positions, polygon)
        v = rng.normal(size=2)
        rate = coverage.centroid_rate(positions, polygon, np.tile(v, (len(polygon), 1)))
        expected = np.tile(v, n) - J @ np.tile(v, n)
        assert rel_err(rate.ravel(), expected, np.linalg.norm(v)) <= 1e-9
        o = rng.normal(size=2) * scale_of(polygon)
        w = rng.normal()
        mass, c = coverage.mass_centroid(positions, polygon)
        rate = coverage.centroid_rate(positions, polygon, w * (polygon - o) @ SKEW.T)
        # rotating S and robots together rotates c: w S (c - o) = rate + J (w S (p - o))
        expected = (w * (c - o) @ SKEW.T).ravel() - J @ (w * (positions - o) @ SKEW.T).ravel()
        assert rel_err(rate.ravel(), expected, abs(w) * scale_of(polygon)) <= 1e-9


def test_jacobian_known_closed_form() -> None:
    """Two robots at height 0.3 in the unit square, bisector x = 0.4; by hand from
    eqs. (6)/(7) (Section 2.3): dc_i/dp_k = +-(1/(m_i d)) int_0^1 (q - c_i)(q - p_k)^T dy."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    p = np.array([[0.2, 0.3], [0.6, 0.3]])
    J = coverage.centroid_jacobian(p, square)
    a, b = 1 / (12 * 0.4 * 0.4), 1 / (12 * 0.6 * 0.4)
    expected = np.array(
        [
            [0.25, 0.25, 0.25, -0.25],
            [0.0, a, 0.0, -a],
            [0.25, 0.25, 0.25, -0.25],
            [0.0, -b, 0.0, b],
        ]
    )
    np.testing.assert_allclose(J, expected, atol=1e-12)
    Jfd = fd_jacobian(centroids(square), p, 1e-6)
    np.testing.assert_allclose(Jfd, expected, atol=1e-7)


def test_empty_cell_rows_follow_nearest_point() -> None:
    """Robot 1 far outside S with an empty cell: its centroid is its nearest point of S, so
    its row of dc/dp is the tangent projector near the middle of an edge and 0 facing a
    vertex, and other centroids do not depend on it."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    for far, row in [
        ([0.5, -5.0], np.array([[1.0, 0.0], [0.0, 0.0]])),
        ([-5.0, -5.0], np.zeros((2, 2))),
    ]:
        p = np.array([[0.5, 0.5], far])
        mass, c = coverage.mass_centroid(p, square)
        assert mass[1] == 0
        np.testing.assert_allclose(c[1], nearest_point(square, p[1]), atol=1e-15)
        J = coverage.centroid_jacobian(p, square)
        np.testing.assert_allclose(J[2:, 2:], row, atol=1e-12)
        np.testing.assert_allclose(J[:2, 2:], 0, atol=1e-12)
        np.testing.assert_allclose(J[2:, :2], 0, atol=1e-12)
        # S translating: the nearest point follows the edge (normal component) / vertex
        v = np.array([0.3, -0.7])
        rate = coverage.centroid_rate(p, square, np.tile(v, (4, 1)))
        fd = fd_rate(centroids_at(p), lambda t, v=v: square + t * v, 1e-6)
        np.testing.assert_allclose(rate, fd, atol=1e-8)


def test_rotation_about_a_far_point() -> None:
    """Edges rotate, so the normal boundary speed varies along each edge (the exactness
    claim of the linear-interpolation boundary velocity)."""
    confs, _ = configurations(12, 6, 10, outside=0.0)
    for positions, polygon, _ in confs:
        o = polygon.mean(axis=0) + np.array([3.0, -2.0]) * scale_of(polygon)
        w = 0.7
        V = w * (polygon - o) @ SKEW.T
        rate = coverage.centroid_rate(positions, polygon, V)
        fd = fd_rate(
            centroids_at(positions), lambda t, o=o, P=polygon, w=w: o + (P - o) @ rot(w * t).T, H
        )
        assert rel_err(rate, fd, float(np.max(np.linalg.norm(V, axis=1)))) <= TOL
