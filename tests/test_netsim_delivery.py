"""deploy/netsim.py delivers AgentStates and beacons as Zenoh does (covswarm.agent.pack): an
agent hears a robot's AgentState, or a beacon put on a tile, only when it followed that
robot or tile from before the message arrived until its turn; nothing put before it
subscribed, nothing after it unsubscribed."""

from __future__ import annotations

from collections import defaultdict

import pytest

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, FollowStates, FollowTiles
from covswarm.deploy.netsim import START_WALL, run_netsim
from covswarm.mission.scenario_files import load_scenario

TRANSIT = 0.05  # s: long enough that a message put before a follow can still be on its way

History = list[tuple[float, frozenset]]  # (time it was asked, what was followed from then)


def followed_since(history: History, item: object, now: float) -> float | None:
    """Since when ``item`` was followed without a break, as of a turn at ``now`` (which
    reads its messages before asking to follow anything); None if it was not followed."""
    since = None
    for asked, wanted in reversed([entry for entry in history if entry[0] < now]):
        if item not in wanted:
            break
        since = asked
    return since


def test_an_agent_hears_only_what_arrived_while_it_followed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    follows: dict[tuple[int, str], History] = defaultdict(list)
    heard: list[tuple[int, float, str, object, float]] = []  # agent, turn, kind, item, put
    tick, receive = AgentBrain.tick, AgentBrain.receive

    def recording_tick(brain: AgentBrain, now: float, wall: float) -> list:
        actions = tick(brain, now, wall)
        for action in actions:
            if isinstance(action, FollowStates):
                follows[brain.id, "state"].append((now, action.ids))
            elif isinstance(action, FollowTiles):
                follows[brain.id, "beacon"].append((now, action.tiles))
        return actions

    def recording_receive(brain: AgentBrain, kind: str, payload: bytes, now: float, *rest) -> bool:
        if kind == "state":
            state = protocol.AgentState.decode(payload)
            heard.append((brain.id, now, kind, state.id, state.stamp - START_WALL))
        elif kind == "beacon":
            beacon = protocol.Beacon.decode(payload)
            tile = protocol.tile_of(beacon.x, beacon.y, brain.tile_size)
            heard.append((brain.id, now, kind, tile, beacon.stamp - START_WALL))
        return receive(brain, kind, payload, now, *rest)

    monkeypatch.setattr(AgentBrain, "tick", recording_tick)
    monkeypatch.setattr(AgentBrain, "receive", recording_receive)
    run_netsim(load_scenario("passage"), agents=6, duration=4.0, transit=TRANSIT)

    kinds = {kind for _, _, kind, _, _ in heard}
    assert kinds == {"state", "beacon"}
    late_followers = 0  # receipts of an item followed only since shortly before its turn
    for agent, turn, kind, item, put in heard:
        since = followed_since(follows[agent, kind], item, turn)
        assert since is not None, (agent, turn, kind, item)
        assert since <= put + TRANSIT + 1e-9, (agent, turn, kind, item, put, since)
        late_followers += since > put
    assert late_followers > 0  # the transit's grace was exercised, not only old follows
