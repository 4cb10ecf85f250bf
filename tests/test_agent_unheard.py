"""An agent process that hears nothing (started under another swarm's name: a forgotten
--swarm is "default") says what it has not heard and why that may be, once."""

from __future__ import annotations

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.agent.decoding import MessageDecoder
from covswarm.agent.main import unheard

WALL = 1.7e9


def brains(n: int) -> list[AgentBrain]:
    decoder = MessageDecoder()
    return [AgentBrain(i, AgentConfig(), decoder) for i in range(n)]


def test_an_agent_that_heard_nothing_names_what_and_its_swarm() -> None:
    said = unheard(brains(3), "default")
    assert said is not None
    assert said.startswith("agent 0-2 of swarm 'default' has not heard its robot's pose nor")
    assert "a domain from the coordinator" in said and "'default' its swarm's name" in said


def test_an_agent_that_heard_its_robot_but_no_domain_names_the_domain() -> None:
    team = brains(1)
    pose = protocol.Pose(id=0, x=0.0, y=0.0, theta=0.0, stamp=WALL, seq=1)
    assert team[0].receive("pose", pose.encode(), 0.0, WALL, key_id=0)
    said = unheard(team, "lab")
    assert said is not None and "its robot's pose" not in said
    assert "has not heard a domain from the coordinator" in said
