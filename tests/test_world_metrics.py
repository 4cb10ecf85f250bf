"""Arena metrics of a run (mission/world_metrics.py) against shapely and hand-made runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from covswarm.mission.world_metrics import (
    domain_obstacle_overlap,
    goal_times,
    min_obstacle_clearance,
    obstacle_contacts,
    polygon_centroid,
    world_summary,
    write_domain_csv,
)
from covswarm.tvd.geometry import validate_convex
from covswarm.world.model import Obstacle, World

BOX = (-2.0, 2.0, -1.5, 1.5)


def disjoint_world(rng: np.random.Generator, count: int = 5) -> World:
    shapes: list[shapely.Polygon] = []
    while len(shapes) < count:
        points = rng.uniform(-1.6, 1.6, 2) + rng.uniform(-0.35, 0.35, size=(6, 2))
        hull = shapely.MultiPoint(points).convex_hull
        if hull.area > 1e-3 and not any(hull.intersects(s) for s in shapes):
            shapes.append(hull)
    obstacles = tuple(
        Obstacle(f"o{i}", validate_convex(np.array(s.exterior.coords)[:-1]))
        for i, s in enumerate(shapes)
    )
    return World(BOX, obstacles)


def shapely_clearance(point: np.ndarray, world: World) -> float:
    """Signed distance to the nearest obstacle or wall (minus the depth inside an obstacle,
    minus the distance to the room outside it)."""
    p = shapely.Point(point)
    gaps = []
    for o in world.obstacles:
        shape = shapely.Polygon(o.vertices)
        gaps.append(-shape.exterior.distance(p) if shape.contains(p) else shape.distance(p))
    room = shapely.box(*np.array(world.workspace)[[0, 2, 1, 3]])
    wall = room.exterior.distance(p) if room.contains(p) else -room.distance(p)
    return min(*gaps, wall)


@pytest.mark.parametrize("seed", range(10))
def test_min_clearance_matches_shapely(seed: int) -> None:
    rng = np.random.default_rng(seed)
    world = disjoint_world(rng)
    trajectories = rng.uniform(-2.1, 2.1, size=(30, 7, 2))
    trajectories[3, 2] = np.nan  # an unknown robot is skipped
    t = np.arange(30) * 0.1
    radius = 0.07
    reference = np.array(
        [[shapely_clearance(p, world) if np.isfinite(p).all() else np.inf for p in row]
         for row in trajectories]
    ) - radius  # fmt: skip
    clearance, when = min_obstacle_clearance(t, trajectories, radius, world)
    assert clearance == pytest.approx(reference.min(), abs=1e-12)
    assert when == t[np.unravel_index(np.argmin(reference), reference.shape)[0]]


@pytest.mark.parametrize("seed", range(10))
def test_domain_overlap_matches_shapely(seed: int) -> None:
    rng = np.random.default_rng(20 + seed)
    obstacles = []  # overlapping obstacles too: the union's area counts once
    for i in range(4):
        points = rng.uniform(-1.0, 1.0, 2) + rng.uniform(-0.6, 0.6, size=(6, 2))
        hull = np.array(shapely.MultiPoint(points).convex_hull.exterior.coords)[:-1]
        obstacles.append(Obstacle(f"o{i}", validate_convex(hull)))
    world = World(None, tuple(obstacles))
    union = shapely.union_all([shapely.Polygon(o.vertices) for o in obstacles])
    polygons = []
    for _ in range(12):
        points = rng.uniform(-1.5, 1.5, 2) + rng.uniform(-0.8, 0.8, size=(7, 2))
        polygons.append(
            validate_convex(np.array(shapely.MultiPoint(points).convex_hull.exterior.coords)[:-1])
        )
    expected = [shapely.Polygon(p).intersection(union).area for p in polygons]
    overlap, k = domain_obstacle_overlap(polygons, world)
    assert overlap == pytest.approx(max(expected), rel=1e-9, abs=1e-12)
    assert k == int(np.argmax(expected))


def wall_world() -> World:
    return World(
        (-5.0, 5.0, -5.0, 5.0),
        (Obstacle("wall", validate_convex([[1, -1], [2, -1], [2, 1], [1, 1]])),),
    )


def test_contacts_by_hand() -> None:
    # One robot, radius 0.1, facing the wall's face at x = 1: body gaps per sample below.
    # Touching within 1 mm counts, 1.1 mm does not; an episode is counted once; a second
    # touch after leaving is a second episode; an unknown sample ends one; overlap counts.
    gaps = [0.5, 0.0011, 0.0009, 0.0, 0.0005, 0.2, 0.00099, np.nan, -0.03, -0.01, 0.3]
    x = np.array([1.0 - 0.1 - g for g in gaps])
    trajectories = np.column_stack([x, np.zeros_like(x)])[:, None, :]
    trajectories = np.concatenate([trajectories, np.full_like(trajectories, [0.0, 0.0])], axis=1)
    t = np.arange(len(gaps)) * 0.5
    contacts = obstacle_contacts(t, trajectories, 0.1, wall_world())
    assert [(c.robot, c.start, c.duration, c.what) for c in contacts] == [
        (0, 1.0, 1.5, "wall"),
        (0, 3.0, 0.5, "wall"),
        (0, 4.0, 1.0, "wall"),
    ]
    assert contacts[0].closest == pytest.approx(0.0, abs=1e-12)
    assert contacts[2].closest == pytest.approx(-0.03)
    summary = world_summary(t, trajectories, [], 0.1, wall_world())
    assert summary["obstacle_contacts"] == 3
    assert summary["min_obstacle_clearance"] == pytest.approx(-0.03)
    assert summary["min_obstacle_clearance_t"] == 4.0


def test_walls_count_as_contacts_and_are_named_workspace() -> None:
    world = wall_world()
    x = np.array([4.0, 4.9, 4.9, 4.0])  # radius 0.1: touching the right wall twice running
    trajectories = np.column_stack([x, np.zeros(4)])[:, None, :]
    contacts = obstacle_contacts(np.arange(4.0), trajectories, 0.1, world)
    assert [(c.start, c.duration, c.what) for c in contacts] == [(1.0, 2.0, "workspace")]
    empty = World(None)
    assert obstacle_contacts(np.arange(4.0), trajectories, 0.1, empty) == []
    assert min_obstacle_clearance(np.arange(4.0), trajectories, 0.1, empty) == (None, None)


def square(centre: tuple[float, float], half: float = 0.5) -> np.ndarray:
    cx, cy = centre
    return np.array([[cx - half, cy - half], [cx + half, cy - half], [cx + half, cy + half],
                     [cx - half, cy + half]])  # fmt: skip


def test_goals_reached_in_order_within_a_millimetre() -> None:
    # S's centre moves 0 -> 2 -> back to 1 in x, sampled every 0.3 m; it stops at 2.0 and
    # passes 1.15 between samples (reached at the time of its closest point).
    xs = [0.0, 0.3, 0.6, 0.9, 1.2, 1.5, 1.8, 2.0, 2.0, 1.7, 1.4, 1.1, 1.0]
    t = np.arange(len(xs), dtype=float)
    polygons = [square((x, 0.0)) for x in xs]
    times = goal_times(t, polygons, [(2.0, 0.0), (1.15, 0.0), (1.0, 0.0)])
    np.testing.assert_allclose(times, [7.0, 10.0 + 0.25 / 0.3, 12.0])
    # 1.5 mm off the path is not reached, and the goals after it are not either.
    assert goal_times(t, polygons, [(1.15, 0.0015), (2.0, 0.0)]) == [None, None]
    assert goal_times(t, polygons, [(1.15, 0.0009)]) == [pytest.approx(3.0 + 0.25 / 0.3)]
    # In order: (1.0, 0) after (2.0, 0) only counts on the way back.
    assert goal_times(t, polygons, [(2.0, 0.0), (0.3, 0.0)]) == [7.0, None]
    summary = world_summary(t, np.zeros((len(t), 1, 2)), polygons, 0.07, World(None),
                            goals=[(2.0, 0.0), (5.0, 0.0)])  # fmt: skip
    assert (summary["goals"], summary["goals_reached"], summary["goal_times"]) == (
        2,
        1,
        [7.0, None],
    )
    assert summary["goal_list"] == [[2.0, 0.0], [5.0, 0.0]]  # what the plot marks
    with pytest.raises(ValueError, match="finite"):
        goal_times(t, polygons, [(np.nan, 0.0)])


@pytest.mark.parametrize("seed", range(5))
def test_polygon_centroid_matches_shapely(seed: int) -> None:
    rng = np.random.default_rng(seed)
    hull = shapely.MultiPoint(rng.normal(size=(9, 2))).convex_hull
    vertices = np.array(hull.exterior.coords)[:-1]
    np.testing.assert_allclose(polygon_centroid(vertices), [hull.centroid.x, hull.centroid.y])
    np.testing.assert_allclose(polygon_centroid(vertices[::-1]), [hull.centroid.x, hull.centroid.y])


def test_domain_csv_round_trip(tmp_path: Path) -> None:
    polygons = [square((0.0, 0.0)), np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.8]])]
    path = write_domain_csv(tmp_path / "domain.csv", np.array([0.0, 0.04]), polygons)
    assert path.read_text().splitlines()[0] == "t,vertex,x,y"
    rows = np.loadtxt(path, delimiter=",", skiprows=1)
    assert rows.shape == (7, 4)
    np.testing.assert_allclose(rows[4:, 2:], polygons[1])
    assert rows[:, 1].tolist() == [0, 1, 2, 3, 0, 1, 2]
    assert rows[:, 0].tolist() == [0, 0, 0, 0, 0.04, 0.04, 0.04]
    with pytest.raises(ValueError, match="polygons"):
        write_domain_csv(tmp_path / "bad.csv", np.array([0.0]), polygons)


def test_the_plot_marks_the_goals_filled_once_reached() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covswarm.mission.report import _trajectory_figure

    square = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    trajectories = np.zeros((2, 2, 2)) + [[-0.2, 0.0], [0.2, 0.0]]
    summary = {"goal_list": [[1.0, 0.0], [2.0, 1.0]], "goal_times": [3.5, None]}
    fig = _trajectory_figure(plt, summary, trajectories, [square, square], [], None, None)
    marked = {
        c.get_label(): c.get_offsets().tolist()
        for c in fig.axes[0].collections
        if c.get_label().startswith("goal")
    }
    plt.close(fig)
    assert marked == {"goal reached": [[1.0, 0.0]], "goal": [[2.0, 1.0]]}
