"""Agents that know the world (issue 20 item 5, issue 21 item 2), at the brain level (sans-IO).

A brain given a World keeps its robot's body clear of every obstacle and workspace wall
(the safety filter's obstacle rows), refuses a Domain that overlaps an obstacle, and without
a world does exactly what it did before. The runs close the loop with an ideal unicycle
(covswarm.tvd.drive.integrate_one, exact arcs) and check every robot's clearance against
shapely at 10 ms sub-steps, not only at the control instants.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import shapely

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent.brain import AgentBrain, AgentConfig, PublishState, SendCommand
from covswarm.tvd.drive import KHEPERA_IV, integrate_one
from covswarm.world.model import Obstacle, World, box_vertices
from covswarm.world.wire import to_message

WALL = 1.7e9
RADIUS = 0.5 * KHEPERA_IV.body_diameter  # m, the body's
WORKSPACE = (-1.5, 2.5, -2.0, 2.5)
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]  # S; centroid (1, 1)
BLOCK = (0.7, 1.3, -0.9, -0.05)  # just below S: a robot below it is pulled straight into it
ARENA = World(WORKSPACE, (Obstacle("block", box_vertices(BLOCK)),))


def domain(vertices: list, seq: int = 1, velocity: tuple[float, float] = (0.0, 0.0)):
    return protocol.Domain(
        seq=seq,
        stamp=WALL,
        t=0.0,
        state="running",
        vertices=vertices,
        velocities=[list(velocity)] * len(vertices),
        kappa=1.0,
    )


def pose_message(rid: int, pose: np.ndarray, stamp: float, seq: int) -> protocol.Pose:
    return protocol.Pose(
        id=rid, x=float(pose[0]), y=float(pose[1]), theta=float(pose[2]), stamp=stamp, seq=seq
    )


def clearances(world: World, points: np.ndarray) -> np.ndarray:
    """(n,) m from each centre (n, 2) to the nearest obstacle or workspace wall, by shapely:
    negative inside an obstacle or outside the workspace."""
    pts = shapely.points(points)
    gaps = [np.full(len(points), np.inf)]
    for obstacle in world.obstacles:
        polygon = shapely.Polygon(obstacle.vertices)
        gap = shapely.distance(polygon, pts)
        gaps.append(np.where(shapely.contains(polygon, pts), -1.0, gap))
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = world.workspace
        gaps += [points[:, 0] - xmin, xmax - points[:, 0], points[:, 1] - ymin, ymax - points[:, 1]]
    return np.min(gaps, axis=0)


def run(
    brains: list[AgentBrain],
    poses: np.ndarray,
    seconds: float,
    period: float = 0.1,
    substeps: int = 10,
    intruder: Callable[[float], protocol.AgentState] | None = None,
    late: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Close the loop: each period every brain hears its robot's pose and the others'
    AgentStates, ticks, and its command drives an ideal unicycle for the period (exact arcs,
    ``substeps`` poses recorded). ``intruder(now)``: one more robot's AgentState that every
    brain hears (a robot without a brain in this loop). ``late``: each command acts a
    uniform random 0..late s into its period, the previous one driving until then (command
    latency the brain does not know about). Returns (final poses (n, 3), every recorded pose
    (n, 3))."""
    poses = np.array(poses, dtype=float)
    trace = [poses.copy()]
    rng = np.random.default_rng(seed)
    previous = [(0.0, 0.0)] * len(brains)
    for k in range(round(seconds / period)):
        now = k * period
        wall = WALL + now
        for brain, pose in zip(brains, poses, strict=True):
            brain.on_pose(pose_message(brain.id, pose, wall, k), now)
        commands, states = [], [] if intruder is None else [intruder(now)]
        for brain in brains:
            actions = brain.tick(now, wall)
            commands += [a.command for a in actions if isinstance(a, SendCommand)]
            states += [a.state for a in actions if isinstance(a, PublishState)]
        for brain in brains:
            for state in states:
                if state.id != brain.id:
                    brain.on_agent_state(state, now)
        delays = rng.uniform(0.0, late, len(commands))
        for j in range(substeps):
            for i, command in enumerate(commands):
                acting = j * period / substeps >= delays[i]
                wheels = (command.left, command.right) if acting else previous[i]
                poses[i] = integrate_one(*poses[i], wheels[0], wheels[1], period / substeps)
            trace.append(poses.copy())
        previous = [(command.left, command.right) for command in commands]
    return poses, trace


