"""Robots face S's first motion before the mission starts: the coordinator says how S will
move (Domain.start_velocities, while waiting) and each brain turns its robot in place
toward it (AgentBrain._standing, covswarm.tvd.drive.turn_in_place)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.deploy.netsim import run_netsim
from covswarm.deploy.plan import initial_poses
from covswarm.deploy.simulate import simulate
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd.control import MIN_FIELD_SPEED, affine_field, field_directions
from covswarm.tvd.drive import TURN_TOLERANCE

WALL = 1.7e9
SQUARE = ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0))
STILL = ((0.0, 0.0),) * 4


def waiting_brain(start, theta: float, state: str = "waiting", stamp: float = WALL) -> AgentBrain:
    """Brain 0 of a robot at (1, 1) heading ``theta``, told S will move at ``start``."""
    brain = AgentBrain(0, AgentConfig())
    domain = protocol.Domain(
        seq=1, stamp=WALL, t=0.0, state=state, vertices=SQUARE, velocities=STILL, kappa=1.0,
        start_velocities=start,
    )  # fmt: skip
    assert brain.receive("domain", domain.encode(), 0.0, WALL)
    pose = protocol.Pose(id=0, x=1.0, y=1.0, theta=theta, stamp=stamp, seq=1)
    assert brain.receive("pose", pose.encode(), 0.0, WALL, key_id=0)
    return brain


def test_a_waiting_robot_facing_away_from_s_first_motion_turns_in_place() -> None:
    up = ((0.0, 0.2),) * 4  # S will translate along +y
    decision = waiting_brain(up, theta=-0.5 * math.pi).step(0.0, WALL)
    assert decision.reason == "aligning"
    assert decision.left == -decision.right != 0.0  # in place: its centre stays
    # -pi/2 to +pi/2 either way is as short; from just right of down, counter-clockwise
    decision = waiting_brain(up, theta=-0.4 * math.pi).step(0.0, WALL)
    assert decision.right > 0.0
    decision = waiting_brain(up, theta=-0.6 * math.pi).step(0.0, WALL)
    assert decision.right < 0.0
    brain = waiting_brain(up, theta=0.5 * math.pi + 0.5 * TURN_TOLERANCE)
    decision = brain.step(0.0, WALL)
    assert (decision.left, decision.right, decision.reason) == (0.0, 0.0, "waiting")
    assert brain.stats()["aligning"] == 0


def test_the_direction_is_s_motion_where_the_robot_stands() -> None:
    """A turning S (about its centre (1, 1)) moves each point its own way: a robot at
    (1, 1) + r stands where S moves perpendicular to r."""
    omega = 0.3
    start = tuple((-omega * (y - 1.0), omega * (x - 1.0)) for x, y in SQUARE)
    brain = waiting_brain(start, theta=0.0)
    for k, (x, theta, turns) in enumerate(
        [(1.8, 0.0, True), (1.8, 0.5 * math.pi, False), (1.0, 0.0, False)]
    ):  # to face +y, counter-clockwise; facing it; at the centre S does not move
        t = 2.0 * (k + 1)
        pose = protocol.Pose(id=0, x=x, y=1.0, theta=theta, stamp=WALL + t, seq=k + 2)
        assert brain.receive("pose", pose.encode(), t, WALL + t, key_id=0)
        decision = brain.step(t, WALL + t)
        assert decision.reason == ("aligning" if turns else "waiting")
        assert (decision.right > 0.0) is turns


@pytest.mark.parametrize(
    ("start", "state", "age", "reason"),
    [
        (None, "waiting", 0.0, "waiting"),  # S will not move at the start (a steered mission)
        (((0.0, 0.2),) * 4, "done", 0.0, "done"),  # only before the mission
        # not from a pose older than the prediction holds
        (((0.0, 0.2),) * 4, "waiting", 2.1, "pose-too-old"),
    ],
)
def test_no_turn_without_a_start_motion_a_wait_or_a_recent_pose(
    start, state: str, age: float, reason: str
) -> None:
    brain = waiting_brain(start, theta=-0.5 * math.pi, state=state)
    decision = brain.step(0.5, WALL + age)  # the pose received 0.5 s ago, stamped ``age``
    assert (decision.left, decision.right) == (0.0, 0.0) and decision.reason == reason
    if age:  # nor on the steps between two idle ones
        decision = brain.step(0.6, WALL + age + 0.1)
        assert (decision.left, decision.right) == (0.0, 0.0) and decision.reason == state


def test_a_team_waiting_for_the_circle_starts_facing_s_motion() -> None:
    """Real brains and robot models (covswarm.deploy.netsim), headings at random: at the
    first sample of the mission every robot faces the way S starts to move."""
    scenario = load_scenario("circle")
    result = run_netsim(scenario, agents=30, duration=0.2, warmup=3.0)
    vx, vy = scenario.domain(0.0)[1].mean(axis=0)
    direction = math.atan2(vy, vx)

    def error(headings: np.ndarray) -> np.ndarray:
        return np.abs(np.remainder(headings - direction + math.pi, math.tau) - math.pi)

    assert np.abs(error(result.headings[0])).max() <= TURN_TOLERANCE + 0.02
    away = error(initial_poses(scenario, 30, 0)[:, 2]) > TURN_TOLERANCE
    assert away.sum() >= 25  # headings at random: most started facing elsewhere
    turned = np.array([result.stats[i]["aligning"] > 0 for i in range(30)])
    assert np.array_equal(turned, away)


@pytest.mark.parametrize("seed", range(4))
def test_field_directions_are_those_of_a_rigid_motion_of_s(seed: int) -> None:
    """S turning at omega about c while c moves at u: each point q moves at
    u + omega x (q - c) (independent of the fit), and has no direction within
    MIN_FIELD_SPEED / |omega| of the instantaneous centre of rotation."""
    rng = np.random.default_rng(seed)
    centre, u = rng.uniform(-1.0, 1.0, 2), rng.uniform(-0.3, 0.3, 2)
    omega = float(rng.uniform(-0.5, 0.5))
    angles = np.sort(rng.uniform(0.0, math.tau, 6))
    vertices = centre + np.column_stack([np.cos(angles), np.sin(angles)])
    rigid = lambda q: u + omega * np.column_stack([-(q[:, 1] - centre[1]), q[:, 0] - centre[0]])  # noqa: E731
    points = centre + rng.uniform(-1.0, 1.0, (200, 2))
    directions = field_directions(affine_field(vertices, rigid(vertices)), points)
    velocity = rigid(points)
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    moving = speed >= MIN_FIELD_SPEED
    assert np.array_equal(np.isnan(directions), ~moving)
    expected = np.arctan2(velocity[moving, 1], velocity[moving, 0])
    np.testing.assert_allclose(
        np.remainder(directions[moving] - expected + math.pi, math.tau) - math.pi, 0.0, atol=1e-9
    )
    # the instantaneous centre of rotation, where S stands still
    pivot = centre + np.array([-u[1], u[0]]) / omega
    still = field_directions(affine_field(vertices, rigid(vertices)), pivot[None, :])
    assert np.isnan(still[0])


def test_the_simulation_can_start_its_robots_facing_s_motion() -> None:
    scenario = load_scenario("circle")
    facing = simulate(scenario, agents=20, duration=0.1, dynamics="unicycle", face_start=True)
    at_random = simulate(scenario, agents=20, duration=0.1, dynamics="unicycle")
    vx, vy = scenario.domain(0.0)[1].mean(axis=0)  # the circle's S translates
    np.testing.assert_allclose(facing.headings[0], math.atan2(vy, vx), atol=1e-12)
    assert np.ptp(at_random.headings[0]) > 1.0
    np.testing.assert_array_equal(facing.trajectories[0], at_random.trajectories[0])
    with pytest.raises(ValueError, match="not both"):
        simulate(
            scenario, agents=2, duration=0.1, dynamics="unicycle", heading=0.0, face_start=True
        )


def test_at_the_end_of_a_deploy_hold_a_running_robot_faces_s_start_then_steps() -> None:
    """A running S held still that announces its start (the end of a deploy hold,
    covswarm.coordinator.pace.DEPLOY_ALIGN): the robot turns in place to face it instead of
    stepping the law, and says "aligned" once it does; the step after S starts is the
    mission's first (no period measured yet, so its command is not capped to one)."""
    up = ((0.0, 0.2),) * 4
    decision = waiting_brain(up, theta=-0.5 * math.pi, state="running").step(0.0, WALL)
    assert decision.reason == "aligning" and decision.left == -decision.right != 0.0
    brain = waiting_brain(up, theta=0.5 * math.pi, state="running")
    for k in range(3):  # steps of the law before (as in the hold) change nothing
        decision = brain.step(0.1 * k, WALL + 0.1 * k)
        assert (decision.left, decision.right, decision.reason) == (0.0, 0.0, "aligned")
    released = protocol.Domain(
        seq=2, stamp=WALL + 0.3, t=0.3, state="running", vertices=SQUARE, velocities=up,
        kappa=1.0,
    )  # fmt: skip
    assert brain.receive("domain", released.encode(), 0.3, WALL + 0.3)
    decision = brain.step(0.3, WALL + 0.3)
    assert decision.reason == "running" and brain.command_hold == 0.0
