"""Solid obstacles and walls (world/contact.py) against shapely and brute force."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from covswarm.tvd.geometry import validate_convex
from covswarm.world.contact import stop_at_contact, stop_at_contacts
from covswarm.world.model import Obstacle, World

BOX = (-2.0, 2.0, -1.5, 1.5)


def random_world(rng: np.random.Generator, count: int = 4) -> World:
    obstacles = []
    for i in range(count):
        centre = rng.uniform(-1.5, 1.5, 2)
        points = centre + rng.uniform(-0.4, 0.4, size=(int(rng.integers(3, 9)), 2))
        hull = np.array(shapely.MultiPoint(points).convex_hull.exterior.coords)[:-1]
        obstacles.append(Obstacle(f"o{i}", validate_convex(hull)))
    return World(BOX, tuple(obstacles))


def solid(world: World, radius: float) -> shapely.Geometry:
    """Where a body's centre may not be, by shapely: obstacles buffered by the radius (arcs
    of 1024 segments a quarter) and everything outside the workspace shrunk by it."""
    blocked = shapely.union_all(
        [shapely.Polygon(o.vertices).buffer(radius, quad_segs=1024) for o in world.obstacles]
    )
    xmin, xmax, ymin, ymax = world.workspace
    room = shapely.box(xmin + radius, ymin + radius, xmax - radius, ymax - radius)
    return shapely.union(blocked, shapely.box(-99, -99, 99, 99).difference(room))


def first_contact(start: np.ndarray, end: np.ndarray, blocked: shapely.Geometry) -> float | None:
    """Reference fraction of the move at first contact: where the segment first meets the
    blocked set (shapely's intersection, projected back on the segment); None if never."""
    line = shapely.LineString([start, end])
    meet = line.intersection(blocked)
    if meet.is_empty:
        return None
    points = shapely.get_coordinates(meet)
    return float(min(line.project(shapely.Point(x)) for x in points) / line.length)


@pytest.mark.parametrize("seed", range(25))
def test_first_contact_matches_shapely_on_random_worlds(seed: int) -> None:
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    radius = rng.uniform(0.03, 0.2)
    blocked = solid(world, radius)
    # Starts clear of everything (1e-6 m: the buffer's polygon is not the exact arc).
    candidates = rng.uniform(-2.2, 2.2, size=(200, 2))
    starts = np.array([s for s in candidates if blocked.distance(shapely.Point(s)) > 1e-6])[:40]
    ends = starts + rng.normal(size=starts.shape) * rng.choice([0.05, 0.5, 2.0], (len(starts), 1))
    out, hit = stop_at_contacts(starts, ends, radius, world)
    for i in range(len(starts)):
        expected = first_contact(starts[i], ends[i], blocked)
        if expected is None:
            assert not hit[i]
            np.testing.assert_array_equal(out[i], ends[i])  # the same floats
            continue
        assert hit[i] or expected > 1.0 - 1e-6  # a graze at the very end may round either way
        np.testing.assert_allclose(out[i], starts[i] + expected * (ends[i] - starts[i]), atol=2e-6)


@pytest.mark.parametrize("seed", range(10))
def test_a_stopped_body_touches_and_never_overlaps(seed: int) -> None:
    # Brute force: 400 samples along every allowed move keep the centre at least a radius
    # from every obstacle and inside the walls; where a move was cut, the body touches.
    rng = np.random.default_rng(50 + seed)
    world = random_world(rng, 6)
    radius = 0.07
    blocked = solid(world, radius)
    candidates = rng.uniform(-1.9, 1.9, size=(400, 2))
    starts = np.array([s for s in candidates if not blocked.intersects(shapely.Point(s))])
    ends = starts + rng.normal(size=starts.shape) * 0.8
    out, hit = stop_at_contacts(starts, ends, radius, world)
    s = np.linspace(0.0, 1.0, 401)
    for i in range(len(starts)):
        path = starts[i] + s[:, None] * (out[i] - starts[i])
        assert world.clearance(path).min() >= -1e-9  # centre never inside an obstacle
        gaps = [
            shapely.Polygon(o.vertices).distance(shapely.MultiPoint(path)) for o in world.obstacles
        ]
        xmin, xmax, ymin, ymax = BOX
        walls = np.min([path[:, 0] - xmin, xmax - path[:, 0], path[:, 1] - ymin, ymax - path[:, 1]])
        assert min(*gaps, walls) >= radius - 1e-9
        if hit[i]:
            contact = min(
                *[
                    shapely.Polygon(o.vertices).distance(shapely.Point(out[i]))
                    for o in world.obstacles
                ],
                np.min([out[i, 0] - xmin, xmax - out[i, 0], out[i, 1] - ymin, ymax - out[i, 1]]),
            )
            assert contact == pytest.approx(radius, abs=1e-9)
    assert hit.any() and not hit.all()


def test_corner_clipped_between_two_clear_endpoints_is_a_contact() -> None:
    # Both ends of the move are clear of the box, the body's path sweeps over its corner.
    world = World(None, (Obstacle("box", validate_convex([[0, 0], [1, 0], [1, 1], [0, 1]])),))
    position, hit = stop_at_contact([-0.3, 0.8], [0.3, 1.4], 0.1, world)
    assert hit
    assert shapely.Point(position).distance(shapely.box(0, 0, 1, 1)) == pytest.approx(0.1)
    assert position[0] < 0.0


def test_resting_and_overlapping_bodies_leave_but_never_go_deeper() -> None:
    wall = Obstacle("wall", validate_convex([[0, -1], [1, -1], [1, 1], [0, 1]]))
    world = World((-3.0, 3.0, -3.0, 3.0), (wall,))
    # Resting against the wall's face: into it is refused, away and along it are allowed.
    for start, end, stopped in [
        ([-0.1, 0.0], [0.2, 0.1], True),
        ([-0.1, 0.0], [-0.5, 0.3], False),
        ([-0.1, 0.0], [-0.1, 0.5], False),
    ]:
        position, hit = stop_at_contact(start, end, 0.1, world)
        assert hit == stopped
        np.testing.assert_array_equal(position, start if stopped else end)
    # Placed overlapping (centre inside, near the left face): out is free, further in is not.
    position, hit = stop_at_contact([0.05, 0.0], [-0.4, 0.0], 0.1, world)
    assert not hit and position[0] == -0.4
    position, hit = stop_at_contact([0.05, 0.0], [0.2, 0.0], 0.1, world)
    assert hit and position[0] == 0.05
    # Outside the workspace: back in is free, further out is not.
    position, hit = stop_at_contact([2.95, 2.0], [2.5, 2.0], 0.1, world)
    assert not hit
    position, hit = stop_at_contact([2.95, 2.0], [3.2, 2.0], 0.1, world)
    assert hit and position[0] == 2.95


def test_walls_stop_a_body_a_radius_inside() -> None:
    world = World((-1.0, 1.0, -1.0, 1.0))
    out, hit = stop_at_contacts(
        np.array([[0.0, 0.0], [0.5, 0.5], [0.0, 0.0]]),
        np.array([[2.0, 0.0], [1.5, 0.6], [0.3, 0.2]]),
        0.07,
        world,
    )
    np.testing.assert_allclose(out[0], [0.93, 0.0])
    np.testing.assert_allclose(out[1], [0.93, 0.5 + 0.43 / 1.0 * 0.1])
    np.testing.assert_array_equal(out[2], [0.3, 0.2])
    assert hit.tolist() == [True, True, False]


def test_empty_world_and_zero_moves() -> None:
    starts = np.array([[0.0, 0.0], [1.0, 1.0]])
    out, hit = stop_at_contacts(starts, starts + 0.5, 0.1, World(None))
    np.testing.assert_array_equal(out, starts + 0.5)
    assert not hit.any()
    wall = Obstacle("wall", validate_convex([[0, -1], [1, -1], [1, 1], [0, 1]]))
    out, hit = stop_at_contacts(
        np.array([[-0.1, 0.0]]), np.array([[-0.1, 0.0]]), 0.1, World(None, (wall,))
    )
    assert not hit[0]


def test_bad_input_is_refused() -> None:
    world = World(BOX)
    with pytest.raises(ValueError, match="finite"):
        stop_at_contact([np.nan, 0], [0, 0], 0.1, world)
    with pytest.raises(ValueError, match="radius"):
        stop_at_contact([0, 0], [1, 0], -0.1, world)
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        stop_at_contacts(np.zeros((3, 2)), np.zeros((2, 2)), 0.1, world)
