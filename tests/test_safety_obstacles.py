"""The safety filter's obstacle and wall rows (tvd/safety.py) against shapely, finite
differences, a dense QP and sampled motion."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from reference import dense_qp

from covswarm.tvd.drive import DEFAULT_PROJECTION_DISTANCE, KHEPERA_IV, integrate, wheel_speeds
from covswarm.tvd.geometry import validate_convex
from covswarm.tvd.safety import (
    DEFAULT_GAMMA,
    barrier_gain,
    body_safe_distance,
    closest_feasible,
    obstacle_constraints,
    pair_constraints,
    safe_velocity,
    team_safe_velocities,
    unicycle_rows,
    wall_distance,
)


def random_convex(rng: np.random.Generator, centre: np.ndarray, size: float) -> np.ndarray:
    """A random convex polygon about ``centre``: the hull of 3 to 9 random points."""
    points = centre + rng.uniform(-size, size, size=(int(rng.integers(3, 10)), 2))
    hull = shapely.MultiPoint(points).convex_hull
    return validate_convex(np.array(hull.exterior.coords)[:-1])


def reference_h(point: np.ndarray, polygon: np.ndarray, distance: float) -> float:
    """h = signed distance to the polygon (shapely) minus ``distance``."""
    shape, p = shapely.Polygon(polygon), shapely.Point(point)
    depth = shape.exterior.distance(p)
    return (-depth if shape.contains(p) else shape.distance(p)) - distance


def wall_gaps(point: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    xmin, xmax, ymin, ymax = box
    return np.array([point[0] - xmin, xmax - point[0], point[1] - ymin, ymax - point[1]])


@pytest.mark.parametrize("seed", range(30))
def test_rows_are_the_barrier_of_the_shapely_distance(seed: int) -> None:
    # b = gamma h with h from shapely; -A = grad h, checked by central differences.
    rng = np.random.default_rng(seed)
    polygons = [random_convex(rng, rng.uniform(-1, 1, 2), 0.4) for _ in range(3)]
    box = (-1.5, 1.5, -1.2, 1.2)
    point = rng.uniform(-1.4, 1.4, 2)
    distance, gamma = 0.09, 7.0
    A, b = obstacle_constraints(point, polygons, box, distance, gamma)
    expected_h = [reference_h(point, poly, distance) for poly in polygons]
    expected_h += list(wall_gaps(point, box) - distance)
    np.testing.assert_allclose(b, gamma * np.array(expected_h), atol=1e-12)
    eps = 1e-6
    for axis in range(2):
        step = np.eye(2)[axis] * eps
        up = obstacle_constraints(point + step, polygons, box, distance, gamma)[1]
        down = obstacle_constraints(point - step, polygons, box, distance, gamma)[1]
        derivative = (up - down) / (2 * eps * gamma)
        np.testing.assert_allclose(-A[:, axis], derivative, atol=1e-6)
    assert np.allclose(np.linalg.norm(A, axis=1), 1.0)


def test_reach_leaves_out_far_obstacles_and_walls() -> None:
    near = validate_convex([[0.3, -0.1], [0.5, -0.1], [0.5, 0.1], [0.3, 0.1]])
    far = near + [2.0, 0.0]
    box = (-0.4, 3.0, -3.0, 3.0)
    A, b = obstacle_constraints(np.zeros(2), [near, far], box, 0.09, 10.0, reach=0.5)
    # The near box (0.3 m) and the left wall (0.4 m) only.
    np.testing.assert_allclose(A, [[1.0, 0.0], [-1.0, 0.0]])  # u_x <= ..., -u_x <= ...
    np.testing.assert_allclose(b, 10.0 * (np.array([0.3, 0.4]) - 0.09))


def test_bad_workspace_and_missing_distance_are_refused() -> None:
    with pytest.raises(ValueError, match="workspace"):
        obstacle_constraints(np.zeros(2), [], (1.0, -1.0, -1.0, 1.0), 0.09, 10.0)
    with pytest.raises(ValueError, match="obstacle_distance"):
        safe_velocity([0, 0], [0.1, 0], np.empty((0, 2)), 0.16, workspace=(-1, 1, -1, 1))


@pytest.mark.parametrize("seed", range(40))
def test_filter_with_obstacles_matches_dense_qp(seed: int) -> None:
    rng = np.random.default_rng(seed)
    me = rng.uniform(-0.5, 0.5, 2)
    m = int(rng.integers(0, 8))
    others = me + rng.normal(size=(m, 2)) * 0.3
    polygons = [random_convex(rng, me + rng.normal(size=2) * 0.4, 0.2) for _ in range(4)]
    box = (-1.0, 1.0, -0.8, 0.8)
    safe, distance = 0.16, wall_distance(0.14)
    nominal = rng.normal(size=2) * 0.3
    velocity, theirs = rng.normal(size=2) * 0.1, rng.normal(size=(m, 2)) * 0.1
    heading = rng.uniform(-np.pi, np.pi) if seed % 2 else None
    A, b = pair_constraints(me, others, safe, DEFAULT_GAMMA, velocity, theirs)
    A_o, b_o = obstacle_constraints(me, polygons, box, distance, DEFAULT_GAMMA, reach=0.5)
    A, b = np.concatenate([A, A_o]), np.concatenate([b, b_o])
    if heading is not None:
        A = unicycle_rows(A, heading)
    result = safe_velocity(
        me, nominal, others, safe, heading=heading, velocity=velocity,
        neighbor_velocities=theirs, obstacles=polygons, workspace=box,
        obstacle_distance=distance, reach=0.5,
    )  # fmt: skip
    reference = dense_qp(nominal, A, b)
    if reference is None:
        assert result.relaxed
        # Relaxed: no pair closes, no obstacle or wall within reach is approached.
        offset = me - others
        h = np.einsum("ij,ij->i", offset, offset) - safe**2
        relaxed = np.concatenate([np.maximum(0.5 * DEFAULT_GAMMA * h, 0), np.maximum(b_o, 0)])
        assert np.all(A @ result.velocity <= relaxed + 1e-9 * np.maximum(1.0, relaxed))
        return
    assert not result.relaxed
    u = result.velocity
    assert np.all(A @ u <= b + 1e-8 * np.maximum(1.0, np.abs(b)))
    assert np.sum((u - nominal) ** 2) <= np.sum((reference - nominal) ** 2) * (1 + 1e-7) + 1e-12
    np.testing.assert_allclose(u, reference, atol=1e-6)


@pytest.mark.parametrize("seed", range(10))
def test_closest_feasible_with_many_rows(seed: int) -> None:
    # 20 to 60 rows, most of them slack, some tight: the O(m^2) candidate enumeration still
    # finds the dense QP's optimum (or reports no common point when HiGHS finds none).
    rng = np.random.default_rng(100 + seed)
    m = int(rng.integers(20, 61))
    angles = rng.uniform(-np.pi, np.pi, m)
    A = np.column_stack([np.cos(angles), np.sin(angles)]) * rng.uniform(0.1, 3.0, (m, 1))
    b = rng.uniform(-0.05, 1.0, m) * np.linalg.norm(A, axis=1)
    nominal = rng.normal(size=2) * 2.0
    reference = dense_qp(nominal, A, b)
    if reference is None:
        with pytest.raises(ValueError):
            closest_feasible(nominal, A, b)
        return
    u, active = closest_feasible(nominal, A, b)
    assert np.all(A @ u <= b + 1e-8)
    np.testing.assert_allclose(u, reference, atol=1e-6)
    assert active >= 1


def test_without_obstacles_the_filter_is_unchanged() -> None:
    # A workspace whose walls are all beyond reach adds no row: bit-identical velocities.
    rng = np.random.default_rng(7)
    me, others = np.zeros(2), rng.normal(size=(5, 2)) * 0.15
    nominal = np.array([0.3, -0.2])
    plain = safe_velocity(me, nominal, others, 0.16)
    far = safe_velocity(
        me, nominal, others, 0.16, workspace=(-3, 3, -3, 3), obstacle_distance=0.09, reach=0.5
    )
    np.testing.assert_array_equal(plain.velocity, far.velocity)
    assert (plain.active, plain.relaxed) == (far.active, far.relaxed)


def test_robot_between_two_close_walls_is_relaxed_and_approaches_neither() -> None:
    # A corridor 0.16 m wide for a robot that needs 2 x 0.09 m: infeasible, relaxed.
    left = validate_convex([[-1.0, -1.0], [-0.08, -1.0], [-0.08, 1.0], [-1.0, 1.0]])
    right = left * [-1.0, 1.0]
    result = safe_velocity(
        np.zeros(2), np.array([0.3, 0.4]), np.empty((0, 2)), 0.16, obstacles=[left, right],
        obstacle_distance=0.09,
    )  # fmt: skip
    assert result.relaxed
    assert abs(result.velocity[0]) <= 1e-12
    assert result.velocity[1] == pytest.approx(0.4)


def clearance(points: np.ndarray, polygons: list[np.ndarray], box: tuple) -> np.ndarray:
    """Shapely: each point's distance to the nearest obstacle or wall (negative inside one)."""
    out = []
    for p in points:
        gaps = [reference_h(p, poly, 0.0) for poly in polygons]
        out.append(min([*gaps, *wall_gaps(p, box)]))
    return np.array(out)


