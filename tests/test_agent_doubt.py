"""Agents doubt what they hear (issue 21, item 2), at the brain level (sans-IO).

The probes: a forged Domain outside the workspace, one numbered 2^62, and a ring of phantom
beacons around a robot. Each must be dropped or distrusted and counted, while the real
coordinator and real neighbours keep being followed.
"""

from __future__ import annotations

import numpy as np
import pytest
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent import neighborhood
from covswarm.agent.brain import AgentBrain, AgentConfig, Decision, FollowStates

WALL = 1.7e9
WORKSPACE = (-1.0, 3.0, -1.0, 3.0)  # xmin, xmax, ymin, ymax (m)
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
OUTSIDE = [[2.5, 0.0], [3.3, 0.0], [3.3, 1.0], [2.5, 1.0]]  # the probe's x = 3.30 m


def domain(vertices: list, seq: int) -> protocol.Domain:
    return domain_message(vertices, seq=seq, stamp=WALL)


class Brain(AgentBrain):
    """An AgentBrain that keeps its last Decision (tick() returns only the command)."""

    decision: Decision | None = None

    def step(self, now: float, now_wall: float) -> Decision:
        self.decision = super().step(now, now_wall)
        return self.decision


def control(brain: Brain, now: float) -> Decision:
    """One control period as the shell runs it (tick: step, subscriptions, ...)."""
    brain.tick(float(now), WALL + float(now))
    assert brain.decision is not None
    return brain.decision


def brain_at(x: float, y: float, **config: object) -> Brain:
    brain = Brain(0, AgentConfig(**config))
    brain.on_pose(protocol.Pose(id=0, x=x, y=y, theta=0.0, stamp=WALL, seq=0), now=0.0)
    return brain


def test_a_domain_outside_the_workspace_is_dropped_and_counted() -> None:
    brain = brain_at(1.0, 1.0, workspace=WORKSPACE)
    assert brain.receive("domain", domain(SQUARE, 1).encode(), now=0.0, now_wall=WALL)
    # Forged, numbered above the real one: refused, the real one still held and followed.
    assert not brain.receive("domain", domain(OUTSIDE, 2).encode(), now=0.01, now_wall=WALL)
    assert brain.drops.counts["domain_outside_workspace"] == 1
    assert brain.stats()["drop_domain_outside_workspace"] == 1
    assert brain.domain.vertices == tuple(map(tuple, SQUARE))
    assert brain.receive("domain", domain(SQUARE, 3).encode(), now=0.05, now_wall=WALL)
    assert brain.domain.seq == 3
    # Even after the real coordinator's silence (where any number is taken) it is refused.
    assert not brain.on_domain(domain(OUTSIDE, 0), now=5.0)
    assert brain.drops.counts["domain_outside_workspace"] == 2
    # The step drives towards the real S's centroid (1, 1) from (0.5, 1.0): +x.
    brain.on_pose(protocol.Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL, seq=1), now=5.0)
    decision = brain.step(5.0, WALL)
    assert decision.reason == "running" and decision.velocity[0] > 0.0


def test_without_a_workspace_nothing_is_refused_and_it_can_be_set_later() -> None:
    brain = brain_at(1.0, 1.0)
    assert brain.on_domain(domain(OUTSIDE, 1), now=0.0)  # no workspace known: no check
    # A world broadcast (or the scenario) gives the workspace: the held domain goes too.
    brain.set_workspace(WORKSPACE)
    assert brain.domain is None
    assert brain.drops.counts["domain_outside_workspace"] == 1
    assert not brain.on_domain(domain(OUTSIDE, 2), now=0.1)
    assert brain.on_domain(domain(SQUARE, 3), now=0.2)
    # On the edge (and within the slack) is inside.
    edge = [[-1.0, -1.0], [3.0 + 1e-9, -1.0], [3.0, 3.0]]
    assert brain.on_domain(domain(edge, 4), now=0.3)
    for bad in [(0.0, 0.0, 0.0, 1.0), (0.0, float("nan"), 0.0, 1.0), (1.0, 0.0, 0.0, 1.0)]:
        with pytest.raises(ValueError, match="workspace"):
            brain.set_workspace(bad)
    brain.set_workspace(None)
    assert brain.on_domain(domain(OUTSIDE, 5), now=0.4)


