"""Liveliness token changes against the data that crosses them in a packed agent process
(covswarm.agent.pack.Pack.drain, covswarm.agent.neighborhood.Liveliness). Sans-IO, over
the in-memory LocalBus; the races are staged deterministically by a token source that
lets a payload land on the bus while the pack drains (as Zenoh's threads do)."""

from __future__ import annotations

from collections.abc import Callable

from covswarm import protocol
from covswarm.agent.brain import AgentBrain
from covswarm.agent.pack import LocalBus, Pack

SWARM = "t"
WALL = 1.7e9


class LandingTokens:
    """A liveliness source whose changes are already there, and before whose first read
    ``landing`` runs: what reached the process while it drained its data subscribers."""

    def __init__(self, changes: list[tuple[str, bool]], landing: Callable[[], None] | None) -> None:
        self.changes, self.landing = list(changes), landing

    def try_recv(self) -> tuple[str, bool] | None:
        if self.landing is not None:
            landing, self.landing = self.landing, None
            landing()
        return self.changes.pop(0) if self.changes else None


def _state(rid: int, stamp: float) -> bytes:
    return protocol.AgentState(id=rid, x=1.0, y=1.0, stamp=stamp, neighbors=()).encode()


def _turn(pack: Pack, brain: AgentBrain, t: float) -> set[int]:
    """One control period of the pack's only brain at ``t`` s: drain, its data and token
    changes (Pack.receive), its neighbourhood reckoned; the robots it would use."""
    pack.drain()
    pack.receive(brain.id, t, WALL + t)
    brain.neighborhood.refresh(t)
    return set(brain.neighborhood.reckoned)


def _pack_following(rid: int) -> tuple[LocalBus, Pack, AgentBrain]:
    bus = LocalBus()
    brain = AgentBrain(0)
    pack = Pack(bus, SWARM, [brain])
    pack.follow(0, "state", frozenset({rid}))
    return bus, pack, brain


def test_a_dead_agents_last_state_landing_while_the_pack_drains_does_not_revive_it() -> None:
    """Agent 3 sends a state and is SIGKILLed. The state and then its token's deletion
    reach the process in that order (one router link), but the state lands in its ring
    after the pack drained the data subscribers and the deletion before it drains the
    token changes. The brain applies the deletion this turn and the state at its next
    turn, as data heard after the deletion: agent 3 is revived and used (and named as
    a neighbour) until that state is stale, ~1 s after the kill (the 0.5 s bound of
    tests/test_faults.py::test_dead_brain_dead_robot_and_a_newcomer). Pack.receive says
    the opposite is meant: a last message of a process that has just died must not
    revive it."""
    bus, pack, brain = _pack_following(3)
    key = protocol.agent_state_key(SWARM, 3)
    bus.put(key, _state(3, WALL))
    assert 3 in _turn(pack, brain, 0.0)

    def last_state_lands() -> None:
        bus.put(key, _state(3, WALL + 0.05))  # sent before the kill

    pack._token_changes = LandingTokens(
        [(protocol.alive_key(SWARM, "agent", 3), False)], last_state_lands
    )
    assert 3 not in _turn(pack, brain, 0.1)  # the deletion: dropped at once
    assert 3 not in _turn(pack, brain, 0.2)  # its last state must not bring it back
    assert 3 not in _turn(pack, brain, 0.3)


def test_the_same_state_drained_with_the_deletion_does_not_revive_it() -> None:
    """The same state landing before the pack drains its data: applied before the brain
    catches up on the deletion, it does not revive agent 3 (what the race above breaks)."""
    bus, pack, brain = _pack_following(3)
    key = protocol.agent_state_key(SWARM, 3)
    bus.put(key, _state(3, WALL))
    assert 3 in _turn(pack, brain, 0.0)
    bus.put(key, _state(3, WALL + 0.05))
    pack._token_changes = LandingTokens([(protocol.alive_key(SWARM, "agent", 3), False)], None)
    assert 3 not in _turn(pack, brain, 0.1)
    assert 3 not in _turn(pack, brain, 0.2)


def test_a_robot_token_deleted_unseen_keeps_it_out_against_its_living_agents_states() -> None:
    """Robot 1's token predates the liveliness subscriber (no PUT ever seen) and vanishes
    while its agent lives on and keeps sending states: the deletion alone keeps robot 1
    out, and no AgentState revives a robot role (only its own pose could). So a robot
    still used ~2 s after its kill means the deletion never reached the pack (or a PUT of
    its token followed it), not a race in the bookkeeping."""
    bus, pack, brain = _pack_following(1)
    key = protocol.agent_state_key(SWARM, 1)
    bus.put(key, _state(1, WALL))
    assert 1 in _turn(pack, brain, 0.0)
    pack._token_changes = LandingTokens(
        [(protocol.alive_key(SWARM, "robot", 1), False)],
        lambda: bus.put(key, _state(1, WALL + 0.05)),
    )
    for k in range(1, 12):
        t = 0.1 * k
        bus.put(key, _state(1, WALL + t))  # agent 1 lives on (its pose fresh for 1 s)
        assert 1 not in _turn(pack, brain, t)


def test_a_brain_that_has_not_stepped_since_a_death_does_not_name_the_dead_robot() -> None:
    """Robot 1 is a Voronoi neighbour at a step; its token vanishes; the brain's next
    AgentStates come without a step in between (a hold in an overloaded pack, or a step
    that ends early: the neighbour set stays as the last full step found it): they do not
    name robot 1 and still name robot 2."""
    brain = AgentBrain(0)
    square = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
    brain.on_domain(
        protocol.Domain(seq=0, stamp=WALL, t=0.0, state="running", vertices=square,
                        velocities=[[0.0, 0.0]] * 4, kappa=1.0),
        0.0,
    )  # fmt: skip
    brain.on_pose(protocol.Pose(id=0, x=0.0, y=0.0, theta=0.0, stamp=WALL, seq=0), 0.0)
    for rid, (x, y) in {1: (1.0, 0.0), 2: (-1.0, 0.0)}.items():
        brain.on_pose(protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=WALL, seq=0), 0.0)
    assert brain.step(0.0, WALL).reason != "error"
    assert brain.neighborhood.one_hop == {1, 2}
    brain.on_liveliness("robot", 1, alive=False)
    assert brain.neighborhood.one_hop == {1, 2}  # no step since
    held = [a.state for a in brain.hold(0.05, WALL + 0.05) if hasattr(a, "state")]
    assert [state.neighbors for state in held] == [(2,)]
    state = brain.agent_state(WALL + 0.1)
    assert state is not None and tuple(state.neighbors) == (2,)
    brain.on_liveliness("robot", 1, alive=True)  # back: named again until the next step
    state = brain.agent_state(WALL + 0.2)
    assert state is not None and tuple(state.neighbors) == (1, 2)