@pytest.mark.parametrize("seed", range(4))
def test_sampled_single_integrators_never_touch_a_wall(seed: int) -> None:
    # Five robots, some started inside an obstacle's reach (h small), every one pushed by its
    # nominal velocity straight at an obstacle or past it into the wall, 5 Hz zero-order
    # hold with gamma T = 1. h >= 0 at 20 instants of every period (shapely distances).
    rng = np.random.default_rng(seed)
    period, radius, margin = 0.2, 0.07, 0.02
    distance = wall_distance(2 * radius, margin)
    gamma = barrier_gain(DEFAULT_GAMMA, period)
    box = (-1.2, 1.2, -1.0, 1.0)
    polygons = [random_convex(rng, np.array([x, rng.uniform(-0.3, 0.3)]), 0.25) for x in (0, 0.8)]
    p = np.column_stack([np.full(5, -0.9), np.linspace(-0.7, 0.7, 5)])
    p[2] = [-0.25 - distance - 0.01, 0.0]  # just outside the first obstacle's reach
    p[2, 1] = shapely.Polygon(polygons[0]).centroid.y
    h_start = clearance(p, polygons, box) - distance
    p = p[h_start >= 0]
    goal = np.array([1.5, 0.0])  # beyond both obstacles and the right wall
    lowest = np.inf
    for _ in range(60):
        nominal = np.clip(goal - p, -0.4, 0.4)
        u = np.array([
            safe_velocity(
                p[i], nominal[i], np.delete(p, i, 0), 2 * radius + margin, gamma,
                obstacles=polygons, workspace=box, obstacle_distance=distance, reach=0.5,
            ).velocity
            for i in range(len(p))
        ])  # fmt: skip
        for s in np.linspace(0, period, 21)[1:]:
            lowest = min(lowest, float((clearance(p + s * u, polygons, box) - distance).min()))
        p = p + period * u
    assert -1e-9 <= lowest < 0.01  # they reached the walls' margin, never crossed it
    # They did move: the filter stops them at walls, not everywhere.
    assert p[:, 0].max() > 0.0


