"""Steering against the arena (coordinator.steering.world_check, plan_goto): S never
touches an obstacle or leaves the workspace at any instant of a steered motion, checked
with shapely at dense instants; goto routes through a door, refusals name the obstacle."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from covswarm.coordinator.steering import (
    REFUSALS,
    Brake,
    Limits,
    Steering,
    motion_speed,
    world_check,
)
from covswarm.protocol.steering import SteerReply, SteerRequest
from covswarm.world.model import Obstacle, World, box_vertices
from covswarm.world.route import RouteMotion, centroid

SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
WORKSPACE = (-3.0, 3.0, -2.0, 2.0)
LIMITS = Limits(max_speed=0.5, workspace=WORKSPACE, min_area=0.3, min_width=0.2)
TOLERANCE = 1e-4  # m, world_check's default
# A wall at x in [1.2, 1.4] with a 0.8 m door at y in (-0.4, 0.4).
DOOR = World(
    WORKSPACE,
    (
        Obstacle("wall south", box_vertices((1.2, 1.4, -2.0, -0.4))),
        Obstacle("wall north", box_vertices((1.2, 1.4, 0.4, 2.0))),
    ),
)


def still(polygon: np.ndarray):
    return lambda t: (polygon.copy(), np.zeros_like(polygon))


def steering(world: World, polygon: np.ndarray = SQUARE, script=None) -> Steering:
    return Steering(
        still(polygon) if script is None else script, LIMITS, checks=(world_check(world),),
        world=world,
    )  # fmt: skip


def send(steer: Steering, request: SteerRequest, t: float) -> SteerReply:
    return steer.handle(request.encode(), t, 1.7e9 + t, True)


def shapes(world: World) -> list[tuple[str, Polygon]]:
    return [(o.name, Polygon(o.vertices)) for o in world.obstacles]


def clear_at(steer: Steering, world: World, t: float) -> tuple[float, str]:
    """(shapely distance from S(t) to the nearest obstacle or outside the workspace, what):
    negative when S leaves the workspace."""
    s = Polygon(steer.domain(t)[0])
    best = (math.inf, "")
    for name, shape in shapes(world):
        best = min(best, (s.distance(shape), name))
    outside = s.difference(box(WORKSPACE[0], WORKSPACE[2], WORKSPACE[1], WORKSPACE[3])).area
    if outside > 1e-12:
        best = (-outside, "workspace")
    return best


def random_world(rng: np.random.Generator) -> World:
    """A few random convex obstacles around S (none touching it at the start)."""
    obstacles = []
    while len(obstacles) < int(rng.integers(2, 6)):
        centre = rng.uniform([-2.7, -1.7], [2.7, 1.7])
        k = int(rng.integers(3, 7))
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        points = centre + rng.uniform(0.1, 0.5) * np.stack([np.cos(angles), np.sin(angles)], 1)
        try:
            obstacle = Obstacle(f"rock {len(obstacles) + 1}", points)
        except ValueError:
            continue
        if Polygon(obstacle.vertices).distance(Polygon(SQUARE)) > 0.05:
            obstacles.append(obstacle)
    return World(WORKSPACE, tuple(obstacles))


def random_request(rng: np.random.Generator) -> SteerRequest:
    kind = ["translate", "rotate", "scale", "polygon"][int(rng.integers(4))]
    if kind == "translate":
        return SteerRequest(
            kind, dx=float(rng.uniform(-2.5, 2.5)), dy=float(rng.uniform(-1.5, 1.5))
        )
    if kind == "rotate":
        return SteerRequest(
            kind, angle=float(rng.uniform(-3, 3)), about=tuple(rng.uniform(-1, 1, 2))
        )
    if kind == "scale":
        return SteerRequest(kind, factor=float(rng.uniform(0.6, 2.5)))
    centre = rng.uniform([-2, -1.2], [2, 1.2])
    angles = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 8))))
    radius = rng.uniform(0.5, 1.0)
    polygon = centre + radius * np.stack([np.cos(angles), np.sin(angles)], 1)
    return SteerRequest(kind, polygon=tuple(map(tuple, polygon)))


def dense_check(steer: Steering, world: World, reply: SteerReply, t: float, n: int = 1500):
    """An accepted motion: S clear of everything at n instants (shapely)."""
    for u in np.linspace(t, t + reply.duration, n):
        gap, what = clear_at(steer, world, float(u))
        assert gap > 0.0, (u, what, gap)


def test_refusal_codes_listed() -> None:
    assert "obstacle" in REFUSALS and "no-path" in REFUSALS


@pytest.mark.parametrize("seed", range(40))
def test_swept_check_against_shapely_at_dense_instants(seed: int) -> None:
    """Accepted motions never touch (shapely at 1500 instants); a refusal names an obstacle
    S is within the tolerance of at the reported time, and no earlier instant touches."""
    rng = np.random.default_rng(seed)
    world = random_world(rng)
    request = random_request(rng)
    steer = steering(world)
    reply = send(steer, request, 1.0)
    if reply.accepted:
        dense_check(steer, world, reply, 1.0)
        return
    code, _, why = reply.reason.partition(": ")
    if code != "obstacle":
        assert code in ("outside-workspace", "too-small"), reply.reason
        return
    when = float(why.rsplit("t = ", 1)[1].split(" s")[0])
    # The same motion, not installed: plan it again on a steering without the check.
    bare = Steering(still(SQUARE), LIMITS)
    assert send(bare, request, 1.0).accepted
    s_then = Polygon(bare.domain(when)[0])
    if "workspace" in why:
        inner = box(WORKSPACE[0] + TOLERANCE, WORKSPACE[2] + TOLERANCE,
                    WORKSPACE[1] - TOLERANCE, WORKSPACE[3] - TOLERANCE)  # fmt: skip
        assert not inner.contains(s_then.buffer(-0.006))  # within rounding of the wall
    else:
        name = why.split("'")[1]
        shape = dict(shapes(world))[name]
        assert s_then.distance(shape) <= TOLERANCE + 0.006  # reported to 2 decimals of t
    for u in np.linspace(1.0, when - 0.01, 400):
        s = Polygon(bare.domain(float(u))[0])
        assert all(s.distance(shape) > 0.0 for _, shape in shapes(world)), u


def test_random_cases_cover_both_answers() -> None:
    answers = set()
    for seed in range(40):
        rng = np.random.default_rng(seed)
        world = random_world(rng)
        reply = send(steering(world), random_request(rng), 1.0)
        answers.add(reply.reason.split(":")[0] if not reply.accepted else "accepted")
    assert {"accepted", "obstacle"} <= answers


def test_a_translation_through_a_wall_is_refused_naming_it_and_the_time() -> None:
    steer = steering(DOOR, SQUARE + [0.0, 1.0])  # beside the north wall
    reply = send(steer, SteerRequest("translate", dx=2.0, dy=0.0), 2.0)
    assert not reply.accepted
    assert reply.reason.startswith(
        "obstacle: S would touch obstacle 'wall north' ([1.2, 1.4] x [0.4, 2] m) at t = "
    )
    when = float(reply.reason.rsplit("t = ", 1)[1].split(" s")[0])
    # The right edge (x = 0.5) reaches x = 1.2 after 0.7 m of the 2 m: smoothstep s = 0.35.
    speed = 0.5
    span = 15 / 8 * 2.0 / speed
    u = [x for x in np.linspace(0, 1, 200001) if x**3 * (10 - 15 * x + 6 * x * x) >= 0.35][0]
    assert when == pytest.approx(2.0 + u * span, abs=0.01)
    np.testing.assert_array_equal(steer.domain(30.0)[0], SQUARE + [0.0, 1.0])  # S stays
    assert steer.refused["obstacle"] == 1


def test_leaving_the_workspace_mid_motion_is_refused() -> None:
    """A rotation about a far point: start and end inside, the arc outside."""
    steer = steering(World(WORKSPACE), SQUARE * 0.6)
    reply = send(steer, SteerRequest("rotate", angle=math.pi, about=(0.0, -1.0)), 0.0)
    assert not reply.accepted
    # plan()'s own sampled wall check, or the sweep: both refuse, the sweep names the time
    assert reply.reason.startswith(("outside-workspace", "obstacle: S would leave the workspace"))
    # A morph whose end is inside and whose start is inside cannot leave (convex), but a
    # translation to the corner and back is two requests: each is checked on its own.


def test_speed_bounds_are_bounds() -> None:
    """motion_speed never below the sampled vertex speeds (what makes the sweep exact)."""
    rng = np.random.default_rng(3)
    for _ in range(30):
        steer = Steering(still(SQUARE), LIMITS)
        request = random_request(rng)
        if not send(steer, request, 0.0).accepted:
            continue
        bound = motion_speed(steer.motion)
        speeds = [
            np.linalg.norm(steer.domain(float(t))[1], axis=1).max() for t in np.linspace(0, 30, 600)
        ]
        assert max(speeds) <= bound * (1 + 1e-9)


def test_a_brake_then_a_motion_into_a_wall_is_refused_after_the_brake() -> None:
    """S moving (a translation in progress) is pre-empted: the brake follows the checked
    path, the new motion is swept from where S stops."""
    steer = steering(DOOR)
    first = send(steer, SteerRequest("translate", dx=0.0, dy=1.2), 0.0)
    assert first.accepted
    t = 0.4 * first.duration  # S moving fast
    reply = send(steer, SteerRequest("translate", dx=2.0, dy=0.0), t)
    assert not reply.accepted and "wall north" in reply.reason
    when = float(reply.reason.rsplit("t = ", 1)[1].split(" s")[0])
    assert not isinstance(steer.motion, Brake)  # refused: the first motion continues
    accepted = send(steer, SteerRequest("translate", dx=-1.0, dy=0.0), t + 0.1)
    assert accepted.accepted and isinstance(steer.motion, Brake)
    assert when > steer.motion.end - 0.1  # the contact after the brake (from its stop)
    dense_check(steer, DOOR, accepted, t + 0.1)


# --- goto --------------------------------------------------------------------------------


def test_goto_through_the_door_and_back_to_full_size() -> None:
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    reply = send(steer, SteerRequest("goto", goal=(2.2, 0.5)), 1.0)
    assert reply.accepted, reply.reason
    assert isinstance(steer.motion, RouteMotion)
    route = reply.route
    assert route[0][:2] == pytest.approx((-1.5, 0.0)) and route[-1] == pytest.approx(
        (2.2, 0.5, 1.0)
    )
    assert min(stop[2] for stop in route) < 0.85  # shrunk for the 0.8 m door
    end = steer.domain(1.0 + reply.duration + 0.01)[0]
    np.testing.assert_allclose(centroid(end), [2.2, 0.5], atol=1e-9)
    assert Polygon(end).area == pytest.approx(1.0)
    dense_check(steer, DOOR, reply, 1.0, n=3000)
    assert SteerReply.decode(reply.encode()) == reply


def test_goto_with_a_goal_polygon_and_a_speed() -> None:
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    diamond = ((0.0, -0.6), (0.6, 0.0), (0.0, 0.6), (-0.6, 0.0))
    slow = SteerRequest("goto", goal=(-1.5, 1.0), polygon=diamond, speed=0.2)
    reply = send(steer, slow, 0.0)
    assert reply.accepted, reply.reason
    end = steer.domain(reply.duration + 0.01)[0]
    assert Polygon(end).symmetric_difference(Polygon(np.array(diamond) + [-1.5, 1.0])).area < 1e-9
    speeds = [
        np.linalg.norm(steer.domain(float(t))[1], axis=1).max()
        for t in np.linspace(0, reply.duration, 400)
    ]
    assert max(speeds) <= 0.2 * (1 + 1e-9)


def test_a_goal_polygon_is_held_to_the_workspace_where_it_is_placed_not_where_typed() -> None:
    # Typed far outside the workspace, placed at a goal inside it: accepted, S ends there.
    outside = tuple(map(tuple, (SQUARE * 0.8 + [10.0, 10.0]).tolist()))
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    reply = send(steer, SteerRequest("goto", goal=(-1.5, 1.0), polygon=outside), 0.0)
    assert reply.accepted, reply.reason
    end = steer.domain(reply.duration + 0.01)[0]
    np.testing.assert_allclose(centroid(end), [-1.5, 1.0], atol=1e-9)
    # Typed inside the workspace, placed where it would leave it: refused, the extents
    # reported are where it would be, not shifted by the slack.
    inside = tuple(map(tuple, (SQUARE * 0.8).tolist()))
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    reply = send(steer, SteerRequest("goto", goal=(-2.8, 0.0), polygon=inside), 0.0)
    assert not reply.accepted
    assert reply.reason.startswith("outside-workspace: the goal polygon at the goal reaches")
    assert "[-3.200, -2.400] x [-0.400, 0.400] m, 200 mm outside the workspace" in reply.reason


@pytest.mark.parametrize(
    ("world", "goal", "code"),
    [
        (  # the goal room is closed
            World(WORKSPACE, (Obstacle("wall", box_vertices((1.2, 1.4, -2.0, 2.0))),)),
            (2.2, 0.0),
            "no-path: enclosed",
        ),
        (  # a 0.15 m door: narrower than a robot with its clearance
            World(
                WORKSPACE,
                (
                    Obstacle("s", box_vertices((1.2, 1.4, -2.0, -0.075))),
                    Obstacle("n", box_vertices((1.2, 1.4, 0.075, 2.0))),
                ),
            ),
            (2.2, 0.0),
            "no-path: too-narrow",
        ),  # fmt: skip
        (DOOR, (1.3, 1.0), "no-path: goal-blocked"),
        (DOOR, (2.8, 0.0), "no-path: outside-workspace"),
    ],
)
def test_goto_without_a_way_is_refused_with_the_planners_reason(world, goal, code) -> None:
    steer = steering(world, SQUARE + [-1.5, 0.0])
    reply = send(steer, SteerRequest("goto", goal=goal), 0.0)
    assert not reply.accepted and reply.reason.startswith(code), reply.reason
    assert reply.route is None and steer.motion is None
    assert steer.refused["no-path"] == 1


def test_goto_while_moving_plans_from_where_the_brake_stops() -> None:
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    first = send(steer, SteerRequest("translate", dx=0.0, dy=1.0), 0.0)
    t = 0.5 * first.duration
    reply = send(steer, SteerRequest("goto", goal=(2.2, 0.0)), t)
    assert reply.accepted and isinstance(steer.motion, Brake)
    stop = steer.motion.motion(steer.motion.stop_time)[0]
    assert reply.route[0][:2] == pytest.approx(tuple(centroid(stop)))
    dense_check(steer, DOOR, reply, t, n=3000)


def test_a_replayed_journal_repeats_a_goto_exactly() -> None:
    steer = steering(DOOR, SQUARE + [-1.5, 0.0])
    lines = []
    for t, request in [
        (1.0, SteerRequest("goto", goal=(2.2, 0.5))),
        (6.0, SteerRequest("goto", goal=(-1.0, -1.0), speed=0.3)),
    ]:
        assert send(steer, request, t).accepted
        lines.append(steer.journal_line())
    assert json.loads(lines[0])["request"]["goal"] == [2.2, 0.5]
    again = steering(DOOR, SQUARE + [-1.5, 0.0])
    assert again.replay(lines) == 2
    for t in np.linspace(0.0, 60.0, 300):
        np.testing.assert_array_equal(again.domain(float(t))[0], steer.domain(float(t))[0])


def test_goto_turns_a_long_s_through_a_corridor_and_the_reply_says_by_how_much() -> None:
    """S 0.6 m x 2.2 m upright, a 0.8 m corridor running east: its least S (scale 0.48)
    is still 1.05 m high, so S turns a quarter to pass at full size; the stops where it is
    turned carry the angle (SteerReply.route's optional 4th value)."""
    corridor = World(
        WORKSPACE,
        (
            Obstacle("south", box_vertices((-0.5, 0.5, -2.0, -0.4))),
            Obstacle("north", box_vertices((-0.5, 0.5, 0.4, 2.0))),
        ),
    )  # fmt: skip
    tall = np.array([[-0.3, -1.1], [0.3, -1.1], [0.3, 1.1], [-0.3, 1.1]])
    steer = steering(corridor, tall + [-1.8, 0.0])
    reply = send(steer, SteerRequest("goto", goal=(1.8, 0.0)), 0.0)
    assert reply.accepted, reply.reason
    assert all(stop[2] == 1.0 for stop in reply.route)
    turned = [stop for stop in reply.route if len(stop) == 4]
    assert turned and any(abs(abs(stop[3]) - math.pi / 2) < 1e-9 for stop in turned)
    assert SteerReply.decode(reply.encode()) == reply
    end = steer.domain(reply.duration + 0.01)[0]
    assert Polygon(end).symmetric_difference(Polygon(tall + [1.8, 0.0])).area < 1e-9
    dense_check(steer, corridor, reply, 0.0, n=3000)