def test_a_robot_pulled_into_an_obstacle_stops_short_of_it() -> None:
    """From below the block, S's centroid lies straight through it: without the world the
    robot drives into it, with the world it never comes closer than its body radius."""
    starts = [(1.0, -1.4, 1.57), (0.8, -1.2, 1.2), (1.35, -1.1, 2.0), (0.6, -0.5, 0.4)]
    for start in starts:
        blind = AgentBrain(0, AgentConfig())
        blind.on_domain(domain(SQUARE), now=0.0)
        _, trace = run([blind], np.array([start]), 4.0)
        assert clearances(ARENA, np.array(trace)[:, 0, :2]).min() < 0.0  # it went in
        brain = AgentBrain(0, AgentConfig())
        brain.set_world(ARENA)
        assert brain.on_domain(domain(SQUARE), now=0.0)
        final, trace = run([brain], np.array([start]), 12.0)
        gaps = clearances(ARENA, np.array(trace)[:, 0, :2])
        assert gaps.min() >= RADIUS - 1e-9, (start, gaps.min())
        assert brain.safety_active > 0


@pytest.mark.parametrize("late", [0.02, 0.06])
def test_commands_acting_late_still_stop_short_of_the_obstacle(late: float) -> None:
    """Command latency the brain does not know about (each command acting up to ``late`` s
    into its period) must not let the body reach the block: the wall rows close only half
    the gap per period (WALL_GAMMA_FRACTION)."""
    starts = [(1.0, -1.1, np.pi / 2), (1.0, -1.4, 1.57), (0.8, -1.2, 1.2), (1.0, -1.3, 0.0)]
    for seed, start in enumerate(starts):
        brain = AgentBrain(0, AgentConfig())
        brain.set_world(ARENA)
        assert brain.on_domain(domain(SQUARE), now=0.0)
        _, trace = run([brain], np.array([start]), 6.0, late=late, seed=seed)
        gaps = clearances(ARENA, np.array(trace)[:, 0, :2])
        assert gaps.min() >= RADIUS + 0.01, (start, gaps.min())


def test_a_crowd_started_against_the_walls_never_touches_them() -> None:
    """Twelve robots packed along the block and in the workspace's corner, random headings,
    S beside them: neighbours' rows push robots toward the walls while they sort out; no
    body ever touches the block or a wall, over 15 s."""
    rng = np.random.default_rng(7)
    corner = [(-1.5 + 0.09 + 0.17 * i, -2.0 + 0.09 + 0.17 * j) for i in range(3) for j in range(2)]
    beside = [(0.7 - 0.09, -0.8 + 0.17 * j) for j in range(3)]
    beside += [(1.3 + 0.09, -0.8 + 0.17 * j) for j in range(3)]
    starts = np.array([(x, y, rng.uniform(-np.pi, np.pi)) for x, y in corner + beside])
    assert clearances(ARENA, starts[:, :2]).min() >= RADIUS + 0.015  # inside the reach
    brains = []
    for rid in range(len(starts)):
        brain = AgentBrain(rid, AgentConfig())
        brain.set_world(ARENA)
        assert brain.on_domain(domain([[-1.5, -0.0], [2.5, 0.0], [2.5, 1.0], [-1.5, 1.0]]), 0.0)
        brains.append(brain)
    _, trace = run(brains, starts, 15.0)
    points = np.array(trace)[:, :, :2].reshape(-1, 2)
    assert clearances(ARENA, points).min() >= RADIUS - 1e-9
    assert sum(brain.safety_active for brain in brains) > 0
    assert all(brain.counters.step_errors == 0 for brain in brains)


def test_a_robot_shoved_toward_an_obstacle_by_a_neighbour_stops_short_of_it() -> None:
    """A neighbour that does not give way drives at our robot from the right and parks
    against it: our robot yields toward the block's side, and stops before touching it
    (squeezed, the pair's rows relax; the wall's never let the body in)."""
    start = np.array([[1.55, -0.5, np.pi / 2]])
    home = [[1.35, -0.7], [1.75, -0.7], [1.75, -0.3], [1.35, -0.3]]  # S around it

    def bully(now: float) -> protocol.AgentState:
        x = max(2.2 - 0.3 * now, 1.45)
        return protocol.AgentState(
            id=9, x=x, y=-0.5, stamp=WALL + now, neighbors=[], vx=-0.3 if x > 1.45 else 0.0
        )

    brain = AgentBrain(0, AgentConfig())
    brain.set_world(ARENA)
    assert brain.on_domain(domain(home), now=0.0)
    final, trace = run([brain], start, 6.0, intruder=bully)
    gaps = clearances(ARENA, np.array(trace)[:, 0, :2])
    assert gaps.min() >= RADIUS - 1e-9
    assert gaps.min() < gaps[0] - 0.1  # it was shoved toward the block
    assert brain.safety_relaxed > 0