def test_sampled_single_integrator_pushed_into_a_box_stops_at_the_margin() -> None:
    box_obstacle = validate_convex([[0.5, -0.5], [1.0, -0.5], [1.0, 0.5], [0.5, 0.5]])
    distance, period = 0.09, 0.1
    p = np.array([0.3, 0.0])
    path = []
    for _ in range(100):
        u = safe_velocity(
            p, np.array([0.5, 0.0]), np.empty((0, 2)), 0.16, barrier_gain(10.0, period),
            obstacles=[box_obstacle], obstacle_distance=distance,
        ).velocity  # fmt: skip
        p = p + period * u
        path.append(p[0])
    assert max(path) <= 0.5 - distance + 1e-12
    assert path[-1] == pytest.approx(0.5 - distance, abs=1e-6)  # approaches it, geometrically


@pytest.mark.parametrize("heading", [0.0, 0.4, -0.9])
def test_khepera_unicycle_driven_at_a_wall_stops_short(heading: float) -> None:
    # A Khepera IV at 10 Hz steered at 0.3 m/s toward the right wall and an obstacle in
    # front of it, integrated in exact arcs (10 substeps a period): its body never touches
    # either (centre rows, as the agents use them).
    period, substeps = 0.1, 10
    radius = 0.5 * KHEPERA_IV.body_diameter
    distance = wall_distance(KHEPERA_IV.body_diameter)
    gamma = barrier_gain(DEFAULT_GAMMA, period)
    box = (-1.0, 1.0, -1.0, 1.0)
    wall = validate_convex([[0.4, 0.2], [0.6, 0.2], [0.6, 0.8], [0.4, 0.8]])
    pose = np.array([[-0.5, 0.1, heading]])
    target = np.array([2.0, 0.6])
    closest = np.inf
    for _ in range(150):
        th = pose[0, 2]
        ahead = np.array([np.cos(th), np.sin(th)])
        steered = pose[0, :2] + DEFAULT_PROJECTION_DISTANCE * ahead
        gap = target - steered
        nominal = gap * min(1.0, 0.3 / np.linalg.norm(gap))
        u = safe_velocity(
            pose[0, :2], nominal, np.empty((0, 2)), body_safe_distance(KHEPERA_IV.body_diameter),
            gamma, heading=th, obstacles=[wall], workspace=box, obstacle_distance=distance,
            reach=0.5,
        ).velocity  # fmt: skip
        wheels = wheel_speeds(np.array([th]), u[None])
        for _ in range(substeps):
            pose = integrate(pose, wheels, period / substeps)
            closest = min(closest, float(clearance(pose[:, :2], [wall], box)[0]))
    assert closest > radius  # the body edge never reached a wall
    assert closest < distance + 0.05  # it did drive up to one


