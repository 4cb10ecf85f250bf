"""The accuracy contract of covswarm.tvd.density's closed forms, for any cell size.

Contract (tvd/density.py docstring, docs/density.md): masses within 1e-6 relative and centroids
within 1e-6 of the cell size of an independent reference, dc/dp and dc/dt within 1e-6 of
central finite differences, from bumps 500 times narrower than a cell to 1e4 times wider.
References: scipy dblquad over fans of triangles of shapely-clipped cells; the first
implementation's subdivided Gauss-Legendre quadrature (tests/density_reference.py, accurate
to 1e-10 while a cell is under 24 deviations wide); central finite differences in positions
and in time while the domain moves and the bumps move, grow and turn (DensityPath).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from density_reference import QuadratureDensity
from reference import (
    fd_jacobian,
    fd_valid,
    motion,
    random_convex_polygon,
    random_cov,
    random_robots,
    reference_cells,
    scale_of,
)
from scipy import integrate
from shapely.geometry import Point
from shapely.geometry.polygon import orient
from shapely.ops import nearest_points

from covswarm.mission.motion import DensityPath
from covswarm.tvd import coverage
from covswarm.tvd.density import Density

CONTRACT = 1e-6


def layout(seed: int, robots: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A random polygon, robots whose cells suit finite differences, and a cell size."""
    rng = np.random.default_rng(seed)
    while True:
        polygon = random_convex_polygon(rng, scale=1.0, offset=1.0)
        positions = random_robots(rng, polygon, robots)
        if fd_valid(positions, polygon):
            cell = scale_of(polygon) / np.sqrt(robots)
            return polygon, positions, cell


def bumps_of_width(
    rng: np.random.Generator, polygon: np.ndarray, sigma: float, moving: bool = True
) -> DensityPath:
    """Two bumps of deviation ~sigma inside S (one a shallow hole), drifting, growing,
    fading and turning when ``moving``."""
    inside = polygon.mean(axis=0) + 0.25 * (polygon[:2] - polygon.mean(axis=0))
    rate = float(moving)
    base = Density(
        floor=0.2,
        means=inside + rng.normal(size=(2, 2)) * 0.1 * sigma,
        covariances=[random_cov(rng, sigma), random_cov(rng, 1.3 * sigma)],
        weights=[5.0, -0.15],
        mean_rates=rate * rng.normal(size=(2, 2)) * scale_of(polygon),
        covariance_rates=rate * np.array([random_cov(rng, 0.3 * sigma), np.eye(2) * sigma**2]),
        weight_rates=[rate * 2.0, rate * 0.05],
    )
    return DensityPath(base, np.array([0.7, -1.1]) * rate)


def scalar_phi(density: Density):
    """phi(q) for one point q (2,), written out from the model (floor + w exp(-x^T P x / 2)),
    independent of the library's evaluation and fast enough for dblquad."""
    bumps = [
        (float(w), float(mx), float(my), float(p[0, 0]), float(p[0, 1]), float(p[1, 1]))
        for w, (mx, my), p in zip(
            density.weights, density.means, np.linalg.inv(density.covariances), strict=True
        )
    ]
    floor = density.floor

    def phi(q: np.ndarray) -> float:
        x, y, total = float(q[0]), float(q[1]), floor
        for w, mx, my, pxx, pxy, pyy in bumps:
            dx, dy = x - mx, y - my
            total += w * math.exp(-0.5 * (pxx * dx * dx + 2.0 * pxy * dx * dy + pyy * dy * dy))
        return total

    return phi


def fan_integral(vertices: np.ndarray, origin: np.ndarray, f) -> float:
    """int of f(q) (q: (2,)) over a convex polygon by dblquad on a fan of triangles from
    ``origin`` (a point of the polygon): a narrow bump's peak at ``origin`` sits at every
    triangle's corner, where QUADPACK's bisection finds it."""
    total = 0.0
    ring = np.vstack([vertices, vertices[:1]])
    for a, b in zip(ring[:-1], ring[1:], strict=True):
        jac = (a - origin)[0] * (b - origin)[1] - (a - origin)[1] * (b - origin)[0]
        if abs(jac) <= 1e-14 * np.abs(vertices).max() ** 2:
            continue
        value = integrate.dblquad(
            lambda v, u, a=a, b=b: f(origin + u * (a - origin) + v * (b - origin)),
            0.0,
            1.0,
            0.0,
            lambda u: 1.0 - u,
            epsabs=0.0,
            epsrel=1e-10,
        )[0]
        total += jac * value
    return total