def test_a_domain_overlapping_an_obstacle_is_refused_and_counted() -> None:
    brain = AgentBrain(0, AgentConfig())
    brain.set_world(ARENA)
    assert brain.on_domain(domain(SQUARE, 1), now=0.0)
    over = [[0.0, -0.5], [2.0, -0.5], [2.0, 1.5], [0.0, 1.5]]  # 0.27 m^2 of the block
    assert not brain.on_domain(domain(over, 2), now=0.01)
    assert brain.drops.counts["domain_in_obstacle"] == 1
    assert brain.stats()["drop_domain_in_obstacle"] == 1
    assert brain.domain.seq == 1
    # Clockwise, and refused all the same; through a payload too.
    assert not brain.receive("domain", domain(over[::-1], 3).encode(), now=0.02, now_wall=WALL)
    assert brain.drops.counts["domain_in_obstacle"] == 2
    # Resting on the block's top edge, or reaching into it less than the slack, is fine.
    slack = brain_module.DOMAIN_OBSTACLE_SLACK
    for depth, taken in ((0.0, True), (0.5 * slack, True), (2.0 * slack, False)):
        y = -0.05 - depth
        held = brain.domain.seq
        assert (
            brain.on_domain(domain([[0, y], [2, y], [2, 1.5], [0, 1.5]], held + 1), 0.03) == taken
        )
    assert brain.drops.counts["domain_in_obstacle"] == 3


def test_a_new_world_drops_a_held_domain_in_its_obstacles_and_sets_the_workspace() -> None:
    brain = AgentBrain(0, AgentConfig())
    assert brain.on_domain(domain([[0.0, -0.5], [2.0, -0.5], [2.0, 1.5], [0.0, 1.5]]), 0.0)
    brain.set_world(ARENA)
    assert brain.domain is None
    assert brain.drops.counts["domain_in_obstacle"] == 1
    assert brain.workspace == WORKSPACE
    assert not brain.on_domain(domain([[2.0, 0.0], [3.0, 0.0], [3.0, 1.0]], 2), 0.1)
    assert brain.drops.counts["domain_outside_workspace"] == 1
    # A world without a workspace keeps the one the agent has (from its scenario).
    brain.set_world(World(None, ARENA.obstacles))
    assert brain.workspace == WORKSPACE
    with pytest.raises(TypeError, match="World"):
        brain.set_world(WORKSPACE)  # type: ignore[arg-type]


def test_without_a_world_or_far_from_it_the_brain_steers_exactly_as_before() -> None:
    """No obstacle or wall within the safety radius: not a row more, the same commands."""
    far = World(None, (Obstacle("far", box_vertices((5.0, 6.0, 5.0, 6.0))),))
    rng = np.random.default_rng(3)
    starts = np.column_stack([rng.uniform(0.2, 1.8, (5, 2)), rng.uniform(-np.pi, np.pi, 5)])
    finals = []
    for world in (None, far):
        brains = []
        for rid in range(5):
            brain = AgentBrain(rid, AgentConfig())
            if world is not None:
                brain.set_world(world)
            brain.on_domain(domain(SQUARE, velocity=(0.05, 0.0)), 0.0)
            brains.append(brain)
        final, _ = run(brains, starts, 3.0, substeps=1)
        finals.append(final)
    np.testing.assert_array_equal(finals[0], finals[1])


def world_payload(world: World, seq: int, stamp: float = WALL) -> bytes:
    return to_message(world, seq, stamp).encode()


