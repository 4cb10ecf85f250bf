"""Agent decision logic with synthetic messages, plus one real-process run over Zenoh."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from live_runs import open_router, stop_children, watch_team
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent import neighborhood
from covswarm.agent.brain import AgentBrain, AgentConfig, Decision
from covswarm.agent.decoding import MessageDecoder
from covswarm.agent.extrapolation import extrapolate_domain
from covswarm.agent.neighborhood import cell_reach, tile_radius

WALL = 1.7e9
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]


def pose(rid: int, x: float, y: float, theta: float = 0.0) -> protocol.Pose:
    return protocol.Pose(id=rid, x=x, y=y, theta=theta, stamp=WALL, seq=0)


def domain(
    state: str = "running",
    stamp: float = WALL,
    vertices: list | None = None,
    velocity=(0.0, 0.0),
    tile_size: float | None = None,
    seq: int = 1,
) -> protocol.Domain:
    vertices = SQUARE if vertices is None else vertices
    return domain_message(
        vertices, seq=seq, stamp=stamp, state=state, velocity=velocity, tile_size=tile_size
    )


def brain_at(x: float, y: float, theta: float = 0.0, **config: object) -> AgentBrain:
    brain = AgentBrain(0, AgentConfig(**config))
    brain.on_pose(pose(0, x, y, theta), now=0.0)
    return brain


# --- pure helpers -----------------------------------------------------------------------


def test_extrapolation_moves_then_holds_still() -> None:
    d = domain(velocity=(0.1, 0.0))
    vertices, velocities = extrapolate_domain(d, 0.5, max_extrapolation=1.0)
    assert vertices == pytest.approx(np.array(SQUARE) + [0.05, 0.0])
    assert velocities == pytest.approx(np.tile([0.1, 0.0], (4, 1)))
    vertices, velocities = extrapolate_domain(d, 5.0, max_extrapolation=1.0)
    assert vertices == pytest.approx(np.array(SQUARE) + [0.1, 0.0])
    assert not velocities.any()
    vertices, _ = extrapolate_domain(d, -1.0, max_extrapolation=1.0)  # never backwards
    assert vertices == pytest.approx(np.array(SQUARE))


def test_tile_radius_grows_at_once_and_shrinks_with_margin() -> None:
    assert cell_reach(0.0, 0.04) == pytest.approx(0.4)
    assert tile_radius(0.4, 1.0, current=1, max_radius=3) == 1
    assert tile_radius(5.0, 1.0, current=1, max_radius=3) == 3  # capped
    assert tile_radius(1.6, 1.0, current=3, max_radius=3) == 2
    assert tile_radius(1.8, 1.0, current=2, max_radius=3) == 2  # 1.25 x 1.8 > 2: no flap
    assert tile_radius(0.8, 1.0, current=3, max_radius=3) == 1


# --- control decisions ------------------------------------------------------------------


def test_no_pose_or_no_domain_gives_zero() -> None:
    brain = AgentBrain(0)
    assert brain.step(0.0, WALL).reason == "no-pose"
    brain.on_pose(pose(0, 0.5, 0.5), now=0.0)
    assert brain.step(0.1, WALL).reason == "no-domain"
    brain.on_domain(domain(), now=0.0)
    assert brain.step(5.0, WALL).reason == "no-pose"  # own pose went stale


def test_a_pose_older_than_the_command_history_stops_the_robot() -> None:
    # Received just now, stamped long ago: its receipt time says nothing of its age.
    # Within the history's span the step steers from the pose predicted along the commands
    # sent since; beyond it the robot stops and the step is counted (28 Nov 2026: steered
    # from as if fresh, 1000 robots' heading loops went unstable).
    brain = AgentBrain(0, AgentConfig(max_clock_skew=5.0))
    brain.on_domain(domain(), now=0.0)
    late = brain_module.POSE_HORIZON - 0.1
    brain.on_pose(protocol.Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL - late, seq=0), 0.0)
    first = brain.step(0.0, WALL)
    assert first.reason == "running" and first.left > 0.0
    brain.command(first, WALL)  # sent: in the history
    brain.on_pose(protocol.Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL + 0.1 - late, seq=1), 0.1)
    # moved on along the first command, not the pose as taken
    assert brain.predicted_pose(WALL + 0.15)[0] > 0.5 + 1e-3
    assert brain.step(0.1, WALL + 0.1).reason == "running"
    assert brain.counters.pose_too_old == 0
    too_old = brain_module.POSE_HORIZON + 0.1
    brain.on_pose(
        protocol.Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL + 0.2 - too_old, seq=2), 0.2
    )
    decision = brain.step(0.2, WALL + 0.2)
    assert (decision.reason, decision.left, decision.right) == ("pose-too-old", 0.0, 0.0)
    assert brain.counters.pose_too_old == 1
    assert brain.stats()["pose_too_old"] == 1


def test_pose_age_is_that_of_commands_steered_from_the_pose() -> None:
    # A late brain's stop goes out a gap after its last pose (covswarm.agent.pack): counted,
    # half of an overloaded team's commands read as ~1 s old poses.
    brain = brain_at(0.5, 1.0)  # its pose stamped WALL
    brain.command(Decision(0.0, 0.0, "held"), WALL + 0.9)
    assert brain.stats()["pose_age_ms_p50"] == 0.0  # none yet
    brain.command(Decision(0.1, 0.1, "running"), WALL + 0.04)
    brain.command(Decision(0.0, 0.0, "held"), WALL + 0.9)
    assert brain.stats()["pose_age_ms_p99"] == pytest.approx(40.0)


def test_running_drives_toward_centroid() -> None:
    brain = brain_at(0.5, 1.0, theta=0.0)
    brain.on_domain(domain(), now=0.0)
    decision = brain.step(0.1, WALL)
    assert decision.reason == "running"
    assert decision.velocity[0] > 0.0  # alone in the square: centroid (1, 1) is to the right
    assert decision.left > 0.0 and decision.right > 0.0
    assert max(abs(decision.left), abs(decision.right)) <= 0.8


def test_steps_without_a_cell_are_counted() -> None:
    """A robot outside S whose Voronoi cell misses S (a teammate stands between them) has
    no cell: its mission steps so are counted (the trap that dominates e_a at 100+ robots),
    those with a cell are not."""
    brain = brain_at(-1.0, 1.0)
    brain.on_domain(domain(), now=0.0)
    teammate = protocol.AgentState(id=1, x=-0.2, y=1.0, stamp=WALL, neighbors=[0])
    brain.on_agent_state(teammate, now=0.0)
    assert brain.step(0.1, WALL).reason == "running"
    assert brain.stats()["cell_empty"] == 1
    brain.on_pose(pose(0, 0.5, 1.0), now=0.1)  # inside S now, its cell with it
    brain.step(0.15, WALL + 0.05)
    assert brain.stats()["cell_empty"] == 1 and brain.counters.mission_steps == 2


@pytest.mark.parametrize("state", ["waiting", "done"])
def test_waiting_and_done_give_zero_but_learn_neighbors(state: str) -> None:
    brain = brain_at(0.5, 0.5)
    brain.on_domain(domain(state), now=0.0)
    brain.on_pose(pose(1, 1.5, 0.5), now=0.0)
    decision = brain.step(0.1, WALL)
    assert (decision.left, decision.right, decision.reason) == (0.0, 0.0, state)
    assert brain.neighborhood.one_hop == {1}


def test_two_hop_bookkeeping() -> None:
    brain = brain_at(0.5, 1.0)
    brain.on_domain(domain(), now=0.0)
    brain.on_pose(pose(1, 1.5, 1.0), now=0.0)  # my only Voronoi neighbour in the square
    brain.on_agent_state(
        protocol.AgentState(id=1, x=1.5, y=1.0, stamp=WALL, neighbors=[0, 7, 9], stats={}),
        now=0.0,
    )
    brain.step(0.1, WALL)
    assert brain.neighborhood.one_hop == {1}
    assert brain.neighborhood.two_hop(0.1) == {1, 7, 9}
    assert brain.neighborhood.wanted_state_ids(0.1) == {1, 7, 9}
    # Robot 1 reports new neighbours: 7 and 9 linger for ``linger`` s, then go.
    brain.on_agent_state(
        protocol.AgentState(id=1, x=1.5, y=1.0, stamp=WALL, neighbors=[0], stats={}), now=0.5
    )
    assert brain.neighborhood.wanted_state_ids(0.5) == {1, 7, 9}
    assert brain.neighborhood.wanted_state_ids(1.2) == {1}
    # A stale neighbour list no longer extends the set.
    brain.on_agent_state(
        protocol.AgentState(id=1, x=1.5, y=1.0, stamp=WALL, neighbors=[0, 4], stats={}), now=1.3
    )
    assert brain.neighborhood.two_hop(1.4) == {1, 4}
    assert brain.neighborhood.two_hop(3.0) == {1}


def test_neighbor_states_are_dead_reckoned() -> None:
    """A state's position moves on with its reported velocity, for at most the limit."""
    brain = brain_at(0.5, 1.0)
    brain.on_agent_state(
        protocol.AgentState(id=1, x=1.5, y=1.0, stamp=WALL, neighbors=[0], vx=0.2, vy=-0.1),
        now=0.0,
    )
    assert brain.neighborhood.candidates(0.1)[1] == pytest.approx([1.52, 0.99])
    limit = neighborhood.DEAD_RECKONING_LIMIT
    reckoned = [1.5 + 0.2 * limit, 1.0 - 0.1 * limit]
    assert brain.neighborhood.candidates(0.9)[1] == pytest.approx(reckoned)
    # A state without a velocity (an older agent) holds its position.
    brain.on_agent_state(
        protocol.AgentState(id=2, x=0.5, y=0.5, stamp=WALL, neighbors=[0]), now=0.0
    )
    assert brain.neighborhood.candidates(0.1)[2] == pytest.approx([0.5, 0.5])