def test_a_domain_numbered_2_to_the_62_does_not_lock_out_the_real_coordinator() -> None:
    brain = brain_at(1.0, 1.0)
    period = 0.05  # the coordinator's broadcast period
    forged_seen = 0
    for k in range(200):  # 10 s of the real stream, a forgery between every two broadcasts
        now = k * period
        assert brain.on_domain(domain(SQUARE, 100 + k), now=now)
        forged_seen += not brain.on_domain(domain(OUTSIDE, 2**62), now=now + 0.01)
        assert brain.domain.seq == 100 + k
    assert forged_seen == 200
    assert brain.drops.counts["domain_seq_jump"] == 200
    # A real jump within the bound is taken (broadcasts lost on the way).
    jump = brain_module.MAX_DOMAIN_SEQ_JUMP
    assert brain.on_domain(domain(SQUARE, 299 + jump), now=10.0)
    # Silence of the held stream (a restarted coordinator) still lets any number in.
    assert brain.on_domain(domain(SQUARE, 2**40), now=10.0 + brain_module.DOMAIN_RESTART_SILENCE)


def _ring(brain: AgentBrain, centre: tuple[float, float], now: float, first_id: int) -> None:
    """36 phantom beacons in a 0.12 m ring around ``centre`` (the probe of issue 21)."""
    for k in range(36):
        a = 2.0 * np.pi * k / 36
        x, y = centre[0] + 0.12 * np.cos(a), centre[1] + 0.12 * np.sin(a)
        beacon = protocol.Beacon(id=first_id + k, x=x, y=y, stamp=WALL)
        assert brain.receive("beacon", beacon.encode(), now=now, now_wall=WALL)


def _run(brain: Brain, t0: float, t1: float, dt: float = 0.1) -> list[float]:
    """Speeds (m/s) the control law gives from t0 to t1 s, the pose kept fresh."""
    speeds = []
    for now in np.arange(t0, t1, dt):
        pose = brain.pose
        brain.on_pose(
            protocol.Pose(id=0, x=pose.x, y=pose.y, theta=0.0, stamp=WALL + float(now), seq=1), now
        )
        decision = control(brain, now)
        assert decision.reason == "running"
        speeds.append(float(np.hypot(*decision.velocity)))
    return speeds


