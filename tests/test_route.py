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


def _turning_route(rng: np.random.Generator) -> tuple[RouteMotion, list[float]]:
    """A route through similarities of SQUARE: each stop shifted, scaled and turned (some
    segments only turn, some only move)."""
    polygons, turns, angle, scale = [SQUARE], [], 0.0, 1.0
    centre = np.zeros(2)
    for k in range(5):
        turn = 0.0 if k == 1 else float(rng.uniform(-2.0, 2.0))
        if k != 2:
            centre = centre + rng.uniform(-2, 2, 2)
        scale *= float(rng.uniform(0.6, 1.5))
        angle += turn
        c, s = np.cos(angle), np.sin(angle)
        polygons.append(centre + scale * SQUARE @ np.array([[c, -s], [s, c]]).T)
        turns.append(turn)
    route = RouteMotion.timed(polygons, 0.4, rng.uniform(0.0, 2.0, 6).tolist(), t0=1.0, turns=turns)
    return route, turns


@pytest.mark.parametrize("seed", range(6))
def test_a_turning_route_has_exact_velocities_and_stays_convex(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    route, turns = _turning_route(rng)
    assert route.turns == pytest.approx(turns)
    h = 1e-6
    for t in rng.uniform(route.t0, route.end, 60):
        vertices, velocities = route(t)
        ahead, back = route(t + h)[0], route(t - h)[0]
        np.testing.assert_allclose(velocities, (ahead - back) / (2 * h), atol=1e-6)
    peak = 0.0
    for t in np.linspace(0.0, route.end + 1.0, 2000):
        vertices, velocities = route(t)
        poly = shapely.Polygon(vertices)
        assert poly.is_valid and poly.exterior.is_ccw
        assert abs(poly.convex_hull.area - poly.area) < 1e-9
        peak = max(peak, float(np.linalg.norm(velocities, axis=1).max()))
    assert peak <= route.peak_speed() + 1e-12 and route.peak_speed() == pytest.approx(0.4)
    for i, arrive in enumerate(route.arrivals):  # S stops exactly at every waypoint
        vertices, velocities = route(arrive)
        np.testing.assert_allclose(vertices, route.polygons[i + 1], atol=1e-12)
        assert np.abs(route(arrive - 1e-7)[1]).max() < 1e-8


def test_the_angle_follows_the_quintic_of_the_centroid() -> None:
    """Turning 90 degrees while moving 2 m: S's first edge points at s(u) * 90 degrees when
    its centroid is s(u) of the way (the same quintic progress)."""
    end = np.array([2.0, 0.0]) + 0.5 * SQUARE @ np.array([[0.0, -1.0], [1.0, 0.0]]).T
    route = RouteMotion((SQUARE, end), (4.0,), (0.0, 0.0), turns=(np.pi / 2,))
    for u in (0.1, 0.35, 0.5, 0.8):
        s, _ = smoothstep(u)
        vertices, _ = route(4.0 * u)
        edge = vertices[1] - vertices[0]
        assert np.arctan2(edge[1], edge[0]) == pytest.approx(s * np.pi / 2)
        np.testing.assert_allclose(centroid(vertices), [2.0 * s, 0.0], atol=1e-12)
        assert shapely.Polygon(vertices).area == pytest.approx(2.0 * (1 - s + 0.5 * s) ** 2)


def test_a_turn_that_does_not_match_its_ends_is_refused() -> None:
    with pytest.raises(ValueError, match="turns by"):
        RouteMotion((SQUARE, SQUARE + 1.0), (1.0,), (0.0, 0.0), turns=(0.3,))
    with pytest.raises(ValueError, match="turns"):
        RouteMotion((SQUARE, SQUARE + 1.0), (1.0,), (0.0, 0.0), turns=(0.0, 0.1))
    with pytest.raises(ValueError, match="vertex count"):
        RouteMotion((SQUARE, HEXAGON), (1.0,), (0.0, 0.0), turns=(0.3,))
