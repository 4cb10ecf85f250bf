"""The coordinator core and its outputs against the arena: the World broadcast (at start,
then every second), steering swept against obstacles, goto, phantom ids (Roster), the
requester's rate limit, and summary.json's arena keys and domain.csv."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from warehouse_core import SWARM, WALL0, join, make_core, run_until_started, steer, warehouse

from covswarm.coordinator.core import (
    WAITING,
    WORLD_PERIOD,
    PublishWorld,
)
from covswarm.coordinator.outputs import build_summary, run_goals, write_run_outputs
from covswarm.protocol import AgentState, Pose, World, agent_state_key, pose_key
from covswarm.protocol.steering import SteerRequest
from covswarm.world.wire import from_message


def test_the_world_is_broadcast_before_the_start_and_every_second() -> None:
    core = make_core()
    sent = []
    now = 0.0
    for _ in range(int(4.0 / 0.05)):
        worlds = [a.world for a in core.tick(now, WALL0 + now) if isinstance(a, PublishWorld)]
        sent += [(now, w) for w in worlds]
        if now == 0.0:
            assert worlds and core.phase.state == WAITING  # the first tick, before the start
        now = round(now + 0.05, 10)
    times = [when for when, _ in sent]
    assert times == pytest.approx([0.0, 1.0, 2.0, 3.0]) and WORLD_PERIOD == 1.0
    message = World.decode(sent[-1][1].encode())
    assert message.stamp == pytest.approx(WALL0 + 3.0) and message.seq == 0
    world = from_message(message)
    assert world.workspace == warehouse().world.workspace
    assert [o.name for o in world.obstacles] == [o.name for o in warehouse().world.obstacles]
    for a, b in zip(world.obstacles, warehouse().world.obstacles, strict=True):
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-12)


def test_steering_into_a_shelf_is_refused_and_goto_is_planned() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    # S (x in [-3.7, -1.3], y in [-1.1, 0.5]) moved 1.2 m north runs into shelf 1.
    reply = steer(core, SteerRequest("translate", dx=0.0, dy=1.2), now)
    assert not reply.accepted and reply.reason.startswith("obstacle: S would touch obstacle")
    assert "'shelf 1'" in reply.reason
    reply = steer(core, SteerRequest("goto", goal=(2.0, 0.3)), now)
    assert reply.accepted, reply.reason
    assert reply.route[-1] == pytest.approx((2.0, 0.3, 1.0))
    assert min(stop[2] for stop in reply.route) < 0.7  # shrunk for the 1.1 m door
    # Straight through the wall south: refused, naming it.
    core2 = make_core()
    now2 = run_until_started(core2) + 0.5
    steer(core2, SteerRequest("translate", dx=0.0, dy=-0.4), now2)
    wall = steer(core2, SteerRequest("translate", dx=4.0, dy=0.0), now2 + 20.0)
    assert not wall.accepted and "'wall south'" in wall.reason
    assert core2.steering.refused["obstacle"] == 1


def test_phantom_ids_are_counted_not_team_members() -> None:
    core = make_core(agents=2)
    join(core, [0, 1, 7])  # 7 is nobody the launcher started
    core.on_pose(pose_key(SWARM, 7), Pose(7, 0.0, 0.0, 0.0, WALL0, 1).encode())
    core.on_pose(pose_key(SWARM, 0), Pose(0, -2.0, 0.0, 0.0, WALL0, 1).encode())
    state = AgentState(7, 0.0, 0.0, WALL0, (), stats={"rate_hz": 10.0})
    core.on_agent_state(agent_state_key(SWARM, 7), state.encode())
    assert core.observed.liveness.count("agent") == 2 and core.team_ready()
    assert set(core.alive_positions()) == {0}
    assert 7 not in core.observed.agent_stats
    counts = core.roster.summary()["counts"]
    assert counts == {"token_agent": 1, "token_robot": 1, "pose": 1, "state": 1}


def test_steering_is_rate_limited_per_requester() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    request = SteerRequest("scale", factor=1.0)
    answers = [steer(core, request, now, "flood").reason for _ in range(12)]
    assert sum(a.startswith("rate-limited") for a in answers) == 2  # a burst of 10
    assert not steer(core, request, now, "operator").reason.startswith("rate-limited")


def test_run_goals_windows() -> None:
    """Scenario goals count until the first accepted request; a goto's goal from its
    acceptance until the next accepted one."""
    square = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    t = np.arange(0.0, 10.0, 1.0)
    centres = [(0, 0), (1, 0), (2, 0), (2, 0), (2, 1), (3, 3), (3, 3), (4, 4), (5, 5), (5, 5)]
    polygons = [square + c for c in centres]
    core = make_core()
    now = run_until_started(core)
    assert steer(core, SteerRequest("goto", goal=(-2.5, -0.3)), now + 3.5).accepted
    assert steer(core, SteerRequest("translate", dx=-0.1, dy=0.0), now + 6.5).accepted
    goals, times = run_goals(t, polygons, ((1.0, 0.0), (2.0, 1.0)), core.steering)
    assert goals == [(1.0, 0.0), (2.0, 1.0), (-2.5, -0.3)]
    # the second scenario goal comes after the goto took over; the goto never arrived
    assert times == [1.0, None, None]


def test_summary_has_the_arena_keys_and_domain_csv(tmp_path: Path) -> None:
    core = make_core(agents=2, duration=40.0)
    now = run_until_started(core)
    reply = steer(core, SteerRequest("goto", goal=(-2.0, -0.2)), now + 0.1)
    assert reply.accepted
    end = now + 0.1 + reply.duration + 1.0
    while now < end:
        now = round(now + 0.05, 10)
        for i, x in enumerate((-2.3, -1.7)):
            core.on_pose(pose_key(SWARM, i), Pose(i, x, -0.2, 0.0, WALL0 + now, 1).encode())
        # robot 1's key carrying a pose that says robot 0: dropped, counted
        core.on_pose(pose_key(SWARM, 1), Pose(0, 2.0, 2.0, 0.0, WALL0 + now, 1).encode())
        core.tick(now, WALL0 + now)
    summary = build_summary(core.settings, core.observed, core.steering, {"stopped": None})
    assert summary["wrong_id_messages"] > 0 and summary["min_obstacle_clearance"] > 1.0
    # The warehouse's own goal (pre-empted at once) and the goto's, reached.
    assert summary["goal_list"] == [[2.7, 0.1], [-2.0, -0.2]]
    assert summary["goals"] == 2 and summary["goals_reached"] == 1
    assert summary["goal_times"][0] is None
    arrival = core.steering.records[-1].t + reply.duration
    assert arrival - 0.11 <= summary["goal_times"][1] <= arrival + 0.11  # 10 Hz samples
    assert summary["obstacle_contacts"] == 0 and summary["domain_obstacle_overlap"] == 0.0
    assert summary["min_obstacle_clearance"] == pytest.approx(1.53, abs=0.01)  # to wall south
    assert summary["unexpected"]["total"] == 0 and summary["steering_omitted"] == 0
    assert summary["recorder_disk"] == {"stopped": None}
    write_run_outputs(tmp_path, core.settings, core.observed, core.steering)
    rows = np.loadtxt(tmp_path / "domain.csv", delimiter=",", skiprows=1)
    assert rows.shape[1] == 4 and set(rows[:, 1]) >= {0, 1, 2, 3}
    assert json.loads((tmp_path / "summary.json").read_text())["goals_reached"] == 1
