"""The mission starts once nothing is known to be missing from the team's neighbour
discovery (coordinator.monitor.discovery_gaps), or after DISCOVERY_WAIT without it, saying
so: a robot whose brain does not know the robot next to it drives into it at its first
mission step (docs/scaling.md, "A near-collision at the start of an overloaded 30 Hz run")."""

from __future__ import annotations

import logging

import pytest
from warehouse_core import SWARM, WALL0, join, make_core

from covswarm.agent.brain import BEACON_TRUST, IDLE_STEP_PERIOD, diagram_trust
from covswarm.coordinator.core import RUNNING, WAITING, CoordinatorCore
from covswarm.coordinator.monitor import (
    DISCOVERY_WAIT,
    START_SETTLE,
    MissionPhase,
    discovery_gaps,
)
from covswarm.deploy.netsim import Stall, run_netsim
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import AgentState, agent_state_key


def test_discovery_gaps_name_silent_agents_and_one_sided_neighbours() -> None:
    team = {0, 1, 2}
    assert discovery_gaps({}, team) == []  # nobody heard yet: the settle's business
    both = {0: frozenset({1}), 1: frozenset({0, 2}), 2: frozenset({1})}
    assert discovery_gaps(both, team) == []
    one_sided = {0: frozenset({1}), 1: frozenset({2}), 2: frozenset({1})}
    assert discovery_gaps(one_sided, team) == ["agent 0 names 1, which does not name it"]
    silent = {0: frozenset(), 1: frozenset({2}), 2: frozenset({1})}
    assert discovery_gaps(silent, team) == ["agent 0 names no neighbour"]
    # Not held against it: an agent not heard yet, a robot outside the team, a team of one.
    assert discovery_gaps({0: frozenset({1}), 2: frozenset({7})}, team) == []
    assert discovery_gaps({0: frozenset()}, {0}) == []


def test_the_phase_waits_for_discovery_at_most_discovery_wait() -> None:
    phase = MissionPhase(60.0, settle=1.5, discovery_wait=5.0)
    assert phase.update(0.0, True, discovered=False) == WAITING
    assert phase.update(6.4, True, discovered=False) == WAITING
    assert phase.update(6.5, True, discovered=False) == RUNNING
    assert phase.started_undiscovered
    found = MissionPhase(60.0, settle=1.5, discovery_wait=5.0)
    found.update(0.0, True, discovered=False)
    assert found.update(2.0, True, discovered=False) == WAITING
    assert found.update(2.05, True, discovered=True) == RUNNING
    assert not found.started_undiscovered


def state(rid: int, neighbours: list[int], now: float) -> bytes:
    return AgentState(id=rid, x=0.1 * rid, y=0.0, stamp=WALL0 + now, neighbors=neighbours).encode()


def ticks(core: CoordinatorCore, start: float, end: float, heard: dict[int, list[int]]) -> float:
    """Tick ``core`` every 0.05 s from ``start`` while waiting, until ``end``, each agent's
    AgentState naming ``heard[agent]`` before each tick; the time of the last tick."""
    now = start
    while core.phase.state == WAITING and now < end:
        for rid, names in heard.items():
            core.on_agent_state(agent_state_key(SWARM, rid), state(rid, names, now))
        core.tick(now, WALL0 + now)
        now = round(now + 0.05, 10)
    return now - 0.05


def test_the_coordinator_starts_once_the_neighbours_name_each_other() -> None:
    core = make_core(agents=3)
    join(core, range(3))
    # Agent 2 names nobody, and agent 1 names 2: the start waits past its settle.
    now = ticks(core, 0.0, START_SETTLE + 1.0, {0: [1], 1: [0, 2], 2: []})
    assert core.phase.state == WAITING and now >= START_SETTLE + 0.9
    # Agent 2 finds its neighbour: the next tick starts the mission.
    now = ticks(core, now + 0.05, now + 1.0, {0: [1], 1: [0, 2], 2: [1]})
    assert core.phase.state == RUNNING and now <= START_SETTLE + 1.1
    assert not core.phase.started_undiscovered and core.observed.undiscovered_start == []


def test_without_discovery_the_coordinator_starts_after_the_wait_and_says_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    core = make_core(agents=3)
    join(core, range(3))
    with caplog.at_level(logging.WARNING, logger="covswarm.coordinator"):
        now = ticks(core, 0.0, 60.0, {0: [1], 1: [0, 2], 2: [0]})
    assert core.phase.state == RUNNING
    assert now == pytest.approx(START_SETTLE + DISCOVERY_WAIT, abs=0.06)
    gaps = [
        "agent 1 names 2, which does not name it",
        "agent 2 names 0, which does not name it",
    ]
    assert core.observed.undiscovered_start == gaps
    assert "neighbour discovery incomplete" in caplog.text and gaps[0] in caplog.text


def test_netsim_holds_the_start_for_a_brain_that_stalled_before_it_met_anyone() -> None:
    # Brain 3 takes its first turn (its token, a state naming nobody), then stalls past the
    # settle: the coordinator's rule, which the netsim mirrors, waits for its next states.
    scenario = load_scenario("circle")
    stall_end = 0.1 + 2.0
    held = run_netsim(scenario, agents=12, duration=0.2, stall=Stall({3}, 0.1, 2.0))
    assert stall_end < held.started <= stall_end + 2.0, held.started
    assert held.undiscovered == []
    # Stalled beyond DISCOVERY_WAIT, it starts without it and says what was missing.
    late = run_netsim(scenario, agents=12, duration=0.2, stall=Stall({3}, 0.1, 10.0))
    assert late.started == pytest.approx(0.1 + START_SETTLE + DISCOVERY_WAIT, abs=0.2)
    assert "agent 3 names no neighbour" in late.undiscovered


def test_the_diagram_takes_every_beacon_heard_since_the_last_view() -> None:
    assert diagram_trust(5.0, None) == BEACON_TRUST
    assert diagram_trust(5.0, 4.9) == BEACON_TRUST  # a 10 Hz step: the rule as ever
    assert diagram_trust(5.0, 4.0) == pytest.approx(IDLE_STEP_PERIOD)  # idle steps
    assert diagram_trust(5.6, 4.0) == pytest.approx(1.6)  # idle, every other of its turns


def test_a_lone_brain_meets_neighbours_known_only_from_their_beacons_before_the_start() -> None:
    # Passage, brains 0 and 3 dead: robot 1's live neighbours are beyond its safety filter's
    # reach, known from beacons that came ~0.9 s before each of its idle steps. Taken only
    # when younger than BEACON_TRUST, they never entered its diagram: it named no neighbour
    # and the start waited out DISCOVERY_WAIT (6.6 s).
    result = run_netsim(load_scenario("passage"), agents=6, duration=0.2, dead=(0, 3))
    assert result.undiscovered == []
    assert result.started < 2.0 + 1.0, result.started