def test_own_state_reports_the_predicted_position_and_velocity() -> None:
    brain = brain_at(0.5, 1.0)  # heading 0, pose stamped WALL
    brain.on_domain(domain(velocity=(0.1, 0.0)), now=0.0)
    brain.command(Decision(0.3, 0.3, "running"), WALL)  # straight ahead at 0.3 m/s
    brain.velocity = (0.3, 500.0)  # beyond what the wire carries: clamped, not refused
    state = brain.agent_state(WALL + 0.1, stats=False)
    decoded = protocol.AgentState.decode(state.encode())
    assert (decoded.vx, decoded.vy) == (0.3, protocol.MAX_SPEED)
    # Where the command sent since the pose has taken the robot by the state's stamp.
    assert (decoded.x, decoded.y) == pytest.approx((0.5 + 0.3 * 0.1, 1.0))
    # Without prediction, the pose as taken.
    still = brain_at(0.5, 1.0, prediction=False)
    still.command(Decision(0.3, 0.3, "running"), WALL)
    assert still.agent_state(WALL + 0.1, stats=False).x == 0.5


def test_stale_poses_are_dropped() -> None:
    brain = brain_at(0.5, 1.0, stale_timeout=1.0, beacon_timeout=3.0)
    brain.on_domain(domain(), now=0.0)
    brain.on_pose(pose(1, 1.5, 1.0), now=0.0)
    assert set(brain.neighborhood.candidates(0.5)) == {1}
    brain.on_pose(pose(0, 0.5, 1.0), now=2.0)  # our own pose stays fresh
    assert brain.neighborhood.candidates(2.0) == {}
    assert brain.neighborhood.stale_dropped == 1
    brain.step(2.0, WALL)
    assert brain.neighborhood.one_hop == frozenset()