@pytest.mark.parametrize("cell_over_sigma", [300.0, 3.0, 0.05, 1e-3])
def test_mass_centroid_against_dblquad(cell_over_sigma: float) -> None:
    """Random cells of a random domain, bumps from 500x narrower to 1000x wider than a cell."""
    polygon, positions, cell = layout(int(cell_over_sigma * 7) % 97, 3)
    density = bumps_of_width(np.random.default_rng(3), polygon, cell / cell_over_sigma)(0.0)
    mass, centroid = coverage.mass_centroid(positions, polygon, density)
    for i, shape in enumerate(reference_cells(positions, polygon)):
        vertices = np.asarray(orient(shape).exterior.coords)[:-1]  # counter-clockwise
        # Fan from the cell's point nearest the narrower bump's mean.
        origin = np.asarray(nearest_points(shape, Point(density.means[0]))[0].coords[0])
        m = fan_integral(vertices, origin, lambda q: density.phi(q))
        c = [
            fan_integral(vertices, origin, lambda q, k=k: q[k] * density.phi(q)) / m for k in (0, 1)
        ]
        assert abs(mass[i] - m) <= CONTRACT * 1e-3 * m
        assert np.linalg.norm(centroid[i] - c) <= CONTRACT * 1e-3 * np.sqrt(shape.area)


@pytest.mark.parametrize("cell_over_sigma", [200.0, 20.0, 1.0, 0.05, 1e-3])
def test_derivatives_against_finite_differences(cell_over_sigma: float) -> None:
    """dc/dp in positions; dc/dt while S moves and the bumps drift, grow, fade and turn."""
    polygon, positions, cell = layout(40 + int(cell_over_sigma * 3) % 50, 5)
    rng = np.random.default_rng(5)
    path = bumps_of_width(rng, polygon, cell / cell_over_sigma)
    density = path(0.0)
    h = 1e-7 * scale_of(polygon)
    jacobian = coverage.centroid_jacobian(positions, polygon, density)
    fd = fd_jacobian(lambda p: coverage.mass_centroid(p, polygon, density)[1], positions, h)
    assert np.abs(jacobian - fd).max() <= CONTRACT * max(np.abs(fd).max(), 1.0)
    for kind in ("translate", "rotate", "combo", "vertexwise"):
        moving, velocity = motion(kind, polygon, rng)
        rate = coverage.centroid_rate(positions, polygon, velocity, density)
        dt = 1e-7
        ahead, behind = (
            coverage.mass_centroid(positions, moving(t), path(t))[1] for t in (dt, -dt)
        )
        fd_rate = (ahead - behind) / (2 * dt)
        assert np.abs(rate - fd_rate).max() <= CONTRACT * max(np.abs(fd_rate).max(), 1.0), kind


@pytest.mark.parametrize("seed", range(6))
def test_closed_forms_equal_the_reference_quadrature(seed: int) -> None:
    """Masses, centroids, dc/dp and dc/dt against the first implementation's quadrature where
    that is accurate (cells a few deviations wide: 1e-8 on elongated bumps, where dblquad
    agrees with the closed forms to 1e-14), random layouts and moving bumps; and cells 1e-4
    deviations wide, where the closed forms hand over to the Gauss rule."""
    rng = np.random.default_rng(100 + seed)
    polygon = random_convex_polygon(rng, scale=float(10 ** rng.uniform(-1, 1)), offset=2.0)
    positions = random_robots(rng, polygon, int(rng.integers(2, 9)), outside_fraction=0.1)
    velocity = motion("combo", polygon, rng)[1]
    cell = scale_of(polygon) / np.sqrt(len(positions))
    for sigma in (cell / 8.0, cell * 3.0, cell * 1e4):
        density = bumps_of_width(rng, polygon, sigma)(0.0)
        reference = QuadratureDensity(density)
        mass, centroid = coverage.mass_centroid(positions, polygon, density)
        mass_q, centroid_q = coverage.mass_centroid(positions, polygon, reference)
        assert np.allclose(mass, mass_q, rtol=1e-7, atol=0.0)
        assert np.abs(centroid - centroid_q).max() <= 1e-7 * cell
        jacobian = coverage.centroid_jacobian(positions, polygon, density)
        jacobian_q = coverage.centroid_jacobian(positions, polygon, reference)
        assert np.abs(jacobian - jacobian_q).max() <= 1e-7 * max(np.abs(jacobian_q).max(), 1.0)
        rate = coverage.centroid_rate(positions, polygon, velocity, density)
        rate_q = coverage.centroid_rate(positions, polygon, velocity, reference)
        assert np.abs(rate - rate_q).max() <= 1e-7 * np.abs(rate_q).max()


def test_a_far_bump_is_left_out_and_a_near_one_is_not() -> None:
    """A bump 40 deviations from S changes nothing (it is skipped); the same bump moved to
    where it touches one cell counts for that cell exactly as the reference says."""
    polygon, positions, cell = layout(7, 6)
    far = Density(0.5, [polygon.mean(axis=0) + [40.0 * cell, 0.0]], [np.eye(2) * cell**2], [9.0])
    flat = Density(0.5, np.zeros((0, 2)), [], [])
    assert np.array_equal(
        coverage.centroid_jacobian(positions, polygon, far),
        coverage.centroid_jacobian(positions, polygon, flat),
    )
    corner = polygon[0] + 0.5 * (polygon[1] - polygon[0])
    near = Density(0.5, [corner], [np.eye(2) * (0.2 * cell) ** 2], [9.0], [[cell, 0.0]])
    velocity = motion("rotate", polygon, np.random.default_rng(2))[1]
    got = coverage.centroid_rate(positions, polygon, velocity, near)
    expected = coverage.centroid_rate(positions, polygon, velocity, QuadratureDensity(near))
    assert np.abs(got - expected).max() <= 1e-7 * np.abs(expected).max()


