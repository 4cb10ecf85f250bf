"""A neighbour whose brain stalls (its process starved for seconds) stays in the safety
filter where it stopped, whatever else still names it (AgentBrain._safety_inputs).

Its AgentStates stop and its robot stops at its command's timeout. Once its last state is
older than our stale horizon (AgentBrain.pace) it is no longer known first-hand; a robot we
heard first-hand nearby and then not at all was held as an obstacle where last reckoned,
but this one was still named: by a neighbour's relay (gone a turn later, when the relayer
drops it too) or by its last beacon (sent in the turn of its last state, so its newest
news; an old beacon is no row while its state is awaited, BEACON_TRUST). Either way the
filter had no row for it at some step, and the follower drove at the unseen speed limit
(0.087 m/s here) into the stopped robot (deploy.netsim circle-400, one process's brains
stalled 2.5 s: 0.104 m; the live circle-1000 at ~1 Hz: 0.115 m).
"""

from __future__ import annotations

import pytest
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, AgentConfig, Decision, FollowStranded
from covswarm.agent.neighborhood import Liveliness
from covswarm.agent.pack import LocalBus, Pack
from covswarm.tvd import control

WALL = 1.7e9
# A strip S moving +x at 0.1 m/s. Our robot at (X, 1) is at its cell's centroid with robot
# 1 at (AHEAD, 1), 0.19 m ahead (D = 0.16 m): S's feedforward drives us into it. Robot 2,
# far ahead, relays robot 1 in the "relay" case.
STRIP = [[0.4, 0.8], [2.0, 0.8], [2.0, 1.2], [0.4, 1.2]]
X, AHEAD, FAR = 0.495, 0.685, 1.8
GAP = 1.0  # s between our turns (a brain stepped at ~1 Hz)


class Brain(AgentBrain):
    """An AgentBrain that keeps its last Decision and its last turn's actions."""

    decision: Decision | None = None
    asked: list = []

    def step(self, now: float, now_wall: float) -> Decision:
        self.decision = super().step(now, now_wall)
        return self.decision

    def tick(self, now: float, now_wall: float) -> list:
        self.asked = super().tick(now, now_wall)
        return self.asked


def turn(brain: Brain, now: float, relayed: bool | None) -> float:
    """One turn at ``now``: S, our pose (facing +x), robot 2's fresh state (relaying robot
    1 when ``relayed``; None: no robot 2); the step's filtered speed along +x (m/s)."""
    wall = WALL + now
    domain = domain_message(STRIP, seq=int(now * 10), stamp=wall, velocity=(0.1, 0.0))
    brain.receive("domain", domain.encode(), now, wall)
    pose = protocol.Pose(id=0, x=X, y=1.0, theta=0.0, stamp=wall, seq=int(now * 10))
    brain.receive("pose", pose.encode(), now, wall, key_id=0)
    if relayed is not None:
        relay = ((1, AHEAD, 1.0, 0.0, 0.0),) if relayed else None
        neighbors = (0, 1) if relayed else (0,)
        state = protocol.AgentState(
            id=2, x=FAR, y=1.0, stamp=wall, neighbors=neighbors, vx=0.0, vy=0.0, relay=relay
        )
        brain.receive("state", state.encode(), now, wall, key_id=2)
    brain.pace(GAP)
    brain.tick(now, wall)
    assert brain.decision is not None and brain.decision.reason == "running"
    return brain.decision.velocity[0]


@pytest.mark.parametrize("named_by", ["beacon", "relay"])
def test_a_stalled_neighbour_stays_a_row_while_only_others_name_it(named_by: str) -> None:
    brain = Brain(0, AgentConfig(cmd_timeout=1.0))
    # Robot 1's last state (and, in the beacon case, a beacon of the same turn); then its
    # brain stalls: its robot stands where it said.
    state = protocol.AgentState(id=1, x=AHEAD, y=1.0, stamp=WALL, neighbors=(0,), vx=0.0, vy=0.0)
    brain.receive("state", state.encode(), 0.1, WALL + 0.1, key_id=1)
    if named_by == "beacon":
        beacon = protocol.Beacon(id=1, x=AHEAD, y=1.0, stamp=WALL)
        brain.receive("beacon", beacon.encode(), 0.1, WALL + 0.1, key_id=1)
    relayer = True if named_by == "relay" else None
    for now in (0.5, 1.5):  # its state fresh: it holds us back (~0.02 m/s)
        assert turn(brain, now, relayer) < 0.04
    # At 2.5 s its state is past our horizon (two gaps): named by the relay or the beacon
    # only. At 3.5 s the relayer no longer relays it.
    for now in (2.5, 3.5):
        speed = turn(brain, now, False if relayer and now > 3.0 else relayer)
        assert 1 not in brain.neighborhood.first_hand
        assert speed < 0.04  # (without the obstacle: 0.087 m/s, the unseen speed limit)
    assert brain.stats()["obstacles_kept"] == 1  # counted once, when it stopped being first-hand