def test_team_filter_passes_obstacles_to_every_robot() -> None:
    rng = np.random.default_rng(3)
    positions = rng.uniform(-0.5, 0.5, (8, 2))
    nominal = rng.normal(scale=0.3, size=(8, 2)) + [1.5, 0.0]  # toward the wall
    wall = validate_convex([[0.55, -1.0], [0.8, -1.0], [0.8, 1.0], [0.55, 1.0]])
    box = (-0.7, 1.0, -0.7, 0.7)
    out, active, relaxed = team_safe_velocities(
        positions, nominal, 0.16, 10.0, 0.5, nearby_obstacles=lambda p, r: [wall], workspace=box,
        obstacle_distance=0.09,
    )  # fmt: skip
    for i in range(8):
        near = [j for j in range(8) if j != i and np.hypot(*(positions[j] - positions[i])) <= 0.5]
        one = safe_velocity(
            positions[i], nominal[i], positions[near], 0.16, 10.0, obstacles=[wall],
            workspace=box, obstacle_distance=0.09, reach=0.5,
        )  # fmt: skip
        np.testing.assert_array_equal(out[i], one.velocity)
        assert (active[i], relaxed[i]) == (one.active, one.relaxed)
    plain, _, _ = team_safe_velocities(positions, nominal, 0.16, 10.0, 0.5)
    assert not np.array_equal(plain, out)  # the walls changed someone's velocity