def test_far_candidates_are_left_out_of_the_local_diagram() -> None:
    brain = brain_at(0.5, 0.5)
    brain.on_domain(domain(vertices=[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]), 0.0)
    grid = [(i, j) for i in range(10) for j in range(10) if (i, j) != (0, 0)]
    for rid, (i, j) in enumerate(grid, start=1):
        brain.on_beacon(protocol.Beacon(id=rid, x=i + 0.5, y=j + 0.5, stamp=WALL), now=0.0)
    brain.step(0.1, WALL)  # no reach yet: everything known is used
    assert brain.stats()["local_set"] == 99
    # Our cell is the unit square around us: reach 2 (1.4x the true 2R), local radius 2.5 m.
    assert brain.reach == pytest.approx(2.0)
    brain.step(0.2, WALL)
    assert brain.stats()["local_set"] == sum(1 for i, j in grid if math.hypot(i, j) <= 2.5)


def test_a_density_does_not_widen_the_local_diagram() -> None:
    """Under a bump 8x the floor the cell's mass is about 8 times its area: the reach comes
    from the area, so the local set is the uniform one (from the mass: 2.9x wider reach)."""
    import dataclasses

    from covswarm.tvd.density import Density

    bump = Density(floor=1.0, means=[[0.5, 0.5]], covariances=[np.eye(2)], weights=[8.0])
    brain = brain_at(0.5, 0.5)
    square = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
    with_bump = dataclasses.replace(domain(vertices=square), density=bump.to_dict())
    assert brain.on_domain(with_bump, 0.0)
    assert brain.density is not None
    grid = [(i, j) for i in range(10) for j in range(10) if (i, j) != (0, 0)]
    for rid, (i, j) in enumerate(grid, start=1):
        brain.on_beacon(protocol.Beacon(id=rid, x=i + 0.5, y=j + 0.5, stamp=WALL), now=0.0)
    brain.step(0.1, WALL)
    # The unit square around us, centred on the bump: c = p, area 1, mass about 8.4.
    assert brain.reach == pytest.approx(2.0)
    brain.step(0.2, WALL)
    limit = 1.25 * brain.reach
    assert brain.stats()["local_set"] == sum(1 for i, j in grid if math.hypot(i, j) <= limit)
    assert brain.stats()["local_set"] <= 12