def test_a_stalled_neighbour_is_held_where_its_robot_stops() -> None:
    """A robot driving at us when its brain stalls drives on until its command timeout
    (1 s here): held there, not where our last step reckoned it (at most
    DEAD_RECKONING_LIMIT, 0.5 s, on)."""
    timeout, gap, speed = 1.0, 0.3, -0.05
    brain = Brain(0, AgentConfig(cmd_timeout=timeout))
    start = AHEAD + 0.05
    state = protocol.AgentState(id=1, x=start, y=1.0, stamp=WALL, neighbors=(0,), vx=speed, vy=0.0)
    brain.receive("state", state.encode(), 0.05, WALL + 0.05, key_id=1)
    now = 0.1
    while 1 in brain.neighborhood.first_hand or now < 0.2:
        wall = WALL + now
        domain = domain_message(STRIP, seq=int(now * 10), stamp=wall, velocity=(0.1, 0.0))
        brain.receive("domain", domain.encode(), now, wall)
        pose = protocol.Pose(id=0, x=X, y=1.0, theta=0.0, stamp=wall, seq=int(now * 10))
        brain.receive("pose", pose.encode(), now, wall, key_id=0)
        brain.pace(gap)
        brain.tick(now, wall)
        now += gap
        assert now < 3.0
    assert brain.stats()["obstacles_kept"] == 1
    x, y, _ = brain.obstacles[1]
    assert x == pytest.approx(start + timeout * speed, abs=1e-9)
    assert y == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("orphan", [True, False])
def test_a_robot_whose_brain_died_is_held_for_as_long_as_its_robot_lives(orphan: bool) -> None:
    """Robot 1's agent token goes while its robot's stays (``orphan``): its robot stands
    where its command timeout stopped it, with no brain to move it again, and stays a row
    of our filter past OBSTACLE_MEMORY; until its robot's token goes too. A neighbour that
    merely fell silent (no token change) is forgotten after OBSTACLE_MEMORY, as before."""
    from covswarm.agent.brain import OBSTACLE_MEMORY

    brain = Brain(0, AgentConfig(cmd_timeout=1.0))
    for role in ("agent", "robot"):
        brain.on_liveliness(role, 1, True)
    state = protocol.AgentState(id=1, x=AHEAD, y=1.0, stamp=WALL, neighbors=(0,), vx=0.0, vy=0.0)
    brain.receive("state", state.encode(), 0.1, WALL + 0.1, key_id=1)
    assert turn(brain, 0.5, None) < 0.04
    if orphan:
        brain.on_liveliness("agent", 1, False)
    now = 1.5
    while now < OBSTACLE_MEMORY + 5.0:
        speed = turn(brain, now, None)
        now += GAP
    assert (1 in brain.obstacles) is orphan
    assert (speed < 0.04) is orphan, speed  # forgotten: the unseen speed limit, 0.087 m/s
    brain.on_liveliness("robot", 1, False)
    turn(brain, now, None)
    assert 1 not in brain.obstacles


def stranded_follows(brain: Brain) -> list[frozenset[int]]:
    """The FollowStranded asked in ``brain``'s last turn (at most one)."""
    return [action.ids for action in brain.asked if isinstance(action, FollowStranded)]


@pytest.mark.parametrize("then", ["robot_dies", "agent_returns"])
def test_a_robot_with_no_brain_is_an_obstacle_to_a_robot_that_never_knew_it(then: str) -> None:
    """Robot 1 stands 0.19 m ahead; its token lives and its agent's never appeared to us
    (we arrived after its brain died): we never had a state of it, so nothing kept it
    (_still_there). Once that has lasted longer than the command timeout (its robot has
    stopped), we follow its robot's pose and it is a still row of our filter: without
    it, we drive at the unseen speed limit (0.087 m/s) into it."""
    brain = Brain(0, AgentConfig(cmd_timeout=1.0))
    brain.on_liveliness("robot", 1, True)
    assert turn(brain, 0.5, None) > 0.08  # stranded for 0 s: not followed yet
    assert stranded_follows(brain) == []
    assert turn(brain, 1.5, None) > 0.08 and stranded_follows(brain) == []  # 1 s: not over
    assert turn(brain, 2.5, None) > 0.08  # no pose of it yet
    assert stranded_follows(brain) == [frozenset({1})]
    pose = protocol.Pose(id=1, x=AHEAD, y=1.0, theta=0.0, stamp=WALL + 2.6, seq=1)
    assert brain.receive("stranded", pose.encode(), 2.6, WALL + 2.6, key_id=1)
    for now in (3.5, 4.5):
        assert turn(brain, now, None) < 0.04
        assert stranded_follows(brain) == []  # (asked again only when it changes)
    assert 1 not in brain.neighborhood.reckoned  # a row, never a cell or a relay
    other = protocol.Pose(id=3, x=AHEAD, y=1.0, theta=0.0, stamp=WALL + 4.6, seq=1)
    assert not brain.receive("stranded", other.encode(), 4.6, WALL + 4.6, key_id=3)
    if then == "robot_dies":
        brain.on_liveliness("robot", 1, False)
    else:  # it is a teammate again; once its state comes, a first-hand row
        brain.on_liveliness("agent", 1, True)
    assert turn(brain, 5.5, None) > 0.08  # no longer a stranded row, from this turn
    assert stranded_follows(brain) == [frozenset()]


