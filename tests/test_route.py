"""RouteMotion: exact vertex velocities, C2 chaining, convexity, the speed limit."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from covswarm.world.route import RouteMotion, centroid, pairing, smoothstep, width

SQUARE = np.array([[-1.0, -0.5], [1.0, -0.5], [1.0, 0.5], [-1.0, 0.5]])
HEXAGON = np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 7)[:-1] + 0.3])


def _route(rng: np.random.Generator, morph: bool) -> RouteMotion:
    polygons = [SQUARE]
    for _ in range(4):
        polygons.append(rng.uniform(-3, 3, 2) + rng.uniform(0.3, 1.5) * SQUARE)
    if morph:
        polygons.append(polygons[-1].mean(axis=0) + 0.7 * HEXAGON)
    holds = rng.uniform(0.0, 2.0, len(polygons)).tolist()
    return RouteMotion.timed(polygons, 0.4, holds, t0=rng.uniform(0, 3))


@pytest.mark.parametrize("seed", range(6))
def test_velocities_are_the_derivative_of_the_vertices(seed: int) -> None:
    rng = np.random.default_rng(seed)
    route = _route(rng, morph=seed % 2 == 1)
    h = 1e-6
    for t in rng.uniform(route.t0, route.end, 40):
        vertices, velocities = route(t)
        ahead, back = route(t + h)[0], route(t - h)[0]
        if ahead.shape != vertices.shape or back.shape != vertices.shape:
            continue  # a merged vertex on one side (morph ends): not comparable
        np.testing.assert_allclose(velocities, (ahead - back) / (2 * h), atol=1e-6)


@pytest.mark.parametrize("seed", range(4))
def test_chaining_is_continuous_and_stops_at_waypoints(seed: int) -> None:
    rng = np.random.default_rng(seed)
    route = _route(rng, morph=True)
    for i, arrive in enumerate(route.arrivals):
        for t in (arrive - 1e-7, arrive, arrive + 1e-7):
            vertices, velocities = route(t)
            assert np.abs(velocities).max() < 1e-8  # s' = 30 u^2 (1 - u)^2, ~0 there
            target = route.polygons[i + 1]
            assert (
                shapely.Polygon(vertices).symmetric_difference(shapely.Polygon(target)).area < 1e-9
            )
    # Acceleration (central second difference of the velocities) vanishes at the joints.
    for start in route.starts:
        h = 1e-4
        accel = (route(start + h)[1] - route(start - h)[1]) / (2 * h)
        assert np.abs(accel).max() < 1e-2


@pytest.mark.parametrize("seed", range(4))
def test_convex_and_within_the_speed_limit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    route = _route(rng, morph=True)
    peak = 0.0
    for t in np.linspace(0.0, route.end + 1.0, 3000):
        vertices, velocities = route(t)
        poly = shapely.Polygon(vertices)
        assert poly.is_valid
        assert abs(poly.convex_hull.area - poly.area) < 1e-9
        assert shapely.Polygon(vertices).exterior.is_ccw
        peak = max(peak, float(np.linalg.norm(velocities, axis=1).max()))
    assert peak <= 0.4 + 1e-9
    assert peak > 0.39  # the limit is reached, not undershot
    assert route.peak_speed() == pytest.approx(0.4)


def test_morph_pairing_is_the_minkowski_combination() -> None:
    a, b = SQUARE, 0.8 * HEXAGON + [2.0, 1.0]
    pairs = pairing(a, b)
    for s in (0.2, 0.5, 0.9):
        ours = shapely.Polygon((1 - s) * a[pairs[:, 0]] + s * b[pairs[:, 1]])
        points = ((1 - s) * a[:, None, :] + s * b[None, :, :]).reshape(-1, 2)
        reference = shapely.MultiPoint(points).convex_hull
        assert ours.symmetric_difference(reference).area < 1e-9


def test_geometry_helpers_against_shapely() -> None:
    shifted = HEXAGON * [1.0, 0.6] + [0.3, -2.0]
    poly = shapely.Polygon(shifted)
    np.testing.assert_allclose(centroid(shifted), [poly.centroid.x, poly.centroid.y])
    assert width(SQUARE) == pytest.approx(1.0)
    assert smoothstep(0.5) == (0.5, pytest.approx(1.875))


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="spans"):
        RouteMotion((SQUARE, SQUARE + 1), (), (0.0, 0.0))
    with pytest.raises(ValueError, match="waypoint 1"):
        RouteMotion((SQUARE, np.array([[0, 0], [1, 1], [2, 2]])), (1.0,), (0.0, 0.0))
    with pytest.raises(ValueError, match="positive"):
        RouteMotion((SQUARE, SQUARE + 1), (0.0,), (0.0, 0.0))
    with pytest.raises(ValueError, match="max_speed"):
        RouteMotion.timed([SQUARE, SQUARE + 1], float("nan"))
    with pytest.raises(ValueError, match="scenario-file form"):
        RouteMotion.timed([SQUARE, SQUARE + 1], 1.0).to_toml()