@pytest.mark.parametrize("relayed", [False, True])
def test_local_view_matches_the_full_team_law(relayed: bool) -> None:
    """Fed only what its subscriptions would deliver, an interior agent's velocity equals
    row ``me`` of the default law (TVD-DA) computed on the whole team: from its two-hop
    set's AgentStates
    (senders without relays), or from its one-hop neighbours' alone, whose relays carry
    their own neighbours' positions."""
    from covswarm.tvd.control import tvd_da
    from covswarm.tvd.coverage import neighbors

    rng = np.random.default_rng(4 if relayed else 3)
    side, spacing = 10, 0.5
    size = side * spacing
    square = [[0.0, 0.0], [size, 0.0], [size, size], [0.0, size]]
    grid = [((i + 0.5) * spacing, (j + 0.5) * spacing) for i in range(side) for j in range(side)]
    points = np.array(grid) + rng.uniform(-0.1, 0.1, (side * side, 2))
    me = 4 * side + 5 if relayed else 5 * side + 4
    brain = AgentBrain(me, AgentConfig())
    brain.on_domain(domain(vertices=square, velocity=(0.05, -0.02)), now=0.0)
    truth = neighbors(points, np.array(square))
    for k in range(5):  # subscriptions converge within a few steps
        now = 0.1 * k
        brain.on_pose(pose(me, *points[me]), now)
        tiles = brain.wanted_tiles()
        for i, (x, y) in enumerate(points):
            if protocol.tile_of(x, y, 1.0) in tiles:
                brain.on_beacon(protocol.Beacon(id=i, x=x, y=y, stamp=WALL), now)
        for i in brain.neighborhood.wanted_state_ids(now):
            relay = [(j, *points[j], 0.0, 0.0) for j in sorted(truth[i])] if relayed else None
            state = protocol.AgentState(
                id=i, x=points[i][0], y=points[i][1], stamp=WALL, neighbors=truth[i], relay=relay
            )
            brain.on_agent_state(state, now)
        decision = brain.step(now, WALL)
    expected = tvd_da(points, np.array(square), np.tile([0.05, -0.02], (4, 1)), kappa=1.0)
    assert brain.neighborhood.one_hop == truth[me]
    assert brain.stats()["local_set"] < 30  # not the whole team of 100
    assert decision.velocity == pytest.approx(tuple(expected[me]), abs=1e-9)
    if relayed:
        # The relays cover the outer ring: only the one-hop neighbours are subscribed
        # (past the linger of the first steps' larger sets).
        assert brain.neighborhood.wanted_state_ids(10.0) == set(truth[me])
        # Our own state relays our neighbours as we used them.
        relay = brain.agent_state(WALL).relay
        assert [entry[0] for entry in relay] == sorted(truth[me])
        for rid, x, y, _, _ in relay:
            assert (x, y) == pytest.approx(tuple(points[rid]))


def test_two_hop_robots_without_a_relay_get_a_subscription() -> None:
    brain = brain_at(0.0, 0.0, linger=0.0)
    brain.neighborhood.one_hop = frozenset({1})
    relay = ((0, 0.0, 0.0, 0.0, 0.0), (2, 1.0, 1.0, 0.0, 0.0))
    state = protocol.AgentState(id=1, x=0.5, y=0.0, stamp=WALL, neighbors=(0, 2, 3), relay=relay)
    brain.on_agent_state(state, now=0.0)
    assert brain.neighborhood.wanted_state_ids(0.1) == {1, 3}  # 2 is relayed, 3 is not (yet)
    bare = protocol.AgentState(id=1, x=0.5, y=0.0, stamp=WALL, neighbors=(0, 2, 3))
    brain.on_agent_state(bare, now=0.2)  # a sender without relays: all of its neighbours
    assert brain.neighborhood.wanted_state_ids(0.3) == {1, 2, 3}


def test_robots_near_a_filtering_brain_are_followed_unless_a_relay_carries_them() -> None:
    """With the safety filter on, a brain follows the AgentStates of the robots within
    SAFETY_RADIUS that no fresh relay of a neighbour carries; those a relay carries stay in
    its table (the filter's input) from the relay, with their velocities, unfollowed."""
    brain = brain_at(0.0, 0.0, linger=0.0, safety=True)
    brain.neighborhood.one_hop = frozenset({1})
    relay = ((0, 0.0, 0.0, 0.0, 0.0), (2, 0.3, 0.1, 0.05, 0.0))
    state = protocol.AgentState(id=1, x=0.2, y=0.0, stamp=WALL, neighbors=(0, 2), relay=relay)
    brain.on_agent_state(state, now=0.0)
    alone = protocol.AgentState(id=4, x=0.35, y=-0.1, stamp=WALL, neighbors=())
    brain.on_agent_state(alone, now=0.0)  # near, no neighbour of ours, in no relay
    brain.neighborhood.refresh(0.1)
    near, kept = brain.near_ids()
    assert near == {1, 2, 4} and not kept
    actions = brain.actions(Decision(0.0, 0.0, "test"), 0.1, WALL + 0.1)
    (follow,) = [a for a in actions if isinstance(a, brain_module.FollowStates)]
    assert follow.ids == {1, 4}  # 2 comes in 1's relay
    x, y, vx, vy = brain.neighborhood.reckoned[2]
    assert (x, y, vx, vy) == pytest.approx((0.3 + 0.1 * 0.05, 0.1, 0.05, 0.0))
    without = brain_at(0.0, 0.0, linger=0.0, safety=False)  # near robots are nothing to it
    without.neighborhood.one_hop = frozenset({1})
    without.on_agent_state(state, now=0.0)
    without.on_agent_state(alone, now=0.0)
    without.neighborhood.refresh(0.1)
    actions = without.actions(Decision(0.0, 0.0, "test"), 0.1, WALL + 0.1)
    (follow,) = [a for a in actions if isinstance(a, brain_module.FollowStates)]
    assert follow.ids == {1}