class Viewing(Brain):
    """A Brain that keeps the local view of its last step."""

    view = None

    def begin(self, now: float, now_wall: float):
        begun = super().begin(now, now_wall)
        self.view = getattr(begun, "view", None)
        return begun


@pytest.mark.parametrize("safety", [True, False])
def test_a_stranded_robot_is_a_still_generator_of_the_local_diagram(safety: bool) -> None:
    """Followed (with the filter or without), robot 1's own pose is in our local view as a
    still generator (covswarm.tvd.control's ``still``): its cell bounds ours, so our
    centroid is on our side of it; it is not a one-hop neighbour we would follow or
    expect an answer from. Its robot's token gone, it leaves the view."""
    brain = Viewing(0, AgentConfig(cmd_timeout=1.0, safety=safety))
    brain.on_liveliness("robot", 1, True)
    for now in (0.5, 1.5, 2.5):
        turn(brain, now, None)
        assert brain.view is not None and brain.view.still == frozenset()
    assert stranded_follows(brain) == [frozenset({1})]
    pose = protocol.Pose(id=1, x=AHEAD, y=1.0, theta=0.0, stamp=WALL + 2.6, seq=1)
    assert brain.receive("stranded", pose.encode(), 2.6, WALL + 2.6, key_id=1)
    turn(brain, 3.5, None)
    view = brain.view
    assert view.still == frozenset({1}) and tuple(view.positions[1]) == (AHEAD, 1.0)
    assert 1 not in brain.neighborhood.one_hop
    # Our cell ends at the bisector with it: its centroid is behind that, the strip's
    # centroid (1.2, 1) is not.
    step = control.local_step(
        0, view.positions, view.polygon, view.polygon_velocity, view.kappa, still=view.still
    )
    assert step.centroid[0] < (X + AHEAD) / 2 and 1 in step.neighbors
    brain.on_liveliness("robot", 1, False)
    turn(brain, 4.5, None)
    assert brain.view.still == frozenset() and 1 not in brain.view.positions


def test_the_process_knows_which_robots_live_without_their_agent() -> None:
    alive = Liveliness()
    alive.change("robot", 1, True)
    alive.change("robot", 2, True)
    alive.change("agent", 2, True)
    assert alive.orphans == {1}
    alive.change("agent", 1, True)
    assert alive.orphans == set()
    alive.change("agent", 2, False)
    assert alive.orphans == {2}
    alive.change("robot", 2, False)
    alive.change("agent", 3, False)  # an agent without a robot: no orphan
    assert alive.orphans == set()
    alive.change("coordinator", 4, True)  # other roles are not robots
    assert alive.orphans == set()


def test_a_pack_follows_a_stranded_robots_pose_for_its_brain() -> None:
    """The pack subscribes to the pose key of the robot its brain asks for (never to its
    own brains' robots' under that name) and hands its poses over as "stranded"."""
    bus = LocalBus()
    brain = AgentBrain(0)
    pack = Pack(bus, "s", [brain])
    heard: list[tuple[str, int | None]] = []

    def receive_all(items, now, wall):  # type: ignore[no-untyped-def]
        heard.extend((kind, key_id) for kind, key_id, _ in items)
        return 0

    brain.receive_all = receive_all  # type: ignore[method-assign]
    pack.carry_out(0, FollowStranded(frozenset({0, 1})))
    key = protocol.pose_key("s", 1)
    assert pack.followers(key) == {0}
    bus.put(key, protocol.Pose(id=1, x=1.0, y=1.0, theta=0.0, stamp=WALL, seq=1).encode())
    pack.drain()
    pack.receive(0, 0.0, WALL)
    assert heard == [("stranded", 1)]
    pack.carry_out(0, FollowStranded(frozenset()))
    assert pack.followers(key) == frozenset() and key not in bus._exact