def test_the_world_broadcast_is_heard_kept_by_seq_and_steers_the_filter() -> None:
    brain = AgentBrain(0, AgentConfig())
    assert brain.receive("world", world_payload(ARENA, 1), now=0.0, now_wall=WALL)
    assert brain.world is not None and brain.workspace == WORKSPACE
    np.testing.assert_array_equal(brain.world.obstacles[0].vertices, ARENA.obstacles[0].vertices)
    assert brain.world.obstacles[0].name == "block"
    held = brain.world
    # The repeat every second changes nothing (not even the object) and is not a drop.
    assert brain.receive("world", world_payload(ARENA, 1), now=1.0, now_wall=WALL + 1.0)
    assert brain.world is held
    # An older or same-numbered different world while the sender talks: dropped, counted.
    empty = World(WORKSPACE)
    assert not brain.receive("world", world_payload(empty, 0), now=1.5, now_wall=WALL + 1.5)
    assert not brain.receive("world", world_payload(empty, 1), now=1.6, now_wall=WALL + 1.6)
    assert brain.drops.counts["old_world"] == 2
    jump = 2 + brain_module.MAX_DOMAIN_SEQ_JUMP
    assert not brain.receive("world", world_payload(empty, jump), now=1.7, now_wall=WALL + 1.7)
    assert brain.drops.counts["world_seq_jump"] == 1
    assert brain.world is held
    # Malformed and stale payloads are dropped and counted like other messages.
    assert not brain.receive("world", b"\xc1junk", now=1.8, now_wall=WALL + 1.8)
    assert brain.drops.counts["undecodable"] == 1
    late = WALL + 2.0 + brain_module.WORLD_MAX_AGE + 1.0
    assert not brain.receive("world", world_payload(empty, 2), now=2.0, now_wall=late)
    # A newer world replaces it; after the sender's silence a restarted one (seq 0) too.
    assert brain.receive("world", world_payload(empty, 2), now=2.0, now_wall=WALL + 2.0)
    assert brain.world.obstacles == ()
    silence = 2.0 + brain_module.WORLD_RESTART_SILENCE
    assert brain.receive("world", world_payload(ARENA, 0), now=silence, now_wall=WALL + silence)
    assert len(brain.world.obstacles) == 1
    assert brain.stats()["drop_old_world"] == 2


def test_a_world_the_model_refuses_is_dropped_as_bad_world() -> None:
    """A message whose geometry the model refuses (here an empty name, set past the
    message's own checks) is dropped as bad_world; the held world stays."""
    message = protocol.World(
        seq=1, stamp=WALL, obstacles=(((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)),), names=("x",)
    )
    brain = AgentBrain(0, AgentConfig())
    assert brain.on_world(message, now=0.0)
    bad = protocol.World(seq=2, stamp=WALL, obstacles=(((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)),))
    object.__setattr__(bad, "names", ("",))  # past the message's own checks
    assert not brain.on_world(bad, now=0.1)
    assert brain.drops.counts["bad_world"] == 1
    assert brain.world is not None and brain.world.obstacles[0].name == "x"


def test_domain_penetration_against_brute_force_and_shapely() -> None:
    """MessageDecoder.domain_penetration (what domain_in_obstacle compares to the slack):
    the shortest translation separating S from its deepest obstacle. Reference: that
    translation over 20000 directions (brute force); shapely confirms that moving S by the
    reference clears the obstacle, and that 1 mm less does not."""
    from covswarm.agent.decoding import MessageDecoder

    rng = np.random.default_rng(11)
    angles = np.linspace(0.0, 2.0 * np.pi, 20000, endpoint=False)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    checked = 0
    while checked < 30:
        boxes = []
        for x, y in rng.uniform(-2.0, 2.0, (rng.integers(1, 6), 2)):
            boxes.append((x, x + rng.uniform(0.05, 1.0), y, y + rng.uniform(0.05, 1.0)))
        world = World.from_boxes_and_polygons(None, boxes)
        hull = shapely.convex_hull(shapely.multipoints(rng.uniform(-2.5, 2.5, (6, 2))))
        if hull.geom_type != "Polygon" or hull.area < 1e-2:
            continue
        checked += 1
        ring = np.asarray(shapely.orient_polygons(hull).exterior.coords)[:-1]
        best, best_move, best_box = 0.0, None, None
        for obstacle in world.obstacles:
            # moving S by -t n clears O once max(S.n) - t <= min(O.n)
            needed = (ring @ directions.T).max(axis=0) - (obstacle.vertices @ directions.T).min(
                axis=0
            )
            k = int(np.argmin(needed))
            if needed[k] > best:
                best, best_move = float(needed[k]), -directions[k]
                best_box = shapely.Polygon(obstacle.vertices)
        for vertices in (ring, ring[::-1]):
            got = MessageDecoder().domain_penetration(domain(vertices.tolist()), world)
            # Any direction's translation bounds the shortest from above; the sampled
            # directions miss the best by up to ~2.5 m x 1.6e-4 rad.
            assert best - 1e-3 <= got <= best + 1e-12
        if best > 2e-3:
            moved = shapely.affinity.translate(hull, *(best_move * (best + 1e-9)))
            assert moved.intersection(best_box).area < 1e-9
            short = shapely.affinity.translate(hull, *(best_move * (best - 1e-3)))
            assert short.intersection(best_box).area > 0.0