@pytest.mark.parametrize("listed_back", [False, True])
def test_a_neighbor_that_leaves_us_out_gets_an_early_beacon(listed_back: bool) -> None:
    brain = AgentBrain(0, AgentConfig(beacon_period=10.0, stale_timeout=10.0))
    brain.on_pose(pose(0, 0.5, 1.0), now=0.0)
    brain.on_domain(domain(), now=0.0)
    assert brain.beacon(0.0, WALL) is not None  # the first one goes out at once
    theirs = (0, 2) if listed_back else (2,)
    state = protocol.AgentState(id=1, x=1.5, y=1.0, stamp=WALL, neighbors=theirs)
    brain.on_agent_state(state, now=0.0)
    brain.step(1.0, WALL)
    assert brain.neighborhood.one_hop == {1}
    assert brain.beacon(1.0, WALL) is None  # within the grace: a relay may still tell it
    brain.step(1.0 + neighborhood.ASYMMETRY_GRACE, WALL)
    early = brain.beacon(1.0 + neighborhood.ASYMMETRY_GRACE, WALL)
    assert (early is None) == listed_back


def test_relayed_positions_rank_below_direct_ones() -> None:
    brain = brain_at(0.0, 0.0, stale_timeout=1.0)
    relay = ((2, 1.0, 1.0, 0.1, 0.0), (0, 9.0, 9.0, 0.0, 0.0), (3, 2.0, 2.0, 0.0, 0.0))
    brain.on_agent_state(
        protocol.AgentState(id=1, x=0.5, y=0.0, stamp=WALL, neighbors=(0, 2, 3), relay=relay),
        now=0.0,
    )
    seen = brain.neighborhood.candidates(0.1)
    assert 0 not in seen  # our own position relayed back to us is ignored
    assert seen[2] == pytest.approx((1.0 + 0.1 * 0.1, 1.0))  # dead-reckoned
    brain.on_agent_state(protocol.AgentState(id=2, x=1.5, y=1.0, stamp=WALL, neighbors=()), 0.0)
    assert brain.neighborhood.candidates(0.1)[2] == pytest.approx((1.5, 1.0))  # its own state wins
    brain.on_liveliness("agent", 3, alive=False)
    assert 3 not in brain.neighborhood.candidates(0.1)
    assert 2 not in brain.neighborhood.candidates(1.5)  # the relay went stale with the state


def test_beacon_candidates_until_pose_arrives() -> None:
    brain = brain_at(0.5, 1.0, stale_timeout=1.0, beacon_timeout=3.0)
    brain.on_beacon(protocol.Beacon(id=3, x=1.2, y=1.0, stamp=WALL), now=0.0)
    assert brain.neighborhood.candidates(0.1)[3] == pytest.approx([1.2, 1.0])
    brain.on_pose(pose(3, 1.4, 1.0), now=0.2)
    assert brain.neighborhood.candidates(0.3)[3] == pytest.approx([1.4, 1.0])
    # Pose stale (> 1 s): the beacon is older than the pose, so it no longer counts...
    assert 3 not in brain.neighborhood.candidates(2.0)
    # ... until a newer one arrives, which counts until beacon_timeout (3 s).
    brain.on_beacon(protocol.Beacon(id=3, x=1.3, y=1.0, stamp=WALL), now=2.1)
    assert brain.neighborhood.candidates(2.2)[3] == pytest.approx([1.3, 1.0])
    assert 3 not in brain.neighborhood.candidates(5.2)
    assert not brain.on_beacon(protocol.Beacon(id=0, x=0.0, y=0.0, stamp=WALL), now=0.0)