def test_phantom_beacons_hold_a_robot_still_no_longer_than_the_confirmation_time() -> None:
    brain = brain_at(0.4, 1.0)
    assert brain.on_domain(domain(SQUARE, 1), now=0.0)
    _ring(brain, (0.4, 1.0), now=0.0, first_id=100)
    confirm, trust = neighborhood.BEACON_CONFIRMATION, brain_module.BEACON_TRUST
    held = _run(brain, 0.0, trust)
    # The phantoms count in the safety filter while their beacons are fresh: the robot,
    # inside their ring, barely moves (the barrier condition with 0.12 m < the safe
    # distance permits no approach).
    assert max(held) < 0.05
    active = brain.safety_active
    assert brain.stats()["beacon_doubted"] == 0
    # Then they are beacons older than BEACON_TRUST whose AgentStates are awaited: no rows
    # of the filter (where a robot was, not where it is), still candidates of the diagram
    # until the confirmation time; each left out is counted, every step.
    doubted = _run(brain, trust + 0.1, confirm - 0.15)
    assert brain.safety_active == active
    assert brain.stats()["beacon_doubted"] == 36 * len(doubted)
    assert len(brain.neighborhood.reckoned) == 36
    free = _run(brain, confirm + 0.05, 3.0)
    # Past the confirmation time the phantoms are out of the diagram and the filter: it
    # heads for its centroid (0.6 m away) at the law's speed.
    assert min(free) > 0.3
    assert brain.safety_active == active
    assert brain.neighborhood.unconfirmed_total == 36
    assert brain.stats()["beacon_unconfirmed"] == 36
    # Renewed within CONFIRMATION_RETRY (under the 25 s beacon timeout): still doubted.
    _ring(brain, (brain.pose.x, brain.pose.y), now=3.0, first_id=100)
    assert min(_run(brain, 3.0, 3.5)) > 0.3
    assert brain.safety_active == active
    assert brain.neighborhood.unconfirmed_total == 36
    # CONFIRMATION_RETRY after the window opened, a beacon opens another (the team may
    # have changed): 1 s of doubt in 10 for forgeries that repeat their ids.
    retry = neighborhood.CONFIRMATION_RETRY
    _ring(brain, (brain.pose.x, brain.pose.y), now=retry, first_id=100)
    control(brain, retry)
    assert len(brain.neighborhood.reckoned) == 36 and not brain.neighborhood.unconfirmed
    control(brain, retry + confirm + 0.05)
    assert not brain.neighborhood.reckoned and len(brain.neighborhood.unconfirmed) == 36
    assert brain.neighborhood.unconfirmed_total == 72


def test_unconfirmed_robots_nearby_are_followed_and_taken_back_when_confirmed() -> None:
    brain = brain_at(0.4, 1.0)
    assert brain.on_domain(domain(SQUARE, 1), now=0.0)
    _ring(brain, (0.4, 1.0), now=0.0, first_id=100)
    _run(brain, 0.0, 1.5)
    assert len(brain.neighborhood.unconfirmed) == 36
    assert not brain.neighborhood.reckoned.keys() & brain.neighborhood.unconfirmed.keys()
    # Their AgentStates are followed (the nearest few): a real robot among them, whose
    # state was late, confirms itself with it and is a candidate (and obstacle) again.
    followed = brain.near_ids()[1] & brain.neighborhood.unconfirmed.keys()
    assert len(followed) == brain_module.MAX_UNCONFIRMED_FOLLOWED
    real = min(followed)
    beacon = brain.neighborhood.beacons[real]
    state = protocol.AgentState(id=real, x=beacon.x, y=beacon.y, stamp=WALL, neighbors=[])
    brain.on_agent_state(state, now=1.5)
    control(brain, 1.5)
    assert real in brain.neighborhood.reckoned and real not in brain.neighborhood.unconfirmed


def _obstacle_run(token: bool) -> tuple[Brain, tuple[float, float]]:
    """Robot 7 right ahead (+x) known from its beacon (and its agent's token if ``token``),
    robot 8 right beside (+y) from its AgentState, both closer than the safe distance;
    the velocity after 3 s."""
    brain = brain_at(0.4, 1.0)
    assert brain.on_domain(domain(SQUARE, 1), now=0.0)
    if token:
        brain.on_liveliness("agent", 7, True)
    brain.on_beacon(protocol.Beacon(id=7, x=0.52, y=1.0, stamp=WALL), now=0.0)
    state = protocol.AgentState(id=8, x=0.4, y=1.12, stamp=WALL, neighbors=[])
    for now in np.arange(0.0, 3.05, 0.1):  # the robot held where it is, its pose fresh
        brain.on_agent_state(state, now=float(now))
        brain.on_pose(
            protocol.Pose(id=0, x=0.4, y=1.0, theta=0.0, stamp=WALL + float(now), seq=1), now
        )
        decision = control(brain, now)
    return brain, decision.velocity


