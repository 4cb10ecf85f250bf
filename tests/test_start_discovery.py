"""The mission starts once nothing is known to be missing from the team's neighbour
discovery (coordinator.monitor.discovery_gaps), or after DISCOVERY_WAIT without it, saying
so: a robot whose brain does not know the robot next to it drives into it at its first
mission step (docs/scaling.md, "A near-collision at the start of an overloaded 30 Hz run")."""

from __future__ import annotations

import logging
import math
from unittest import mock

import numpy as np
import pytest
import shapely
from shapely.geometry import MultiPoint, Point, Polygon, box
from warehouse_core import SWARM, WALL0, join, make_core

from covswarm.agent.brain import BEACON_TRUST, IDLE_STEP_PERIOD, diagram_trust
from covswarm.coordinator.core import RUNNING, WAITING, CoordinatorCore
from covswarm.coordinator.monitor import (
    DISCOVERY_EDGE,
    DISCOVERY_REACH,
    DISCOVERY_WAIT,
    START_SETTLE,
    MissionPhase,
    discovery_gaps,
)
from covswarm.deploy import netsim
from covswarm.deploy.netsim import Mute, NetsimResult, Stall, run_netsim
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import AgentState, Pose, agent_state_key, pose_key
from covswarm.tvd.coverage import neighbour_pairs


def test_discovery_gaps_are_meeting_pairs_one_agent_of_which_does_not_name_the_other() -> None:
    team = {0, 1, 2}
    pairs = np.array([[0, 1], [1, 2]])  # a row: 0 and 2 do not meet
    assert discovery_gaps({}, team, pairs) == []  # nobody heard yet: the settle's business
    both = {0: frozenset({1}), 1: frozenset({0, 2}), 2: frozenset({1})}
    assert discovery_gaps(both, team, pairs) == []
    # Naming a robot whose cell does not meet ours is no gap (a near-degenerate vertex).
    extra = {0: frozenset({1, 2}), 1: frozenset({0, 2}), 2: frozenset({1})}
    assert discovery_gaps(extra, team, pairs) == []
    silent = {0: frozenset(), 1: frozenset({0, 2}), 2: frozenset({1})}
    assert discovery_gaps(silent, team, pairs) == [
        "agent 0 does not name 1, whose cell meets its own"
    ]
    unaware = {0: frozenset({1}), 1: frozenset({0}), 2: frozenset()}
    assert discovery_gaps(unaware, team, pairs) == [
        "agent 1 does not name 2, whose cell meets its own",
        "agent 2 does not name 1, whose cell meets its own",
    ]
    # Not held against it: an agent not heard yet, a robot outside the team, no pairs (a
    # robot outside S names nobody, and its empty cell meets no one's).
    assert discovery_gaps({0: frozenset({1})}, team, pairs) == []
    assert discovery_gaps({1: frozenset({0}), 2: frozenset()}, {0, 1}, pairs) == []
    assert discovery_gaps(silent, team, np.empty((0, 2), dtype=np.int64)) == []


@pytest.mark.parametrize("seed", range(6))
def test_meeting_pairs_are_the_cells_that_share_an_edge_in_shapely(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 30))
    points = rng.uniform(-2.0, 2.0, (n, 2))  # some outside S: empty cells
    polygon = np.array([[-1.5, -1.0], [1.5, -1.2], [1.2, 1.4], [-1.3, 1.1]])
    still = rng.random(n) < 0.2
    still[0] = False
    min_edge = [0.0, DISCOVERY_EDGE, 0.2][seed % 3]
    within = [math.inf, DISCOVERY_REACH][seed % 2]
    expected = set()
    region = Polygon(polygon)
    extent = box(-10.0, -10.0, 10.0, 10.0)
    diagram = shapely.voronoi_polygons(MultiPoint(points), extend_to=extent)
    cell = [
        next(g for g in diagram.geoms if g.contains(Point(p))).intersection(region) for p in points
    ]
    for i in range(n):
        for j in range(i + 1, n):
            if still[i] or still[j] or cell[i].is_empty or cell[j].is_empty:
                continue
            shared = cell[i].boundary.intersection(cell[j].boundary).length
            apart = math.dist(points[i], points[j])
            if shared > 1e-9 and shared >= min_edge and apart <= within:
                expected.add((i, j))
    got = {
        tuple(pair) for pair in neighbour_pairs(points, polygon, min_edge, still, within).tolist()
    }
    assert got == expected


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


# Three robots in a row inside the warehouse's S(0): 0 meets 1, 1 meets 2, 0 and 2 do not;
# robot 3 (when there) outside S.
ROW = {0: (-3.0, -0.3), 1: (-2.7, -0.3), 2: (-2.4, -0.3), 3: (-2.7, 2.0)}


def ticks(core: CoordinatorCore, start: float, end: float, heard: dict[int, list[int]]) -> float:
    """Tick ``core`` every 0.05 s from ``start`` while waiting, until ``end``, each agent's
    AgentState naming ``heard[agent]`` and its robot's pose at ROW before each tick; the
    time of the last tick."""
    now = start
    while core.phase.state == WAITING and now < end:
        for rid, names in heard.items():
            core.on_agent_state(agent_state_key(SWARM, rid), state(rid, names, now))
            x, y = ROW[rid]
            pose = Pose(id=rid, x=x, y=y, theta=0.0, stamp=WALL0 + now, seq=int(now * 20))
            core.on_pose(pose_key(SWARM, rid), pose.encode())
        core.tick(now, WALL0 + now)
        now = round(now + 0.05, 10)
    return now - 0.05