def test_reused_integrals_are_never_stale() -> None:
    """One density over alternating layouts gives what a fresh density gives each time."""
    rng = np.random.default_rng(9)
    polygon = random_convex_polygon(rng, scale=1.0)
    layouts = [random_robots(rng, polygon, 5) for _ in range(2)]
    shared = bumps_of_width(rng, polygon, 0.3 * scale_of(polygon))(0.0)
    for positions in layouts + layouts[:1]:
        fresh = Density.from_dict(shared.to_dict())
        for function in (coverage.mass_centroid, coverage.centroid_jacobian):
            got = function(positions, polygon, shared)
            expected = function(positions, polygon, fresh)
            pairs = zip(got, expected, strict=True) if isinstance(got, tuple) else [(got, expected)]
            assert all(np.array_equal(a, b) for a, b in pairs)


@pytest.mark.parametrize("mean", [[0.0, 0.0], [0.5, 0.3], [0.5, 0.5], [0.25, 0.5]])
def test_a_bump_centred_on_a_vertex_an_edge_or_a_robot(mean: list[float]) -> None:
    """The mean on a corner of S, on a bisector, on a cell vertex, on a robot: the edge
    whose line passes through the mean (h = 0) adds no triangle, and nothing is NaN."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    positions = np.array([[0.25, 0.5], [0.75, 0.5], [0.5, 0.9]])
    velocity = np.array([[0.1, 0.0], [0.2, 0.1], [0.0, 0.1], [-0.1, 0.0]])
    cov, cov_rate = [[0.04, 0.01], [0.01, 0.02]], [[0.01, 0.0], [0.0, 0.02]]
    density = Density(0.5, [mean], [cov], [3.0], [[0.3, 0.1]], [cov_rate], [0.5])
    reference = QuadratureDensity(density)
    for function in (coverage.mass_centroid, coverage.centroid_jacobian):
        got, expected = function(positions, square, density), function(positions, square, reference)
        pairs = zip(got, expected, strict=True) if isinstance(got, tuple) else [(got, expected)]
        for a, b in pairs:
            assert np.all(np.isfinite(a)) and np.abs(a - b).max() <= 1e-8 * np.abs(b).max()
    # dc/dt against fourth-order central differences along the exact (linear) paths of S
    # and of the bump's parameters (the reference quadrature is 2e-9 off at a corner).
    rate = coverage.centroid_rate(positions, square, velocity, density)
    dt = 1e-3

    def centroid(t: float) -> np.ndarray:
        return coverage.mass_centroid(positions, square + t * velocity, density.at(t))[1]

    fd = (8.0 * (centroid(dt) - centroid(-dt)) - centroid(2 * dt) + centroid(-2 * dt)) / (12 * dt)
    assert np.abs(rate - fd).max() <= 1e-8 * np.abs(fd).max()  # the differences' own noise


@pytest.mark.parametrize("distance", [3.0, 6.0, 8.0])
@pytest.mark.parametrize("cell_over_sigma", [0.15, 1.0])
def test_a_cell_in_the_far_tail_of_a_bump_with_a_tiny_floor(
    distance: float, cell_over_sigma: float
) -> None:
    """A cell 3 to 8 deviations from the mean, the floor 1e-12 of the peak: the bump's tail
    is the cell's whole mass, far below the rounding of the O(1) terms whose sums the closed
    forms are (the angle a cell subtends, Owen's T near saturation), which they avoid."""
    eps = cell_over_sigma
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) * eps + [distance, 0.3]
    positions = square.mean(axis=0) + np.array([[0.1, -0.05], [0.3, 0.2]]) * eps
    cov = [[1.0, 0.3], [0.3, 0.8]]
    density = Density(1e-12, [[0.0, 0.0]], [cov], [1.0], [[0.3, -0.2]], [np.eye(2) * 0.1])
    reference = QuadratureDensity(density)  # exact here: the tail is smooth across the cell
    mass, centroid = coverage.mass_centroid(positions, square, density)
    mass_q, centroid_q = coverage.mass_centroid(positions, square, reference)
    assert np.allclose(mass, mass_q, rtol=1e-9, atol=0.0)
    # Measured at worst 3.5e-9 of the cell (6 deviations out, a cell 0.15 deviations wide).
    assert np.abs(centroid - centroid_q).max() <= 1e-7 * eps
    velocity = np.array([[0.1, 0.0], [0.2, 0.1], [0.0, 0.1], [-0.1, 0.0]])
    rate = coverage.centroid_rate(positions, square, velocity, density)
    expected = coverage.centroid_rate(positions, square, velocity, reference)
    speed = max(np.abs(velocity).max(), np.abs(density.mean_rates).max())
    assert np.abs(rate - expected).max() <= CONTRACT * speed