def test_a_beacon_with_a_live_agent_token_or_an_agent_state_stays_an_obstacle() -> None:
    brain, (vx, vy) = _obstacle_run(token=True)
    assert brain.neighborhood.unconfirmed_total == 0
    # Both still bound the velocity at 3 s: neither 7 (+x) nor 8 (+y) may be approached,
    # while the centroid (1, 1) pulls towards +x.
    assert vx <= 1e-6 and vy <= 1e-6
    # Without the token robot 7 is a phantom after BEACON_CONFIRMATION; robot 8, backed by
    # its AgentState, still holds.
    brain, (vx, vy) = _obstacle_run(token=False)
    assert brain.neighborhood.unconfirmed_total == 1
    assert vx > 0.1 and vy <= 1e-6
    # Its token gone, a robot leaves the diagram at once (as before this change).
    brain, _ = _obstacle_run(token=True)
    brain.on_liveliness("agent", 7, False)
    brain.step(3.1, WALL + 3.1)
    assert 7 not in brain.neighborhood.reckoned


def test_the_agent_command_refuses_a_bad_workspace_with_a_sentence() -> None:
    from click.testing import CliRunner

    from covswarm.agent.main import agent_command

    args = ["--id", "0", "--connect", "tcp/127.0.0.1:1", "--workspace", "0", "1", "0", "nan"]
    result = CliRunner().invoke(agent_command, args)
    assert result.exit_code == 2
    assert "Invalid value for --workspace" in result.output
    assert "Traceback" not in result.output
    args = ["--id", "0", "--connect", "tcp/127.0.0.1:1", "--state-period", "0.5"]
    result = CliRunner().invoke(agent_command, [*args, "--stale-timeout", "0.4"])
    assert result.exit_code == 2
    assert "Invalid value for --state-period" in result.output
    assert "Traceback" not in result.output


def test_a_beacon_only_robot_never_asked_for_stays_a_candidate() -> None:
    # Robots 0 (us), 8 (AgentState) and 9 (beacon only) on the line y = 1 across the
    # square: the cells are strips, 9 is no neighbour of ours and 1.4 m away, so we never
    # subscribe to its AgentState and it cannot confirm itself; it stays a candidate (it
    # is how newcomers are found), and becomes doubted only once asked for and silent.
    brain = brain_at(0.4, 1.0)
    assert brain.on_domain(domain(SQUARE, 1), now=0.0)
    brain.on_beacon(protocol.Beacon(id=9, x=1.8, y=1.0, stamp=WALL), now=0.0)
    state = protocol.AgentState(id=8, x=1.0, y=1.0, stamp=WALL, neighbors=[0])
    for now in np.arange(0.0, 3.0, 0.1):
        brain.on_agent_state(state, now=float(now))
        brain.on_pose(
            protocol.Pose(id=0, x=0.4, y=1.0, theta=0.0, stamp=WALL + float(now), seq=1), now
        )
        control(brain, now)
    assert 9 in brain.neighborhood.reckoned and 9 not in brain.neighborhood.asked
    assert brain.neighborhood.unconfirmed_total == 0


def test_a_forger_right_after_each_broadcast_does_not_hide_it() -> None:
    # A packed process hands its brains every queued domain sample in order (Pack's
    # DOMAIN_RING): newest-only, the forgery put after each real broadcast was all an agent
    # ever saw.
    from covswarm.agent.pack import DOMAIN_RING, LocalBus, Pack

    bus = LocalBus()
    brain = brain_at(1.0, 1.0, workspace=WORKSPACE)
    pack = Pack(bus, protocol.new_swarm_name(), [brain])
    for seq in (10, 11):
        for vertices, number in ((SQUARE, seq), (OUTSIDE, 2**62)):
            bus.put(protocol.domain_key(pack.swarm), domain(vertices, number).encode())
    pack.drain()
    pack.receive(0, 0.0, WALL)
    assert brain.domain is not None and brain.domain.seq == 11
    refused = brain.drops.counts["domain_seq_jump"] + brain.drops.counts["domain_outside_workspace"]
    assert refused == 2, brain.drops.counts
    assert brain.counters.coalesced == 0
    assert DOMAIN_RING >= 4


