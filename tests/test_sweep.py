"""world.sweep.first_contact against shapely on densely sampled instants of every motion kind."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import shapely
from scipy.spatial import ConvexHull
from shapely.geometry import Polygon

from covswarm.coordinator.steering import Brake, Hold, Morph, Similarity, support_pairs
from covswarm.mission.motion import Keyframes, Rigid
from covswarm.world.model import World
from covswarm.world.sweep import Contact, first_contact

TOL = 1e-4
SAMPLES = 2000


def rect(xmin: float, xmax: float, ymin: float, ymax: float) -> np.ndarray:
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]], dtype=float)


def random_convex(rng: np.random.Generator, centre, size: float) -> np.ndarray:
    pts = rng.uniform(-size, size, size=(rng.integers(3, 9), 2)) + np.asarray(centre)
    return pts[ConvexHull(pts).vertices]


def motions(rng: np.random.Generator, start: np.ndarray) -> dict[str, object]:
    """One motion of each kind from ``start`` over [0, 10] s."""
    c = start.mean(axis=0)
    shift = rng.uniform(-3, 3, 2)
    translate = Similarity(start, 0.0, 10.0, c, shift, 0.0, 1.0)
    pivot = c + rng.uniform(-1.5, 1.5, 2)  # off-centre: S swings through the map
    rotate = Similarity(start, 0.0, 10.0, pivot, np.zeros(2), float(rng.uniform(-3, 3)), 1.0)
    scale = Similarity(start, 0.0, 10.0, c, shift / 3, 0.5, float(rng.uniform(0.4, 2.0)))
    target = random_convex(rng, c + shift, 0.8)
    morph = Morph(start, target, 0.0, 10.0, support_pairs(start, target))
    brake = Brake(translate, 3.0, 4.0, Hold(translate(3.0 + 4.0 / 3.0)[0]))
    keyframes = Keyframes(
        times=np.array([0.0, 4.0, 10.0]),
        vertices=np.array([start, start + shift / 2, start + shift * [1, -1]]),
    )
    rigid = Rigid(
        polygon=start - c, center=tuple(c), radius=1.0, period=20.0, rotation_rate=0.3,
        scale_rate=-0.03,
    )  # fmt: skip
    return {
        "hold": Hold(start),
        "translate": translate,
        "rotate": rotate,
        "scale": scale,
        "morph": morph,
        "brake": brake,
        "keyframes": keyframes,
        "rigid": rigid,
    }


def reference(motion, world: World, t0: float, t1: float):
    """Shapely on SAMPLES + 1 instants: per instant the distance to each obstacle and how far
    the farthest vertex is outside the workspace."""
    times = np.linspace(t0, t1, SAMPLES + 1)
    obstacles = np.array([Polygon(o.vertices) for o in world.obstacles])
    dist = np.empty((len(times), len(obstacles)))
    outside = np.empty(len(times))
    xmin, xmax, ymin, ymax = world.workspace
    for i, t in enumerate(times):
        v = motion(float(t))[0]
        dist[i] = shapely.distance(obstacles, Polygon(v)) if len(obstacles) else []
        outside[i] = max(xmin - v[:, 0].min(), v[:, 0].max() - xmax, ymin - v[:, 1].min(),
                         v[:, 1].max() - ymax)  # fmt: skip
    return times, dist, outside


def check_against_reference(motion, world: World, t0: float, t1: float) -> Contact | None:
    got = first_contact(motion, t0, t1, world, tolerance=TOL)
    times, dist, outside = reference(motion, world, t0, t1)
    touching = (dist <= 0.0).any(axis=1) | (outside > 2 * TOL)
    if got is None:
        assert not touching.any(), "a contact shapely sees was missed"
        return None
    # nothing touched before the reported instant, and it is a real (near) contact then
    assert not touching[times < got.time - 1e-12].any()
    v = motion(got.time)[0]
    if got.obstacle == "workspace":
        xmin, xmax, ymin, ymax = world.workspace
        assert max(xmin - v[:, 0].min(), v[:, 0].max() - xmax, ymin - v[:, 1].min(),
                   v[:, 1].max() - ymax) > TOL  # fmt: skip
    else:
        (obstacle,) = [o for o in world.obstacles if o.name == got.obstacle]
        assert Polygon(obstacle.vertices).distance(Polygon(v)) < TOL + 1e-12
    return got


KINDS = ["hold", "translate", "rotate", "scale", "morph", "brake", "keyframes", "rigid"]


@pytest.mark.parametrize("kind", KINDS)
def test_every_motion_kind_against_shapely_on_random_maps(kind: str) -> None:
    rng = np.random.default_rng(KINDS.index(kind))
    hits = clear = 0
    for _ in range(16):
        polys = [random_convex(rng, rng.uniform(-5, 5, 2), 0.4) for _ in range(18)]
        world = World.from_boxes_and_polygons((-6.0, 6.0, -6.0, 6.0), polys)
        start = random_convex(rng, rng.uniform(-3, 3, 2), 0.8)
        if world.contact(start) is not None:
            continue
        got = check_against_reference(motions(rng, start)[kind], world, 0.0, 10.0)
        hits += got is not None
        clear += got is None
    assert hits + clear >= 6
    if kind != "hold":
        assert hits >= 2


def test_thin_wall_crossed_fast_is_found_at_the_right_time() -> None:
    wall = [[0.0, 0.001, -1.0, 1.0]]  # 1 mm thick
    world = World.from_boxes_and_polygons((-10.0, 10.0, -2.0, 2.0), wall)
    start = rect(-5.0, -4.8, -0.1, 0.1)
    # 10 m in 1 s at peak 18.75 m/s: the wall is inside S for well under a millisecond
    motion = Similarity(start, 0.0, 1.0, start.mean(axis=0), np.array([10.0, 0.0]), 0.0, 1.0)
    got = first_contact(motion, 0.0, 1.0, world, tolerance=TOL)
    assert got is not None and got.obstacle == "obstacle 1"
    # the exact instant the leading edge (x = -4.8 + 10 s(u)) reaches x = 0
    from scipy.optimize import brentq

    def edge(t: float) -> float:
        return float(motion(t)[0][:, 0].max())

    exact = brentq(edge, 0.0, 1.0, xtol=1e-14)
    peak = 10.0 * 15.0 / 8.0
    assert exact - TOL / (peak / 1.5) - 1e-9 <= got.time <= exact + 1e-12


def test_stays_clear_through_a_gap_and_along_the_workspace_wall() -> None:
    world = World.from_boxes_and_polygons(
        (-2.591, 2.591, -1.829, 1.829), [[-0.3, 0.3, 0.45, 1.829], [-0.3, 0.3, -1.829, -0.45]]
    )
    start = rect(-1.5, -0.4, -0.3, 0.3)
    through = Similarity(start, 0.0, 12.0, start.mean(axis=0), np.array([1.9, 0.0]), 0.0, 1.0)
    assert first_contact(through, 0.0, 12.0, world) is None
    along = rect(-2.591, -2.0, -1.829, -1.0)  # resting in a corner, slides up the wall
    slide = Similarity(along, 0.0, 10.0, along.mean(axis=0), np.array([0.0, 2.0]), 0.0, 1.0)
    start_time = time.perf_counter()
    assert first_contact(slide, 0.0, 10.0, world) is None
    assert time.perf_counter() - start_time < 0.5


def test_through_the_wall_and_out_of_the_workspace() -> None:
    world = World.from_boxes_and_polygons((-2.591, 2.591, -1.829, 1.829), [[-0.3, 0.3, -1, 1]])
    s = rect(-2.4, -1.2, -0.8, 0.8)
    motion = Keyframes(times=np.array([0.0, 10.0]), vertices=np.array([s, s + [3.6, 0.0]]))
    got = check_against_reference(motion, world, 0.0, 10.0)
    assert got is not None and got.obstacle == "obstacle 1"
    assert got.time == pytest.approx(10.0 * 0.9 / 3.6, abs=TOL / 0.36 + 1e-9)  # 0.9 m to go
    out = Keyframes(times=np.array([0.0, 10.0]), vertices=np.array([s, s - [1.0, 0.0]]))
    got = check_against_reference(out, World((-2.591, 2.591, -1.829, 1.829)), 0.0, 10.0)
    assert got is not None and got.obstacle == "workspace"
    assert got.time == pytest.approx(10.0 * 0.191 / 1.0, abs=3 * TOL / 0.1)


def test_fast_enough_for_a_steering_request() -> None:
    rng = np.random.default_rng(7)
    centres = rng.uniform(-10, 10, size=(260, 2))
    polys = [random_convex(rng, c, 0.25) for c in centres if np.abs(c[1]) > 1.2][:200]
    assert len(polys) == 200
    world = World.from_boxes_and_polygons((-11.0, 11.0, -11.0, 11.0), polys)
    start = rect(-9.0, -8.0, -0.5, 0.5)
    motion = Similarity(start, 0.0, 30.0, start.mean(axis=0), np.array([17.0, 0.0]), 0.4, 0.8)
    first_contact(motion, 0.0, 30.0, world)  # warm up
    begin = time.perf_counter()
    got = first_contact(motion, 0.0, 30.0, world)
    elapsed = time.perf_counter() - begin
    assert elapsed < 0.1, f"{elapsed * 1e3:.0f} ms"
    assert got is None or got.obstacle.startswith("obstacle")


def test_refuses_bad_arguments() -> None:
    world = World(None)
    hold = Hold(rect(0, 1, 0, 1))
    with pytest.raises(ValueError, match="t0 <= t1"):
        first_contact(hold, 1.0, 0.0, world)
    with pytest.raises(ValueError, match="tolerance"):
        first_contact(hold, 0.0, 1.0, world, tolerance=0.0)
    with pytest.raises(ValueError, match="speed"):
        first_contact(hold, 0.0, 1.0, world, speed=math.nan)
    assert first_contact(hold, 0.0, 1.0, world) is None
