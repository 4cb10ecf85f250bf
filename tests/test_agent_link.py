"""The Zenoh side of a packed agent process (covswarm.agent.link.ZenohBus), over real
sessions on loopback: the liveliness tokens it hears."""

from __future__ import annotations

import time

import pytest
import zenoh
from live_runs import new_swarm, open_router

from covswarm import protocol
from covswarm.agent.link import ZenohBus
from covswarm.protocol import session_config


def _changes(source: object, count: int, timeout: float = 5.0) -> list[tuple[str, bool]]:
    """The first ``count`` token changes ``source`` gives within ``timeout`` s."""
    got: list[tuple[str, bool]] = []
    deadline = time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        change = source.try_recv()
        if change is None:
            time.sleep(0.01)
        else:
            got.append(change)
    return got


@pytest.mark.e2e
def test_the_tokens_alive_when_an_agent_starts_come_first_and_their_deletions_follow() -> None:
    """A robot's token declared before the agent process subscribes reaches it as an
    appearance, and its deletion follows. Subscribed for changes only, such a token was
    sometimes never undeclared to the agent when its process was killed (agent.link)."""
    swarm = new_swarm()
    router, endpoint = open_router()
    with router, zenoh.open(session_config([endpoint], role="robot", id=1)) as robot:
        key = protocol.alive_key(swarm, "robot", 1)
        token = robot.liveliness().declare_token(key)
        time.sleep(0.3)  # declared well before the agent starts
        with zenoh.open(session_config([endpoint], role="agent", id=0)) as agent:
            changes = ZenohBus(agent).liveliness(protocol.alive_selector(swarm))
            assert _changes(changes, 1) == [(key, True)]
            token.undeclare()
            assert _changes(changes, 1) == [(key, False)]