def test_a_robot_held_as_an_obstacle_is_still_followed_and_freed_by_its_next_state() -> None:
    # Robot 1 was heard next to ours, then not (our brain stopped following it, say, with
    # an empty cell outside S). Held as an obstacle where last heard, it must stay followed:
    # unfollowed, its phantom fenced our robot in for OBSTACLE_MEMORY though it had moved on.
    brain = brain_at(0.5, 1.0)
    for role in ("agent", "robot"):
        brain.on_liveliness(role, 1, True)
    assert brain.receive("domain", domain(SQUARE, 1).encode(), now=0.0, now_wall=WALL)

    def pose(now: float) -> None:
        message = protocol.Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL + now, seq=int(now))
        assert brain.receive("pose", message.encode(), now, WALL + now)

    def state(now: float, x: float) -> None:
        message = protocol.AgentState(id=1, x=x, y=1.0, stamp=WALL + now, neighbors=(0,))
        assert brain.receive("state", message.encode(), now, WALL + now)

    state(0.0, 0.75)
    control(brain, 0.0)
    assert 1 not in brain.obstacles
    for now in (2.0, 3.0):  # silent for longer than its state stays fresh
        pose(now)
        actions = brain.tick(now, WALL + now)
    assert brain.obstacles[1][:2] == (0.75, 1.0)
    (follow,) = [a for a in actions if isinstance(a, FollowStates)]
    assert 1 in follow.ids
    pose(3.5)
    state(3.5, 1.8)  # it was alive and moved on
    control(brain, 3.5)
    assert 1 not in brain.obstacles


def test_the_safety_filter_takes_obstacles_around_our_robot_not_around_one_that_vanished() -> None:
    # Robot 3 vanished first and is held where last heard, (0.2, 1.0). Our robot then moved
    # to (0.8, 1.0), 0.6 m from it, beyond SAFETY_RADIUS: the filter must leave it out, also
    # in the step where robot 1, last heard at (0.45, 1.0), 0.25 m from robot 3, vanishes.
    assert brain_module.SAFETY_RADIUS == 0.5
    brain = brain_at(0.5, 1.0)
    for rid in (1, 3):
        for role in ("agent", "robot"):
            brain.on_liveliness(role, rid, True)
    assert brain.receive("domain", domain(SQUARE, 1).encode(), now=0.0, now_wall=WALL)
    near_rows: list[np.ndarray] = []
    inputs = brain._safety_inputs

    def recording(*args):  # type: ignore[no-untyped-def]
        filtering = inputs(*args)
        near_rows.append(filtering.near)
        return filtering

    brain._safety_inputs = recording  # type: ignore[method-assign]

    def hear(now: float, ours: float, states: dict[int, float]) -> None:
        pose = protocol.Pose(id=0, x=ours, y=1.0, theta=0.0, stamp=WALL + now, seq=int(now * 10))
        assert brain.receive("pose", pose.encode(), now, WALL + now)
        for rid, x in states.items():
            state = protocol.AgentState(id=rid, x=x, y=1.0, stamp=WALL + now, neighbors=(0,))
            assert brain.receive("state", state.encode(), now, WALL + now)
        control(brain, now)

    hear(0.0, 0.5, {1: 0.9, 3: 0.2})
    hear(1.5, 0.5, {1: 0.9})  # robot 3 silent for longer than its state stays fresh
    assert brain.obstacles[3][:2] == (0.2, 1.0)
    hear(2.0, 0.8, {1: 0.45})
    hear(3.5, 0.8, {})  # robot 1 silent too: it vanishes in this step
    assert brain.obstacles[1][:2] == (0.45, 1.0)
    assert len(near_rows) == 4
    xs = near_rows[-1][:, 0].tolist()
    assert 0.45 in xs and 0.2 not in xs, xs