def test_wanted_tiles_follow_own_position() -> None:
    brain = AgentBrain(0, AgentConfig())
    assert brain.wanted_tiles() == set()
    brain.on_pose(pose(0, 0.5, -0.5), now=0.0)
    assert brain.wanted_tiles() == set()  # the swarm's tile size comes with the domain
    brain.on_domain(domain(), now=0.0)  # a domain that does not say: the default
    assert brain.wanted_tiles() == {(i, j) for i in (-1, 0, 1) for j in (-2, -1, 0)}
    brain.on_pose(pose(0, 1.5, -0.5), now=0.1)
    assert (2, 0) in brain.wanted_tiles() and (-1, 0) not in brain.wanted_tiles()


def test_the_tile_size_is_the_one_the_domain_broadcasts() -> None:
    brain = brain_at(0.5, -0.5)
    brain.on_domain(domain(tile_size=0.25), now=0.0)
    assert brain.wanted_tiles() == {(i, j) for i in (1, 2, 3) for j in (-3, -2, -1)}
    tile, _ = brain.beacon(0.0, WALL)
    assert tile == (2, -2)
    brain.on_domain(domain(stamp=WALL + 1, tile_size=2.0, seq=2), now=0.1)
    assert brain.wanted_tiles() == {(i, j) for i in (-1, 0, 1) for j in (-2, -1, 0)}


def test_domain_order_and_validation() -> None:
    # Newer means a higher sequence number, whatever the stamps say (they come from the
    # coordinator's clock); a lower one is a restarted coordinator once the held one's
    # sender has been silent for DOMAIN_RESTART_SILENCE.
    brain = brain_at(0.5, 0.5)
    assert brain.on_domain(domain(stamp=WALL + 1, seq=5), now=0.0)
    assert not brain.on_domain(domain(stamp=WALL + 2, seq=4), now=0.1)
    assert not brain.on_domain(domain(stamp=WALL + 2, seq=5), now=0.1)  # a duplicate
    assert brain.drops.counts["old_domain"] == 2
    assert brain.on_domain(domain(stamp=WALL - 5, seq=6), now=0.2)  # a clock behind
    bowtie = [[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]]
    assert not brain.on_domain(domain(stamp=WALL + 2, vertices=bowtie, seq=7), now=0.3)
    assert brain.drops.counts["bad_domain"] == 1
    assert brain.domain.seq == 6
    silence = 0.2 + brain_module.DOMAIN_RESTART_SILENCE
    assert not brain.on_domain(domain(seq=0), now=silence - 0.01)
    assert brain.on_domain(domain(seq=0), now=silence + 0.01)  # restarted coordinator
    assert brain.domain.seq == 0


def test_bad_payloads_are_counted_not_raised() -> None:
    brain = brain_at(0.5, 0.5)
    assert not brain.receive("pose", b"\xff\x00", now=0.0, now_wall=WALL)
    assert not brain.receive("domain", b"", now=0.0, now_wall=WALL)
    assert brain.drops.counts["undecodable"] == 2
    assert not brain.receive("pose", pose(5, 1.0, 1.0).encode(), now=0.0, now_wall=WALL, key_id=6)
    assert brain.drops.counts["wrong_id"] == 1
    assert brain.stats()["drop_wrong_id"] == 1
    assert brain.receive("pose", pose(5, 1.0, 1.0).encode(), now=0.0, now_wall=WALL, key_id=5)
    assert 5 in brain.neighborhood.poses


