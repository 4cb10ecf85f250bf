"""The safety filter's obstacle rows, vectorised over polygons, against the per-polygon
reference covswarm.tvd.geometry.point_polygon_distance_grad and shapely's distances."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from covswarm.tvd.geometry import point_polygon_distance_grad
from covswarm.tvd.safety import obstacle_constraints, polygon_distance_grads


def random_convex(rng: np.random.Generator) -> np.ndarray:
    """A convex CCW polygon of 3..12 vertices: the hull of random points (shapely)."""
    centre = rng.uniform(-2.0, 2.0, 2)
    points = centre + rng.uniform(-0.6, 0.6, (rng.integers(3, 16), 2))
    hull = shapely.convex_hull(shapely.multipoints(points))
    if hull.geom_type != "Polygon" or hull.area < 1e-3:
        return random_convex(rng)
    return np.asarray(shapely.orient_polygons(hull).exterior.coords)[:-1]


@pytest.mark.parametrize("seed", range(20))
def test_vectorised_rows_match_the_reference_per_polygon(seed: int) -> None:
    rng = np.random.default_rng(seed)
    polygons = [random_convex(rng) for _ in range(rng.integers(1, 9))]
    # Points anywhere, and exactly on vertices and edge midpoints (boundary cases).
    probes = list(rng.uniform(-3.0, 3.0, (30, 2)))
    for q in polygons[:2]:
        probes += [q[0], 0.5 * (q[0] + q[1])]
    for p in probes:
        signed, grad = polygon_distance_grads(p, polygons)
        for j, q in enumerate(polygons):
            ref_signed, ref_grad = point_polygon_distance_grad(p, q)
            assert signed[j] == pytest.approx(ref_signed, abs=1e-12)
            assert np.linalg.norm(grad[j]) == pytest.approx(1.0)
            # On the boundary (h = 0 to 1e-17 m) the direction is a corner's tie or the
            # rounding of a vanishing gap, in the reference as here: not compared.
            if abs(signed[j]) > 1e-9:
                np.testing.assert_allclose(grad[j], ref_grad, atol=1e-9)
            shape = shapely.Polygon(q)
            outside = shapely.distance(shape, shapely.Point(p))
            assert max(signed[j], 0.0) == pytest.approx(outside, abs=1e-9)
            if signed[j] < 0.0:  # inside: minus the distance to the boundary
                assert -signed[j] == pytest.approx(
                    shapely.distance(shape.exterior, shapely.Point(p)), abs=1e-9
                )


def test_rows_keep_only_what_is_within_reach() -> None:
    near = np.array([[1.0, -1.0], [2.0, -1.0], [2.0, 1.0], [1.0, 1.0]])  # 1 m away
    far = near + [3.0, 0.0]
    A, b = obstacle_constraints(np.zeros(2), [near, far], None, 0.09, 5.0, reach=1.5)
    np.testing.assert_allclose(A, [[1.0, 0.0]])  # -grad: moving toward +x closes the gap
    np.testing.assert_allclose(b, [5.0 * (1.0 - 0.09)])
    A, b = obstacle_constraints(np.zeros(2), [], (-1.0, 1.0, -2.0, 2.0), 0.09, 5.0, reach=1.5)
    np.testing.assert_allclose(A, [[-1.0, 0.0], [1.0, 0.0]])


def test_bench_times_the_filter_with_obstacles() -> None:
    from covswarm.deploy.bench import bench_world, make_layout, time_safety_filter

    layout = make_layout(30, "random", 0)
    world = bench_world(layout, 40)
    side = float(layout.polygon[:, 0].max())
    assert len(world.obstacles) == 40 and world.workspace == (0.0, side, 0.0, side)
    row = time_safety_filter(layout, 10, obstacles=40)
    assert row["safety_walls_p50_us"] > 0.0 and row["obstacles_nearby_mean"] > 0.0
    assert "safety_walls_p50_us" not in time_safety_filter(layout, 10)