def test_the_coordinator_starts_once_the_neighbours_name_each_other() -> None:
    core = make_core(agents=4)
    join(core, range(4))
    # Agent 2 names nobody, and agent 1 names 2: the start waits past its settle. Robot 3,
    # outside S, names nobody either, and is not waited for.
    now = ticks(core, 0.0, START_SETTLE + 1.0, {0: [1], 1: [0, 2], 2: [], 3: []})
    assert core.phase.state == WAITING and now >= START_SETTLE + 0.9
    # Agent 2 finds its neighbour: the next tick starts the mission.
    now = ticks(core, now + 0.05, now + 1.0, {0: [1], 1: [0, 2], 2: [1], 3: []})
    assert core.phase.state == RUNNING and now <= START_SETTLE + 1.1
    assert not core.phase.started_undiscovered and core.observed.undiscovered_start == []


def test_two_agents_unaware_of_each_other_hold_the_start_though_their_lists_agree(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # 1 and 2 meet, and neither names the other: their lists agree with each other and say
    # nothing is missing. The poses' cells show the pair.
    core = make_core(agents=3)
    join(core, range(3))
    heard = {0: [1], 1: [0], 2: []}
    with caplog.at_level(logging.INFO, logger="covswarm.coordinator"):
        now = ticks(core, 0.0, START_SETTLE + 1.0, heard)
    assert core.phase.state == WAITING and now >= START_SETTLE + 0.9
    gaps = [
        "agent 1 does not name 2, whose cell meets its own",
        "agent 2 does not name 1, whose cell meets its own",
    ]
    assert core.discovery_gaps(now) == gaps
    # The log says why the start waits, once.
    said = [r.message for r in caplog.records if "the start waits" in r.message]
    assert len(said) == 1 and gaps[0] in said[0]


def test_without_discovery_the_coordinator_starts_after_the_wait_and_says_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    core = make_core(agents=3)
    join(core, range(3))
    with caplog.at_level(logging.WARNING, logger="covswarm.coordinator"):
        now = ticks(core, 0.0, 60.0, {0: [1], 1: [0, 2], 2: [0]})
    assert core.phase.state == RUNNING
    assert now == pytest.approx(START_SETTLE + DISCOVERY_WAIT, abs=0.06)
    gaps = ["agent 2 does not name 1, whose cell meets its own"]
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
    assert any(gap.startswith("agent 3 does not name") for gap in late.undiscovered)


def test_the_diagram_takes_every_beacon_heard_since_the_last_view() -> None:
    assert diagram_trust(5.0, None) == BEACON_TRUST
    assert diagram_trust(5.0, 4.9) == BEACON_TRUST  # a 10 Hz step: the rule as ever
    assert diagram_trust(5.0, 4.0) == pytest.approx(IDLE_STEP_PERIOD)  # idle steps
    assert diagram_trust(5.6, 4.0) == pytest.approx(1.6)  # idle, every other of its turns


def test_a_lone_brain_meets_neighbours_known_only_from_their_beacons_before_the_start() -> None:
    # Passage, brains 0 and 3 dead: robot 1's live neighbours stand beyond its safety
    # filter's reach, known from beacons that came ~0.9 s before each of its idle steps.
    # Taken only when younger than BEACON_TRUST, they never entered its diagram: it named no
    # neighbour and covered all of S alone when the mission started.
    result = run_netsim(load_scenario("passage"), agents=6, duration=0.2, dead=(0, 3))
    assert result.stats[1]["neighbors"] >= 2, result.stats[1]
    assert result.undiscovered == []


def test_the_gate_keeps_a_team_off_robots_it_has_not_heard_of() -> None:
    # The robot-14 case, made deterministic: every 7th of 100 robots on the circle has its
    # AgentStates and beacons lost for the first 4 s. Started when the settle allows (the
    # gate off), their neighbours drive into them (0.003 m between centres, 3 Dec 2026); the
    # gate waits until they are heard and named, and nobody comes within a body diameter.
    muted = list(range(0, 100, 7))

    def run() -> NetsimResult:
        return run_netsim(
            load_scenario("circle"), agents=100, duration=1.5, mute=Mute(muted, 0.0, 4.0)
        )

    def closest_to_muted(result: NetsimResult) -> float:
        others = np.setdiff1d(np.arange(100), muted)
        return min(
            float(np.hypot(*(frame[muted, None] - frame[None, others]).transpose(2, 0, 1)).min())
            for frame in result.trajectories
        )

    with mock.patch.object(netsim, "discovery_gaps", lambda *args: []):
        ungated = run()
    assert ungated.started == pytest.approx(2.0)
    assert closest_to_muted(ungated) < 0.10
    gated = run()
    assert gated.started > 4.0 and gated.undiscovered == []
    assert closest_to_muted(gated) >= 0.14 - 1e-3