def test_failing_math_stops_the_robot(monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise IndexError("bug")

    monkeypatch.setattr(brain_module, "local_steps", boom)
    brain = brain_at(0.5, 0.5)
    brain.on_domain(domain(), now=0.0)
    decision = brain.step(0.1, WALL)
    assert (decision.left, decision.right, decision.reason) == (0.0, 0.0, "error")
    assert brain.counters.step_errors == 1


def test_nan_never_reaches_a_wheel_command() -> None:
    brain = brain_at(0.5, 0.5)
    message = brain.command(Decision(math.nan, 0.3, "running"), WALL)
    assert (message.left, message.right) == (0.0, 0.0)


def test_beacon_period_and_agent_state() -> None:
    brain = AgentBrain(0, AgentConfig(beacon_period=5.0, stale_timeout=10.0))
    assert brain.beacon(0.0, WALL) is None and brain.agent_state(WALL) is None
    brain.on_pose(pose(0, 2.5, -0.5), now=0.0)
    assert brain.beacon(0.0, WALL) is None  # no beacon before the domain gives the tiles
    brain.on_domain(domain(), now=0.0)
    tile, beacon = brain.beacon(0.0, WALL)
    assert tile == (2, -1) and beacon.id == 0
    assert brain.beacon(0.5, WALL) is None
    assert brain.beacon(4.9, WALL) is None
    assert brain.beacon(5.0, WALL) is not None
    # A new teammate's agent token: an early beacon, BEACON_MIN_PERIOD after the last one.
    brain.on_liveliness("agent", 7, True)
    assert brain.beacon(5.0 + 0.5 * brain_module.BEACON_MIN_PERIOD, WALL) is None
    assert brain.beacon(5.0 + brain_module.BEACON_MIN_PERIOD, WALL) is not None
    assert brain.beacon(5.0 + 2.0 * brain_module.BEACON_MIN_PERIOD, WALL) is None  # routine again
    brain.on_liveliness("robot", 8, True)  # robots do not beacon: nothing owed
    assert brain.beacon(5.0 + 3.0 * brain_module.BEACON_MIN_PERIOD, WALL) is None
    brain.step(8.1, WALL)
    state = brain.agent_state(WALL)
    assert protocol.AgentState.decode(state.encode()) == state
    assert state.stats["step_us_p50"] > 0.0
    slim = brain.agent_state(WALL, stats=False)
    assert slim.stats is None and len(slim.encode()) < len(state.encode()) / 4
    assert protocol.AgentState.decode(slim.encode()) == slim


def test_brains_of_a_process_share_decoding() -> None:
    payload = pose(3, 1.0, 1.0).encode()
    decoder = MessageDecoder()
    first, second = AgentBrain(0, decoder=decoder), AgentBrain(1, decoder=decoder)
    assert first.receive("pose", payload, 0.0, WALL, key_id=3)
    assert second.receive("pose", payload, 0.0, WALL, key_id=3)
    assert decoder.decode("pose", payload) is decoder.decode("pose", bytes(payload))
    assert MessageDecoder().decode("pose", payload) is not decoder.decode("pose", payload)
    bad = pose(3, 1.0, 1.0).encode()[:-1]
    for brain in (first, second):  # a failure is never cached: each brain counts its own
        assert not brain.receive("pose", bad, 0.0, WALL, key_id=3)
        assert brain.drops.counts["undecodable"] == 1


def test_a_tick_of_several_domains_checks_each_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Brains take turns, each handed every domain of the tick: with the last domain only
    remembered, every brain checked them all again. A domain's check runs once while it is
    among the last DOMAINS_REMEMBERED, and the answers are each domain's own."""
    from covswarm.agent import decoding

    checked = []
    real = decoding.validate_polygon
    monkeypatch.setattr(decoding, "validate_polygon", lambda v: checked.append(1) or real(v))
    decoder = MessageDecoder()
    small = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
    domains = [domain(seq=1), domain(seq=2, vertices=small)]
    for _ in range(5):  # five brains' turns
        for d in domains:
            assert decoder.domain_geometry(d) is None  # no density
    assert len(checked) == 2
    many = [domain(seq=k) for k in range(decoding.DOMAINS_REMEMBERED + 1)]
    for d in many:
        decoder.domain_geometry(d)
    decoder.domain_geometry(many[-1])
    assert len(checked) == 2 + len(many)
    decoder.domain_geometry(many[0])  # forgotten: checked again
    assert len(checked) == 3 + len(many)
    flat = domain(vertices=[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    for _ in range(2):  # a refused polygon is never remembered as valid
        with pytest.raises(ValueError):
            decoder.domain_geometry(flat)
    assert len(checked) == 5 + len(many)


# --- real processes ---------------------------------------------------------------------

REPO = Path(__file__).resolve().parent.parent
COVSWARM = str(Path(sys.executable).with_name("covswarm"))


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_three_robots_and_agents_over_zenoh() -> None:
    pytest.importorskip("zenoh")
    from covswarm.tvd.coverage import mass_centroid

    swarm = protocol.new_swarm_name()
    starts = [(0.3, 0.3), (0.6, 0.4), (0.4, 0.7)]
    children: list[subprocess.Popen] = []
    session, endpoint = open_router()
    try:
        poses, states = watch_team(session, swarm)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        for rid, (x, y) in enumerate(starts):
            common = ["--id", str(rid), "--connect", endpoint, "--swarm", swarm]
            robot = [COVSWARM, "robot", *common, "--x", str(x), "--y", str(y)]
            children.append(subprocess.Popen(robot, cwd=REPO, env=env))
            children.append(subprocess.Popen([COVSWARM, "agent", *common], cwd=REPO, env=env))

        def publish(state: str, seq: int) -> None:
            message = domain_message(SQUARE, seq=seq, stamp=time.time(), state=state)
            session.put(protocol.domain_key(swarm), message.encode())

        # Wait (domain "waiting") until every agent reports, i.e. sees its own pose.
        seq, deadline = 0, time.monotonic() + 60.0
        while len(states.snapshot()) < 3:
            assert time.monotonic() < deadline, "agents did not come up"
            assert all(child.poll() is None for child in children), "a child exited"
            seq += 1
            publish("waiting", seq)
            time.sleep(0.1)

        def error() -> float:
            positions = np.array([[p.x, p.y] for _, p in sorted(poses.snapshot().items())])
            _, centroids = mass_centroid(positions, np.array(SQUARE))
            return float(np.linalg.norm(positions - centroids))

        initial = error()
        still = np.array([[p.x, p.y] for _, p in sorted(poses.snapshot().items())])
        assert still == pytest.approx(np.array(starts), abs=1e-9)  # waiting: nobody moved
        end = time.monotonic() + 6.0
        while time.monotonic() < end:
            seq += 1
            publish("running", seq)
            time.sleep(0.1)
        final = error()
        assert final < 0.5 * initial, (initial, final)
        for state in states.snapshot().values():
            assert state.stats["rate_hz"] > 5.0
            assert all(state.stats[f"drop_{r}"] == 0 for r in protocol.REASONS)
            assert set(state.neighbors) <= {0, 1, 2} - {state.id}
    finally:
        codes = stop_children(children)
        session.close()
    assert codes == [0] * len(children), "children must exit cleanly on SIGTERM"


def test_sampled_gain_never_overshoots() -> None:
    """kappa unchanged at normal rates; capped so one period closes at most 80 % of the gap."""
    assert brain_module.sampled_gain(2.0, 0.1) == 2.0
    assert brain_module.sampled_gain(8.0, 0.1) == 8.0
    capped = brain_module.sampled_gain(8.0, 0.26) * 0.26
    assert capped == pytest.approx(brain_module.MAX_STEP_FRACTION)
    assert brain_module.sampled_gain(3.0, 0.0) == 3.0


def test_tick_gives_every_action_in_order_and_declares_alive_once() -> None:
    brain = AgentBrain(0)
    first = brain.tick(0.0, WALL)  # no pose yet: a stop command, no state, nothing to follow
    assert [type(a) for a in first] == [
        brain_module.SendCommand,
        brain_module.FollowStates,
        brain_module.FollowTiles,
    ]
    assert (first[0].command.left, first[0].command.right) == (0.0, 0.0)
    brain.on_domain(domain(velocity=(0.1, 0.0)), now=0.0)
    brain.on_pose(pose(0, 0.5, 0.5), now=0.0)
    brain.on_pose(pose(1, 1.5, 1.5), now=0.0)
    second = brain.tick(0.1, WALL + 0.1)
    kinds = [type(a) for a in second]
    assert kinds[0] is brain_module.SendCommand and second[0].command.left != 0.0
    assert brain_module.PublishState in kinds and brain_module.DeclareAlive in kinds
    assert kinds.index(brain_module.PublishState) < kinds.index(brain_module.FollowStates)
    assert brain_module.DeclareAlive not in [type(a) for a in brain.tick(0.2, WALL + 0.2)]
    assert brain.stop(WALL).command.left == 0.0


@pytest.mark.parametrize(
    ("rate", "state_period", "every"),
    [(10.0, 0.1, 1), (30.0, 0.1, 3), (20.0, 0.1, 2), (30.0, 0.0, 1), (5.0, 0.1, 1)],
)
def test_agent_states_go_out_at_most_every_state_period(
    rate: float, state_period: float, every: int
) -> None:
    """A control loop faster than the state period keeps stepping (a command every period)
    but publishes its AgentState, and chooses what to follow, every ``every`` periods,
    jitter of a tenth of a period included; a held period (Pack._hold) always says it
    stopped."""
    brain = brain_at(1.0, 1.0, state_period=state_period)
    brain.on_domain(domain(), now=0.0)
    rng = np.random.default_rng(3)
    period = 1.0 / rate
    published = []
    for k in range(60):
        now = k * period + rng.uniform(-0.1, 0.1) * period
        brain.on_pose(pose(0, 1.0, 1.0), now=now)
        actions = brain.tick(now, WALL + now)
        assert isinstance(actions[0], brain_module.SendCommand)
        kinds = {type(a) for a in actions}
        published.append(brain_module.PublishState in kinds)
        assert (brain_module.FollowStates in kinds) == published[-1]
        assert (brain_module.FollowTiles in kinds) == published[-1]
    assert published[0]
    gaps = np.diff(np.flatnonzero(published))
    assert set(gaps.tolist()) == {every}
    held = brain.hold(60 * period, WALL + 60 * period)
    assert [type(a) for a in held] == [brain_module.SendCommand, brain_module.PublishState]
    assert held[1].state.vx == held[1].state.vy == 0.0


def test_a_state_period_the_neighbours_would_time_out_on_is_refused() -> None:
    with pytest.raises(ValueError, match="state_period"):
        AgentBrain(0, AgentConfig(state_period=1.0, stale_timeout=1.0))
    with pytest.raises(ValueError, match="state_period"):
        AgentBrain(0, AgentConfig(state_period=-0.1))
