"""tvd.geometry against shapely on random convex polygons, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from shapely.geometry import Point, Polygon

from covswarm.tvd.geometry import (
    area,
    clip_convex,
    nearest_points,
    point_polygon_distance_grad,
    polygon_distance,
    polygons_intersect,
    validate_convex,
)


def random_convex(rng: np.random.Generator, centre=(0.0, 0.0), size=1.0) -> np.ndarray:
    pts = rng.uniform(-size, size, size=(rng.integers(3, 12), 2)) + np.asarray(centre)
    hull = ConvexHull(pts)
    return validate_convex(pts[hull.vertices])


def test_validate_accepts_ccw_and_reorients_clockwise() -> None:
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    got = validate_convex(square)
    assert got.dtype == float and got.shape == (4, 2)
    np.testing.assert_array_equal(got, np.array(square, dtype=float))
    cw = validate_convex(square[::-1])
    assert Polygon(cw).exterior.is_ccw
    assert area(cw) == pytest.approx(1.0)


def test_validate_drops_collinear_and_repeated_vertices() -> None:
    got = validate_convex([[0, 0], [0.5, 0], [1, 0], [1, 0], [1, 1], [0, 1]])
    assert len(got) == 4
    assert Polygon(got).equals(Polygon([[0, 0], [1, 0], [1, 1], [0, 1]]))


@pytest.mark.parametrize(
    ("vertices", "reason"),
    [
        ([[0, 0], [1, 0]], "at least 3"),
        ([[0, 0], [1, 0], [float("nan"), 1]], "finite"),
        ([[0, 0], [1, 0], [float("inf"), 1]], "finite"),
        ([[0, 0], [1, 1], [2, 2]], "zero area"),
        ([[0, 0], [0, 0], [0, 0]], "zero area"),
        ([[0, 0], [2, 0], [1, 0.2], [2, 2], [0, 2]], "not convex"),
        # a pentagram: every corner turns left, yet the outline winds twice
        ([[np.cos(a), np.sin(a)] for a in np.arange(5) * 4 * np.pi / 5 + 0.1], "not convex"),
        ([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 2]], "not convex"),
        ("abc", "vertices"),
        ([[0, 0, 0], [1, 0, 0], [1, 1, 0]], "pairs"),
        ([[0, 0], [1, "x"], [1, 1]], "numbers"),
    ],
)
def test_validate_refuses_with_the_reason(vertices, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        validate_convex(vertices)


def test_random_hulls_validate_as_shapely_polygons() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        poly = random_convex(rng)
        shp = Polygon(poly)
        assert shp.is_valid and shp.exterior.is_ccw
        assert shp.convex_hull.area == pytest.approx(shp.area, rel=1e-9)
        assert area(poly) == pytest.approx(shp.area, rel=1e-12)


def test_nearest_points_match_shapely() -> None:
    rng = np.random.default_rng(2)
    for _ in range(50):
        poly = random_convex(rng)
        shp = Polygon(poly)
        pts = rng.uniform(-2, 2, size=(40, 2))
        nearest, dist, inside = nearest_points(pts, poly)
        for p, q, d, ins in zip(pts, nearest, dist, inside, strict=True):
            assert d == pytest.approx(shp.distance(Point(p)), abs=1e-12)
            assert ins == shp.covers(Point(p)) or d < 1e-12
            assert shp.distance(Point(q)) < 1e-12
            assert np.linalg.norm(p - q) == pytest.approx(d, abs=1e-12)


def test_nearest_points_on_the_boundary_and_at_vertices() -> None:
    square = validate_convex([[0, 0], [1, 0], [1, 1], [0, 1]])
    pts = np.array([[0.5, 0.0], [1.0, 1.0], [0.0, 0.3], [2.0, 2.0], [0.5, -1.0]])
    nearest, dist, inside = nearest_points(pts, square)
    np.testing.assert_array_equal(inside, [True, True, True, False, False])
    np.testing.assert_allclose(dist, [0, 0, 0, np.sqrt(2), 1.0])
    np.testing.assert_allclose(nearest[3:], [[1, 1], [0.5, 0]])


def test_signed_distance_gradient_matches_central_differences() -> None:
    rng = np.random.default_rng(3)
    step = 1e-6
    checked = 0
    for _ in range(40):
        poly = random_convex(rng)
        shp = Polygon(poly)
        for p in rng.uniform(-2, 2, size=(20, 2)):
            h, grad = point_polygon_distance_grad(p, poly)
            signed = shp.exterior.distance(Point(p)) * (-1 if shp.contains(Point(p)) else 1)
            assert h == pytest.approx(signed, abs=1e-12)
            assert np.linalg.norm(grad) == pytest.approx(1.0)
            fd = np.array(
                [
                    point_polygon_distance_grad(p + step * e, poly)[0]
                    - point_polygon_distance_grad(p - step * e, poly)[0]
                    for e in np.eye(2)
                ]
            ) / (2 * step)
            # where the nearest feature changes within the step the difference quotient is
            # not a derivative; those points are rare and skipped
            if abs(np.linalg.norm(fd) - 1.0) < 1e-6:
                np.testing.assert_allclose(grad, fd, atol=1e-6)
                checked += 1
    assert checked > 700


def test_signed_distance_on_boundary_and_inside() -> None:
    square = validate_convex([[0, 0], [2, 0], [2, 2], [0, 2]])
    h, g = point_polygon_distance_grad(np.array([1.0, 0.0]), square)
    assert h == 0.0
    np.testing.assert_allclose(g, [0, -1])
    h, g = point_polygon_distance_grad(np.array([1.8, 1.0]), square)
    assert h == pytest.approx(-0.2)
    np.testing.assert_allclose(g, [1, 0])
    h, g = point_polygon_distance_grad(np.array([3.0, 1.0]), square)
    assert h == pytest.approx(1.0)
    np.testing.assert_allclose(g, [1, 0])


def test_intersection_distance_and_clip_match_shapely() -> None:
    rng = np.random.default_rng(4)
    hits = misses = 0
    for _ in range(400):
        a = random_convex(rng)
        b = random_convex(rng, centre=rng.uniform(-2.5, 2.5, 2))
        sa, sb = Polygon(a), Polygon(b)
        meets = sa.intersects(sb)
        assert polygons_intersect(a, b) == meets
        assert polygon_distance(a, b) == pytest.approx(sa.distance(sb), abs=1e-12)
        clip = clip_convex(a, b)
        assert area(clip) == pytest.approx(sa.intersection(sb).area, abs=1e-12)
        if area(clip) > 1e-9:
            assert Polygon(clip).symmetric_difference(sa.intersection(sb)).area < 1e-9
        hits += meets
        misses += not meets
    assert hits > 50 and misses > 50


def test_touching_counts_and_tolerance_widens() -> None:
    a = validate_convex([[0, 0], [1, 0], [1, 1], [0, 1]])
    touching = a + [1.0, 0.0]
    assert polygons_intersect(a, touching)
    assert polygon_distance(a, touching) == 0.0
    apart = a + [1.01, 0.0]
    assert not polygons_intersect(a, apart)
    assert polygons_intersect(a, apart, tolerance=0.02)
    assert polygon_distance(a, apart) == pytest.approx(0.01)
    assert clip_convex(a, a + [5.0, 0.0]).shape == (0, 2)
    assert area(clip_convex(a, touching)) == 0.0
    np.testing.assert_allclose(area(clip_convex(a, a + 0.5)), 0.25)
