"""world.model against shapely: contact, overlap area, clearance, nearby, and refusals."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from shapely.geometry import Point, Polygon, box
from shapely.ops import unary_union

from covswarm.world.model import Obstacle, World, make_obstacle


def random_convex(rng: np.random.Generator, centre, size: float) -> np.ndarray:
    pts = rng.uniform(-size, size, size=(rng.integers(3, 9), 2)) + np.asarray(centre)
    return pts[ConvexHull(pts).vertices]


def random_world(rng: np.random.Generator, count: int, span: float = 5.0) -> World:
    polys = [random_convex(rng, rng.uniform(-span, span, 2), 0.6) for _ in range(count)]
    return World.from_boxes_and_polygons((-span, span, -span, span), polys)


def shapely_of(world: World) -> list[Polygon]:
    return [Polygon(o.vertices) for o in world.obstacles]


def test_names_boxes_and_polygons() -> None:
    world = World.from_boxes_and_polygons(
        (-2, 2, -1, 1), [[-0.3, 0.3, 0.45, 1.0], [[1, 0], [1.5, 0], [1.2, 0.5]]]
    )
    assert [o.name for o in world.obstacles] == ["obstacle 1", "obstacle 2"]
    assert world.obstacles[0].is_box and not world.obstacles[1].is_box
    assert world.obstacles[0].box == (-0.3, 0.3, 0.45, 1.0)
    assert world.bounds == (-2.0, 2.0, -1.0, 1.0)
    assert World(None, world.obstacles).bounds == (-0.3, 1.5, 0.0, 1.0)
    assert World(None).bounds is None


@pytest.mark.parametrize(
    ("entry", "reason"),
    [
        ([1, 0, 0, 1], "xmin < xmax"),
        ([0, 1, 0, float("nan")], "finite"),
        ([0, 1, True, 2], "booleans"),
        ([[0, 0], [1, 0]], "at least 3"),
        ([[0, 0], [2, 0], [1, 0.2], [2, 2], [0, 2]], "not convex"),
        ([[0, 0], [1, "a"], [1, 1]], "not a pair of numbers"),
        ("wall", "neither a box"),
        (3.0, "neither a box"),
    ],
)
def test_bad_obstacles_are_refused_by_name(entry, reason: str) -> None:
    with pytest.raises(ValueError, match=f"obstacle 1: .*{reason}"):
        make_obstacle("obstacle 1", entry)


def test_workspace_must_be_a_box() -> None:
    with pytest.raises(ValueError, match="xmin < xmax"):
        World((1, 0, 0, 1))


def test_contact_matches_shapely_on_random_worlds() -> None:
    rng = np.random.default_rng(10)
    touched = clear = 0
    for _ in range(30):
        world = random_world(rng, 40)
        shapes = shapely_of(world)
        for _ in range(20):
            s = random_convex(rng, rng.uniform(-5, 5, 2), 1.0)
            tol = float(rng.choice([0.0, 0.05]))
            expect = next(
                (o.name for o, p in zip(world.obstacles, shapes, strict=True)
                 if p.distance(Polygon(s)) <= tol),
                None,
            )  # fmt: skip
            if expect is None and not box(-5, -5, 5, 5).buffer(tol).covers(Polygon(s)):
                expect = "workspace"
            assert world.contact(s, tolerance=tol) == expect
            touched += expect is not None
            clear += expect is None
    assert touched > 50 and clear > 50


def test_contact_workspace_edges() -> None:
    world = World((0, 1, 0, 1))
    assert world.contact(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)) is None
    assert world.contact(np.array([[0, 0], [1.01, 0], [1, 1], [0, 1]], float)) == "workspace"
    assert world.contact(np.array([[0, 0], [1.01, 0], [1, 1], [0, 1]], float), 0.02) is None


def test_overlap_area_is_exact_for_overlapping_obstacles() -> None:
    rng = np.random.default_rng(11)
    for _ in range(40):
        world = random_world(rng, 12, span=1.5)  # crowded: obstacles overlap each other
        union = unary_union(shapely_of(world))
        for _ in range(5):
            s = random_convex(rng, rng.uniform(-1.5, 1.5, 2), 1.2)
            expect = union.intersection(Polygon(s)).area
            assert world.overlap_area(s) == pytest.approx(expect, abs=1e-9)


def test_clearance_matches_shapely() -> None:
    rng = np.random.default_rng(12)
    world = random_world(rng, 30)
    union = unary_union(shapely_of(world))
    walls = box(-5, -5, 5, 5)
    pts = rng.uniform(-5.5, 5.5, size=(400, 2))
    got = world.clearance(pts)
    for p, c in zip(pts, got, strict=True):
        point = Point(p)
        wall = walls.exterior.distance(point) * (1 if walls.contains(point) else -1)
        if union.contains(point):
            # inside: minus the depth into the obstacle the point is deepest in
            depth = max(
                Polygon(o.vertices).exterior.distance(point)
                for o in world.obstacles
                if Polygon(o.vertices).covers(point)
            )
            assert c == pytest.approx(min(-depth, wall), abs=1e-9)
        else:
            assert c == pytest.approx(min(union.distance(point), wall), abs=1e-9)


def test_nearby_matches_brute_force_and_is_fast() -> None:
    rng = np.random.default_rng(13)
    world = random_world(rng, 400, span=20.0)
    shapes = shapely_of(world)
    for _ in range(50):
        q = rng.uniform(-20, 20, 2)
        got = world.nearby(q, 1.5)
        expect = [o.vertices for o, p in zip(world.obstacles, shapes, strict=True)
                  if p.distance(Point(q)) <= 1.5]  # fmt: skip
        assert len(got) == len(expect)
        for a, b in zip(got, expect, strict=True):
            np.testing.assert_array_equal(a, b)
    start = time.perf_counter()
    for _ in range(100):
        world.nearby(rng.uniform(-20, 20, 2), 1.0)
    assert (time.perf_counter() - start) / 100 < 2e-3


def test_obstacle_is_frozen_and_ccw() -> None:
    o = Obstacle("x", np.array([[0, 0], [0, 1], [1, 1], [1, 0]], float))
    assert Polygon(o.vertices).exterior.is_ccw
    with pytest.raises(ValueError):
        o.vertices[0, 0] = 5.0


def test_clearance_of_many_points_equals_brute_force_without_a_workspace() -> None:
    """Many points: the per-chunk pruning must keep every obstacle that can be nearest."""
    from covswarm.tvd.geometry import point_polygon_distance_grad

    rng = np.random.default_rng(14)
    world = World(None, random_world(rng, 60, span=8.0).obstacles)
    pts = np.concatenate([rng.uniform(-10, 10, size=(1000, 2)), rng.normal(0, 0.3, (200, 2))])
    got = world.clearance(pts)
    expect = [
        min(point_polygon_distance_grad(p, o.vertices)[0] for o in world.obstacles) for p in pts
    ]
    np.testing.assert_allclose(got, expect, atol=1e-12)
