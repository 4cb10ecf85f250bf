"""The coordinator's sans-IO core, driven with messages and a fake clock (no network)."""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from reference import reference_cells
from rich.console import Console
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import split

from covswarm.coordinator.core import (
    DONE,
    DONE_HOLD,
    RUNNING,
    START_SETTLE,
    STATUS_PERIOD,
    WAITING,
    CoordinatorCore,
    CoordinatorSettings,
    Finished,
    JournalSteering,
    MissionStarted,
    PublishDomain,
    PublishStatus,
    ReplySteer,
    _read_state,
)
from covswarm.coordinator.steering import Refusal
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import (
    AgentState,
    Pose,
    ProtocolError,
    agent_state_key,
    alive_key,
    messages,
    pose_key,
)
from covswarm.protocol.steering import SteerReply, SteerRequest
from covswarm.records.recorder import RunRecorder
from covswarm.records.replay import read_agent_states
from covswarm.tvd.coverage import aggregate_error

SWARM = "core-test"
WALL0 = 1.7e9  # s since the epoch at now = 0


def make_core(
    agents: int = 2, duration: float = 3.0, time_scale: float = 1.0, checks: tuple = ()
) -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=load_scenario("circle"), swarm=SWARM, agents=agents, duration=duration,
        kappa=2.0, rate=20.0, sample_rate=10.0, feedforward=True, time_scale=time_scale,
        tile_size=0.5,
    )  # fmt: skip
    return CoordinatorCore(
        settings, steer_checks=checks, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0
    )


def join(core: CoordinatorCore, ids: list[int], now: float = 0.0) -> None:
    for i in ids:
        for role in ("robot", "agent"):
            core.on_liveliness(alive_key(SWARM, role, i), True, now, WALL0 + now)


def of(kind: type, actions: list) -> list:
    return [action for action in actions if isinstance(action, kind)]


def start(core: CoordinatorCore) -> float:
    """Join the whole team at 0 and tick until the mission starts; returns that time."""
    join(core, list(range(core.settings.agents)))
    now = 0.0
    while core.phase.state == WAITING:
        core.tick(now, WALL0 + now)
        now = round(now + 0.05, 10)
    return now - 0.05


def test_the_mission_starts_once_the_whole_team_held_its_tokens_for_the_settle_time() -> None:
    core = make_core()
    join(core, [0])  # half the team
    assert of(PublishDomain, core.tick(0.0, WALL0))[0].domain.state == WAITING
    join(core, [1], now=0.5)
    core.tick(0.5, WALL0 + 0.5)  # the first tick that sees the whole team
    assert core.tick(0.5 + START_SETTLE - 0.05, WALL0 + 2.0)[0].domain.state == WAITING
    actions = core.tick(0.5 + START_SETTLE, WALL0 + 2.05)
    assert of(MissionStarted, actions) == [MissionStarted(SWARM, WALL0 + 2.05)]
    domain = of(PublishDomain, actions)[0].domain
    assert domain.state == RUNNING and domain.t == 0.0
    assert core.observed.started_wall == WALL0 + 2.05
    # A token lost while waiting restarts the settle time.
    late = make_core()
    join(late, [0, 1])
    late.tick(0.0, WALL0)
    late.on_liveliness(alive_key(SWARM, "agent", 1), False, 1.0, WALL0 + 1.0)
    late.tick(1.0, WALL0 + 1.0)
    late.on_liveliness(alive_key(SWARM, "agent", 1), True, 1.2, WALL0 + 1.2)
    late.tick(1.2, WALL0 + 1.2)
    assert late.tick(1.2 + START_SETTLE - 0.05, WALL0)[0].domain.state == WAITING
    assert of(PublishDomain, late.tick(1.2 + START_SETTLE, WALL0))[0].domain.state == RUNNING


def test_domain_broadcasts_carry_s_its_velocities_and_a_rising_sequence() -> None:
    core = make_core(time_scale=0.5)
    scenario = core.settings.scenario
    waiting = of(PublishDomain, core.tick(0.0, WALL0))[0].domain
    vertices, velocities = scenario.domain(0.0)
    assert waiting.seq == 0 and waiting.stamp == pytest.approx(WALL0 * 0.5)
    np.testing.assert_allclose(waiting.vertices, vertices)
    assert np.abs(np.array(velocities)).max() > 0  # S moves, but not while waiting
    np.testing.assert_array_equal(waiting.velocities, np.zeros_like(velocities))
    # how it will move at the start: robots turn to face it while they wait
    np.testing.assert_allclose(waiting.start_velocities, velocities)
    assert waiting.kappa == 2.0 and waiting.tile_size == 0.5
    started = start(core)
    now = started + 0.8
    domain = of(PublishDomain, core.tick(now, WALL0 + now))[0].domain
    vertices, velocities = scenario.domain(0.8)
    assert domain.t == pytest.approx(0.8) and domain.state == RUNNING
    assert domain.start_velocities is None
    np.testing.assert_allclose(domain.vertices, vertices)
    np.testing.assert_allclose(domain.velocities, velocities)
    assert domain.seq == core._seq - 1 and domain.seq > waiting.seq
    decoded = type(domain).decode(domain.encode())  # what the shell puts on the wire
    assert decoded == domain


def test_a_mission_that_starts_still_announces_no_start_motion() -> None:
    settings = CoordinatorSettings(
        scenario=load_scenario("live"), swarm=SWARM, agents=1, duration=3.0, kappa=2.0,
        rate=20.0, sample_rate=10.0, feedforward=True, tile_size=0.5,
    )  # fmt: skip
    core = CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)
    waiting = of(PublishDomain, core.tick(0.0, WALL0))[0].domain
    assert waiting.state == WAITING and waiting.start_velocities is None


def test_steering_is_refused_while_waiting_and_accepted_once_running() -> None:
    core = make_core(duration=30.0)
    request = SteerRequest(kind="translate", dx=0.1, dy=0.0, duration=2.0).encode()
    refused = core.on_steer(request, 0.0, WALL0)
    assert len(refused) == 1 and refused[0].accepted is False
    reply = SteerReply.decode(refused[0].payload)
    assert not reply.accepted and reply.reason.startswith("not-running")
    garbage = core.on_steer(b"\x00not msgpack", 0.0, WALL0)
    assert SteerReply.decode(garbage[0].payload).reason.startswith("undecodable")
    started = start(core)
    now = started + 1.0
    before = core.steering.domain(1.0)[0]
    actions = core.on_steer(request, now, WALL0 + now)
    assert isinstance(actions[0], ReplySteer) and actions[0].accepted
    assert SteerReply.decode(actions[0].payload).duration > 0
    (journal,) = of(JournalSteering, actions)
    assert '"translate"' in journal.line
    assert core.steering.refused == {"not-running": 1, "undecodable": 1}
    # S now follows the request (it brakes, then moves 0.1 m), not the scenario's script,
    # and rests once it arrives.
    end = now + SteerReply.decode(actions[0].payload).duration + 0.5
    domain = of(PublishDomain, core.tick(end, WALL0 + end))[0].domain
    t = end - started
    assert domain.t == pytest.approx(t)
    np.testing.assert_allclose(domain.vertices, core.steering.domain(t)[0])
    np.testing.assert_allclose(domain.velocities, 0.0, atol=1e-12)
    assert np.abs(np.array(domain.vertices) - core.settings.scenario.domain(t)[0]).max() > 0.05
    assert np.abs(np.array(domain.vertices) - before).max() > 0.05


def test_status_every_half_second_with_the_team_and_the_latest_error() -> None:
    core = make_core()
    join(core, [0])
    first = of(PublishStatus, core.tick(0.0, WALL0))
    assert len(first) == 1
    status = first[0].status
    assert status.state == WAITING and status.error is None
    assert (status.alive_agents, status.alive_robots) == (1, 1)
    assert of(PublishStatus, core.tick(STATUS_PERIOD - 0.05, WALL0)) == []
    assert len(of(PublishStatus, core.tick(STATUS_PERIOD, WALL0))) == 1


def voronoi_error(positions: np.ndarray, polygon: np.ndarray) -> float:
    """e_a for two robots, uniform density, with shapely: the cells are S split by the
    robots' perpendicular bisector."""
    a, b = positions
    mid, normal = (a + b) / 2, np.array([-(b - a)[1], (b - a)[0]])
    line = LineString([mid - 100 * normal, mid + 100 * normal])
    cells = split(Polygon(polygon), line).geoms
    error = 0.0
    for p in positions:
        (cell,) = [c for c in cells if c.contains(Point(p))]
        error += float(np.sum((p - np.array(cell.centroid.coords[0])) ** 2))
    return error**0.5


def test_error_samples_use_the_poses_of_the_team_at_the_sample_rate() -> None:
    core = make_core()
    assert core.settings.scenario.density(0.0) is None  # uniform: the reference holds
    started = start(core)
    centre = core.settings.scenario.domain(0.0)[0].mean(axis=0)
    positions = centre + np.array([[-0.3, 0.1], [0.4, -0.2]])
    samples = []
    for k in range(6):
        now = round(started + 0.05 * (k + 1), 10)
        wall = WALL0 + now
        for i, (x, y) in enumerate(positions):
            pose = Pose(id=i, x=x, y=y, theta=0.0, stamp=wall, seq=k)
            core.on_pose(pose_key(SWARM, i), pose.encode())
        core.on_pose(pose_key(SWARM, 7), b"junk")  # not decodable: counted
        core.tick(now, wall)
        samples.append(len(core.observed.record.t))
    # 20 Hz broadcasts, 10 Hz samples: one sample every second tick.
    assert samples == [0, 1, 1, 2, 2, 3]
    record = core.observed.record
    t = record.t[-1]
    polygon = core.steering.domain(t)[0]
    assert record.error[-1] == pytest.approx(voronoi_error(positions, polygon), rel=1e-9)
    assert core.observed.rejected >= 1
    # A robot whose agent is gone is not in e_a.
    core.on_liveliness(alive_key(SWARM, "agent", 1), False, 0.0, WALL0)
    assert set(core.alive_positions()) == {0}


def test_a_robot_whose_agent_died_bounds_the_cells_of_e_a_and_is_out_of_it() -> None:
    """Robot 2's agent dies and its robot stays: the agents take it as a still generator
    (covswarm.tvd.control's ``still``), so e_a is robots 0 and 1's in the cells it bounds
    (shapely's); its robot's token gone too, it is out of the diagram."""
    core = make_core(agents=3)
    started = start(core)
    centre = core.settings.scenario.domain(0.0)[0].mean(axis=0)
    positions = centre + np.array([[-0.3, 0.1], [0.4, -0.2], [0.05, 0.3]])

    def sample(k: int) -> float:
        """Ticks from 0.1 k s into the mission until an e_a sample is taken; that e_a."""
        record, taken = core.observed.record, len(core.observed.record.t)
        now = round(started + 0.1 * k, 10)
        while len(record.t) == taken:
            for i, (x, y) in enumerate(positions):
                pose = Pose(id=i, x=x, y=y, theta=0.0, stamp=WALL0 + now, seq=round(now * 100))
                core.on_pose(pose_key(SWARM, i), pose.encode())
            core.tick(now, WALL0 + now)
            now = round(now + 0.05, 10)
        return record.error[-1]

    core.on_liveliness(alive_key(SWARM, "agent", 2), False, started, WALL0 + started)
    error = sample(1)
    polygon = core.steering.domain(core.observed.record.t[-1])[0]
    cells = reference_cells(positions, polygon)
    expected = math.sqrt(
        sum(np.sum((positions[i] - np.array(cells[i].centroid.coords[0])) ** 2) for i in (0, 1))
    )
    assert error == pytest.approx(expected, rel=1e-9)
    assert error != pytest.approx(voronoi_error(positions[:2], polygon), rel=1e-3)
    core.on_liveliness(alive_key(SWARM, "robot", 2), False, started, WALL0 + started)
    error = sample(3)
    polygon = core.steering.domain(core.observed.record.t[-1])[0]
    assert error == pytest.approx(voronoi_error(positions[:2], polygon), rel=1e-9)


def test_the_team_changes_once_per_tick_and_tokens_gone_after_done_are_not_losses() -> None:
    core = make_core(agents=3, duration=1.0)
    started = start(core)
    now = started + 0.2
    core.on_liveliness(alive_key(SWARM, "robot", 1), False, now, WALL0 + now)
    core.on_liveliness(alive_key(SWARM, "agent", 2), False, now, WALL0 + now)
    core.on_liveliness(alive_key(SWARM, "agent", 1), False, now, WALL0 + now)
    core.on_liveliness("not/a/key", True, now, WALL0 + now)
    core.tick(now, WALL0 + now)
    (change,) = core.observed.team_changes
    assert change.lost == (1, 2) and change.joined == () and change.t == pytest.approx(0.2)
    assert core.observed.rejected == 1
    assert [e.t for e in core.observed.liveness.events if not e.alive] == [pytest.approx(0.2)] * 3
    core.tick(started + 1.0, WALL0)
    assert core.phase.state == DONE
    core.on_liveliness(alive_key(SWARM, "robot", 0), False, started + 1.1, WALL0)
    assert core.observed.liveness.count("robot") == 2


def test_done_at_the_duration_with_a_final_sample_then_finished_after_the_hold() -> None:
    core = make_core(duration=1.0)
    started = start(core)
    end = started + 1.0
    for i in range(2):  # taken at the end
        pose = Pose(id=i, x=0.1 * i, y=0.0, theta=0.0, stamp=WALL0 + end, seq=0)
        core.on_pose(pose_key(SWARM, i), pose.encode())
    actions = core.tick(end, WALL0 + end)
    domain = of(PublishDomain, actions)[0].domain
    assert domain.state == DONE and domain.t == pytest.approx(1.0)
    np.testing.assert_allclose(domain.vertices, core.settings.scenario.domain(1.0)[0])
    assert core.observed.record.t[-1] == pytest.approx(1.0)  # the final sample, at the end
    assert of(Finished, actions) == []
    later = core.tick(end + 5.0, WALL0)  # mission time stays at the duration
    assert of(PublishDomain, later)[0].domain.t == pytest.approx(1.0)
    assert of(Finished, later) == [Finished(started=True)]
    assert DONE_HOLD <= 5.0


def test_stopping_ends_a_waiting_mission_at_once_and_a_running_one_through_done() -> None:
    waiting = make_core()
    assert waiting.tick(0.0, WALL0, stopping=True) == [Finished(started=False)]
    running = make_core()
    started = start(running)
    actions = running.tick(started + 0.3, WALL0, stopping=True)
    assert running.phase.state == DONE
    assert of(PublishDomain, actions)[0].domain.t == pytest.approx(0.3)
    assert of(Finished, running.tick(started + 0.31 + DONE_HOLD, WALL0)) == [Finished(True)]


def test_agent_stats_are_kept_and_malformed_states_counted() -> None:
    core = make_core()
    state = AgentState(id=1, x=0.0, y=0.0, stamp=WALL0, neighbors=(0,), stats={"rate_hz": 9.9})
    hear(core, state)
    core.on_agent_state(agent_state_key(SWARM, 1), b"\xff")
    assert core.observed.agent_stats == {1: {"rate_hz": 9.9}}
    assert core.observed.rejected == 1


def test_a_message_naming_another_robot_than_its_key_is_dropped_and_counted() -> None:
    """In secure mode a process may put only on its own keys: robot 9's credentials put
    poses and states saying id 0 on robot 9's keys. Neither moves robot 0 nor gives it
    stats (the pace would follow a forged rate); both are counted in summary.json."""
    core = make_core()
    started = start(core)
    real = Pose(0, -1.0, 0.0, 0.0, WALL0 + started, 1)
    forged = Pose(0, 2.2, 1.6, 0.0, WALL0 + started, 2)
    core.on_poses([(pose_key(SWARM, 0), real.encode()), (pose_key(SWARM, 9), forged.encode())])
    state = AgentState(0, 2.2, 1.6, WALL0, (1,), stats={"rate_hz": 0.1})
    core.on_agent_state(agent_state_key(SWARM, 9), state.encode())
    assert core.alive_positions()[0] == (-1.0, 0.0)
    assert 0 not in core.observed.agent_stats
    assert core.observed.wrong_ids == 2 and core.observed.rejected == 0


# A state valid but for its relay: entries of the wrong arity or type, numbers not finite
# or out of bounds, ids out of range or repeated, too many entries, or no array at all.
GOOD_RELAY = [[0, 1.0, 2.0, 0.1, -0.1], [5, -1.0, 0.5, 0.0, 0.2]]
BAD_RELAYS = [
    [[0, 1.0, 2.0, 0.1]],
    [[0, 1.0, 2.0, 0.1, -0.1, 0.0]],
    [[]],
    [[0, math.nan, 2.0, 0.1, -0.1]],
    [[0, 1.0, math.inf, 0.1, -0.1]],
    [[0, 1.0, 2.0, -math.inf, -0.1]],
    [[0, 1.0, 2.0, 0.1, math.nan]],
    [[0, 2 * messages.MAX_COORD, 2.0, 0.1, -0.1]],
    [[0, 1.0, 2.0, 0.1, 2 * messages.MAX_SPEED]],
    [[-1, 1.0, 2.0, 0.1, -0.1]],
    [[messages.MAX_ID + 1, 1.0, 2.0, 0.1, -0.1]],
    [[1.0, 1.0, 2.0, 0.1, -0.1]],
    [[True, 1.0, 2.0, 0.1, -0.1]],
    [[0, False, 2.0, 0.1, -0.1]],
    [[0, "1.0", 2.0, 0.1, -0.1]],
    [[0, None, 2.0, 0.1, -0.1]],
    [[0, [1.0], 2.0, 0.1, -0.1]],
    [GOOD_RELAY[0], GOOD_RELAY[0]],
    [GOOD_RELAY[0], [0, 3.0, 3.0, 0.0, 0.0]],
    [[i, 1.0, 2.0, 0.1, -0.1] for i in range(messages.MAX_RELAY + 1)],
    [GOOD_RELAY[0], 7],
    [GOOD_RELAY[0], {"id": 5}],
    [GOOD_RELAY[0], "entry"],
    {"0": [1.0, 2.0, 0.1, -0.1]},
    "relay",
    7,
]


def hear(core: CoordinatorCore, state: AgentState) -> None:
    """``state`` as the link hands it over: on its own agent's key."""
    core.on_agent_state(agent_state_key(SWARM, state.id), state.encode())


def state_payload(**fields) -> bytes:
    """An AgentState's bytes as a peer might send them, ``fields`` in place of a valid
    state's (robot 1, neighbour 0, with stats and a relay)."""
    valid = {
        "v": 1, "id": 1, "x": 0.5, "y": -0.5, "stamp": WALL0, "neighbors": [0],
        "stats": {"rate_hz": 9.9, "mission_steps": 10}, "vx": 0.1, "vy": 0.0,
        "relay": GOOD_RELAY,
    }  # fmt: skip
    return msgpack.packb({**valid, **fields}, use_bin_type=True)


def refusal(read, payload: bytes) -> tuple[str, str] | None:
    try:
        read(payload)
    except ProtocolError as exc:
        return exc.reason, str(exc)
    return None


@pytest.mark.parametrize("relay", BAD_RELAYS, ids=range(len(BAD_RELAYS)))
def test_a_state_malformed_only_in_its_relay_is_dropped_and_counted(relay) -> None:
    """The coordinator does not build the relay it never reads, but checks it as decode
    does: such a state is refused for decode's reason (the same message), counted, and
    keeps no stats; the same state with a valid relay is taken."""
    core = make_core()
    payload = state_payload(relay=relay)
    reason = refusal(AgentState.decode, payload)
    assert reason is not None  # today's checker refuses it
    assert refusal(_read_state, payload) == reason
    core.on_agent_state(agent_state_key(SWARM, 1), payload)
    assert core.observed.rejected == 1 and core.observed.agent_stats == {}
    core.on_agent_state(agent_state_key(SWARM, 1), state_payload())
    assert core.observed.rejected == 1
    assert core.observed.agent_stats == {1: {"rate_hz": 9.9, "mission_steps": 10}}


@given(data=st.data())
@settings(max_examples=300, deadline=None, database=None)
def test_the_coordinator_reads_of_a_state_what_decode_gives(data: st.DataObject) -> None:
    """Random valid states, as agents send them (floats, tuples) or as another encoder may
    (ints for floats, lists, optional fields left out): what the coordinator reads is what
    AgentState.decode's message holds, with the same types."""
    ident = st.integers(0, messages.MAX_ID)
    coord = st.floats(-messages.MAX_COORD, messages.MAX_COORD) | st.integers(-10_000, 10_000)
    speed = st.floats(-messages.MAX_SPEED, messages.MAX_SPEED) | st.integers(-100, 100)
    stat = st.floats(-messages.MAX_STAT, messages.MAX_STAT) | st.integers(
        -messages.MAX_SEQ, messages.MAX_SEQ
    )
    relay = st.lists(
        st.tuples(ident, coord, coord, speed, speed), max_size=messages.MAX_RELAY,
        unique_by=lambda entry: entry[0],
    )  # fmt: skip
    fields = {
        "id": ident, "x": coord, "y": coord,
        "stamp": st.floats(0.0, messages.MAX_STAMP) | st.integers(0, 10**11),
        "neighbors": st.lists(ident, max_size=messages.MAX_NEIGHBORS, unique=True),
        "stats": st.dictionaries(
            st.text(min_size=1, max_size=messages.MAX_STAT_NAME), stat,
            max_size=messages.MAX_STATS,
        ),
        "vx": speed, "vy": speed, "relay": relay,
    }  # fmt: skip
    optional = AgentState._OPTIONAL
    state = {
        name: data.draw(strategy, name)
        for name, strategy in fields.items()
        if name not in optional or data.draw(st.booleans(), f"{name} sent")
    }
    payload = msgpack.packb({"v": 1, **state}, use_bin_type=True)
    message = AgentState.decode(payload)
    expected = (message.id, message.stamp, message.neighbors, message.stats)
    read = _read_state(payload)
    assert repr(read) == repr(expected)


def test_a_state_naming_a_newcomer_enters_it_in_the_liveness_and_the_team() -> None:
    """Robot 5 (beyond the team of 2) holds both tokens: it is a team member once an agent
    of the team names it in a state, not when it names itself."""
    core = make_core(agents=2)
    join(core, [0, 1, 5])
    assert core.observed.liveness.count("agent") == 2
    hear(core, AgentState(5, 0.0, 0.0, WALL0, (0, 5)))
    assert core.observed.liveness.count("agent") == 2
    hear(core, AgentState(1, 0.0, 0.0, WALL0, (0, 5)))
    assert core.observed.liveness.count("agent") == core.observed.liveness.count("robot") == 3
    assert core.roster.members(core.observed.liveness.alive) == frozenset({0, 1, 5})
    assert core.roster.summary()["counts"] == {}  # its tokens and state are not unexpected


def test_a_robot_outside_the_team_is_named_once_in_the_log(caplog) -> None:
    """A bridge serving robots 0-3 to a team of 2: robots 2 and 3 hold tokens, no brain of
    the team moves them and the agents keep clear of them; the coordinator says so once per
    robot, and the run's summary table lists them (deploy.display.summary_table)."""
    from covswarm.deploy.display import summary_table
    from covswarm.deploy.processes import RunResult

    core = make_core(agents=2)
    with caplog.at_level("WARNING", logger="covswarm.coordinator"):
        for _ in range(3):  # tokens that come and go are named once
            for i in range(4):
                core.on_liveliness(alive_key(SWARM, "robot", i), True, 0.0, WALL0)
        core.on_liveliness(alive_key(SWARM, "agent", 7), True, 0.0, WALL0)  # no robot
    told = [r.getMessage() for r in caplog.records if "outside the team" in r.getMessage()]
    assert len(told) == 2
    assert told[1].startswith("robot 3 holds a liveliness token outside the team (ids 0-1)")
    assert told[1].endswith("a bridge serving it needs --agents 4 or more")
    summary = {"unexpected": core.roster.summary(), "lost_processes": []}
    table = summary_table(summary, RunResult(0, {}, {}, {}), Path("out"), 1.0)
    with Console(width=200, record=True) as console:
        console.print(table)
    row = " ".join(console.export_text().replace("│", " ").split())
    assert "outside the team ids 2, 3, 7: 7 tokens and messages refused" in row


def test_a_batch_of_poses_is_taken_as_one_pose_at_a_time(tmp_path) -> None:
    """on_poses (the link's batch of a tick) keeps each robot's newest payload and backlogs
    every pose, counting those that push out older ones, as on_pose one by one does."""
    pairs = [(pose_key(SWARM, i % 3), Pose(i % 3, 0.1 * i, 0.0, 0.0, WALL0 + i, i).encode())
             for i in range(1500)]  # fmt: skip
    cores = []
    for batch in (True, False):
        settings = make_core().settings
        with RunRecorder(tmp_path / str(batch), run_metadata={}) as recorder:
            core = CoordinatorCore(settings, recorder=recorder, cpu_clock=lambda: 0.0)
            for chunk in (pairs[:1000], pairs[1000:1001], pairs[1001:]):
                if batch:
                    core.on_poses(chunk)
                else:
                    for key, payload in chunk:
                        core.on_pose(key, payload)
            cores.append(core)
    batched, single = cores
    assert batched._pose_payloads == single._pose_payloads
    assert list(batched._pose_backlog) == list(single._pose_backlog) == pairs[-1024:]
    assert batched.recording["backlog_overflow"] == single.recording["backlog_overflow"] == 476


def recording_core(out, record_states: bool = True, cpu_clock=lambda: 0.0):
    """A core of 2 agents recording into ``out`` (its recorder closes with the core's)."""
    settings = dataclasses.replace(make_core().settings, record_states=record_states)
    recorder = RunRecorder(out, run_metadata={})
    return CoordinatorCore(settings, recorder=recorder, cpu_clock=cpu_clock), recorder


@pytest.mark.parametrize("record_states", [True, False])
def test_the_core_records_each_admitted_state_and_the_newest_of_each_from_the_wait(
    tmp_path, record_states: bool
) -> None:
    """While waiting, each agent's newest state is kept for the first record (what it
    believed as the mission started); then every state received, as sent, at the tick
    after it arrived. Malformed states and those of ids outside the team are not recorded,
    and ``--no-record-states`` records none."""
    core, recorder = recording_core(tmp_path, record_states)
    join(core, [0, 1])
    core.tick(0.0, WALL0)
    waiting = [AgentState(i % 2, 0.1 * i, 0.0, WALL0 + i, (1 - i % 2,)) for i in range(5)]
    for state in waiting:
        hear(core, state)
        core.tick(0.0, WALL0)
    core.on_agent_state(agent_state_key(SWARM, 1), b"\xff")
    hear(core, AgentState(7, 0.0, 0.0, WALL0, (0,)))  # not in the team
    started = start(core)
    relay = ((1, 0.5, 0.0, 0.1, 0.0),)
    running = [AgentState(0, 0.0, 0.0, WALL0 + 9, (1,), vx=0.1, vy=0.0, relay=relay),
               AgentState(1, 0.5, 0.0, WALL0 + 9, (0,))]  # fmt: skip
    for state in running:
        hear(core, state)
    now = started + 0.05
    core.tick(now, WALL0 + now)
    recorder.close()
    record = read_agent_states(tmp_path / "run.mcap")
    if not record_states:
        assert record.states == [] and recorder.counts["states"] == 0
        return
    t0, t1 = core.phase.mission_time(started), core.phase.mission_time(now)
    assert record.t == pytest.approx([t0, t0, t1, t1], abs=1e-9)  # (log times are in ns)
    assert sorted(record.states[:2], key=lambda s: s.id) == waiting[-2:][::-1]
    assert record.states[2:] == running and record.rejected == 0
    assert record.at(0, t1 + 0.01) == (record.t[2], running[0])
    assert record.at(0, t1 + 0.01)[1].relay == relay
    assert recorder.counts["states"] == 4
    assert core.recording["thinned_states"] == core.recording["state_backlog_overflow"] == 0


def test_a_waiting_core_keeps_one_state_per_agent_however_many_arrive(tmp_path) -> None:
    """While waiting, states are kept by id as they arrive (not appended and thinned once a
    tick): 3000 states of 2 agents between two ticks overflow nothing, and the first record
    holds each agent's newest."""
    core, recorder = recording_core(tmp_path)
    join(core, [0, 1])
    core.tick(0.0, WALL0)
    for k in range(3000):
        hear(core, AgentState(k % 2, 0.0, 0.0, WALL0 + k, (1 - k % 2,)))
    started = start(core)
    core.tick(started + 0.05, WALL0 + started + 0.05)
    recorder.close()
    record = read_agent_states(tmp_path / "run.mcap")
    assert core.recording["state_backlog_overflow"] == 0
    assert sorted(state.stamp for state in record.states) == [WALL0 + 2998, WALL0 + 2999]


def test_states_are_thinned_to_each_agents_newest_past_the_budget_and_counted(tmp_path) -> None:
    """A record costing 4 ticks' worth of RECORD_SHARE skips 3 ticks; the next record keeps
    only each agent's newest state received since the last one and counts the others, so
    every state received by the last record is either recorded or counted."""
    cpu = iter(np.arange(0.0, 100.0, 0.01))  # every reading 10 ms of CPU later
    core, recorder = recording_core(tmp_path, cpu_clock=lambda: float(next(cpu)))
    now = start(core)
    sent: dict[int, list[tuple[float, float]]] = {0: [], 1: []}  # (its tick's t, stamp)
    for k in range(12):
        now = round(now + 0.05, 10)
        for i in (0, 1):
            stamp = WALL0 + 100 + k + 0.1 * i
            hear(core, AgentState(i, 0.0, 0.0, stamp, (1 - i,)))
            sent[i].append((core.phase.mission_time(now), stamp))
        core.tick(now, WALL0 + now)
    recorder.close()
    record = read_agent_states(tmp_path / "run.mcap")
    counts = core.recording
    assert counts["skipped_ticks"] >= 6 and counts["thinned_states"] >= 6
    # (the states of the ticks after the last record wait for the next)
    taken = sum(when <= record.t[-1] for i in (0, 1) for when, _ in sent[i])
    assert len(record.states) + counts["thinned_states"] == taken
    for i in (0, 1):
        recorded = record.of(i)
        assert len({t for t, _ in recorded}) == len(recorded)  # one per record
        for t, state in recorded:  # the newest received by the record's tick
            assert state.stamp == max(stamp for when, stamp in sent[i] if when <= t)


def test_a_resumed_core_continues_the_mission_time_and_replays_steering() -> None:
    first = make_core(duration=30.0)
    started = start(first)
    request = SteerRequest(kind="translate", dx=0.1, dy=0.0, duration=2.0).encode()
    line = first.on_steer(request, started + 1.0, WALL0 + started + 1.0)[-1].line
    second = make_core(duration=30.0)
    # Restarted 4 s of mission after the first started, on another monotonic clock.
    second.resume(WALL0 + started, 100.0, WALL0 + started + 4.0, [line])
    domain = of(PublishDomain, second.tick(100.0, WALL0 + started + 4.0))[0].domain
    assert domain.state == RUNNING and domain.t == pytest.approx(4.0)
    np.testing.assert_allclose(domain.vertices, first.steering.domain(4.0)[0], atol=1e-9)


def test_a_steering_check_vetoes_a_planned_motion() -> None:
    seen = []

    def no_left_of(x: float):
        def check(motion, begin: float, end: float) -> None:
            seen.append((begin, end))
            if motion(end)[0][:, 0].min() < x:
                raise Refusal("outside-workspace", f"S would pass x = {x} m")

        return check

    request = SteerRequest(kind="translate", dx=-0.3, dy=0.0, duration=2.0).encode()
    for limit, accepted in ((-10.0, True), (0.4, False)):
        core = make_core(duration=30.0, checks=(no_left_of(limit),))
        now = start(core) + 1.0
        (reply,) = of(ReplySteer, core.on_steer(request, now, WALL0 + now))
        assert reply.accepted is accepted
    assert SteerReply.decode(reply.payload).reason.startswith("outside-workspace")
    np.testing.assert_allclose(  # S kept its script
        core.steering.domain(5.0)[0], core.settings.scenario.domain(5.0)[0]
    )
    begin, end = seen[-1]
    assert begin >= 1.0 and end > begin


def test_domains_of_another_publisher_are_counted_not_its_own(caplog) -> None:
    """The coordinator hears its own Domains come back (ignored) and counts any other on
    the key: a second coordinator's, a forger's, or garbage (issue 21)."""
    core = make_core()
    own = [of(PublishDomain, core.tick(0.05 * k, WALL0 + 0.05 * k))[0].domain for k in range(5)]
    for domain in own:
        core.on_domain_heard(domain.encode())
    assert core.observed.foreign_domains == 0
    impostor = dataclasses.replace(own[-1], stamp=own[-1].stamp + 1e-3)
    with caplog.at_level(logging.ERROR, logger="covswarm.coordinator"):
        core.on_domain_heard(impostor.encode())
        core.on_domain_heard(b"\xc1garbage")
    assert core.observed.foreign_domains == 2
    assert "another process publishes" in caplog.text


def test_an_offloaded_sample_enters_the_record_once_done_with_the_inline_value() -> None:
    """e_a computed on a worker thread (coordinator.main at 1000 robots): the ticks go on
    broadcasting while it runs, no second sample starts, and once it is done the next tick
    records the same time and value as a core that sampled inline."""
    release = threading.Event()

    def gated(pool: ThreadPoolExecutor):
        def submit(job):
            return pool.submit(lambda: (release.wait(10), job())[1])

        return submit

    with ThreadPoolExecutor(max_workers=1) as pool:
        settings = make_core().settings
        inline = CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)
        worker = CoordinatorCore(
            settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0, offload=gated(pool)
        )
        started = [start(core) for core in (inline, worker)][0]
        centre = settings.scenario.domain(0.0)[0].mean(axis=0)
        positions = centre + np.array([[-0.3, 0.1], [0.4, -0.2]])

        def tick(core: CoordinatorCore, k: int) -> list:
            now = round(started + 0.05 * (k + 1), 10)
            for i, (x, y) in enumerate(positions + 0.01 * k):
                pose = Pose(id=i, x=x, y=y, theta=0.0, stamp=WALL0 + now - 0.02, seq=k)
                core.on_pose(pose_key(SWARM, i), pose.encode())
            return core.tick(now, WALL0 + now)

        for k in range(6):  # the worker's first sample is held back all along
            tick(inline, k)
            assert of(PublishDomain, tick(worker, k))
        assert len(inline.observed.record.t) == 3 and not worker.observed.record.t
        release.set()
        while not worker._pending.result.done():
            time.sleep(0.01)
        tick(worker, 6)
        assert worker.observed.record.t == inline.observed.record.t[:1]
        assert worker.observed.record.error == inline.observed.record.error[:1]


def test_the_final_e_a_sample_takes_every_robot_at_its_time_against_s_then() -> None:
    # The last sample is taken in the tick the mission ends, the robots still riding S:
    # placed at their poses' time as the others are, not read as behind S(now) each.
    core = make_core(agents=3, duration=1.0)
    started = start(core)
    centre = core.settings.scenario.domain(0.0)[0].mean(axis=0)
    offsets = np.array([[-0.5, 0.2], [0.3, -0.4], [0.1, 0.5]])
    phases = (0.03, 0.04, 0.045)
    now, k = started, 0
    while core.phase.state != DONE:
        k += 1
        now = round(started + 0.05 * k, 10)
        for i, phase in enumerate(phases):
            stamp = WALL0 + now - phase
            t = stamp - WALL0 - started  # the mission time the pose was taken at
            x, y = core.settings.scenario.domain(t)[0].mean(axis=0) - centre + offsets[i]
            pose = Pose(id=i, x=x, y=y, theta=0.0, stamp=stamp, seq=k)
            core.on_pose(pose_key(SWARM, i), pose.encode())
        core.tick(now, WALL0 + now)
    record = core.observed.record
    assert record.t[-1] == pytest.approx(now - started - np.mean(phases), abs=1e-6)
    # The mission itself ran until the tick it ended (the summary's mission_time).
    assert core.observed.mission_time() == pytest.approx(now - started, abs=1e-9)
    assert core.observed.mission_time() >= 1.0 > record.t[-1]
    polygon = core.settings.scenario.domain(record.t[-1])[0]
    np.testing.assert_allclose(record.polygons[-1], polygon, atol=1e-12)
    # Each robot where it was at that time (moved along its last poses' velocity, S turning
    # slowly enough over 45 ms for a straight line to hold to 0.1 mm).
    at = polygon.mean(axis=0) - centre + offsets
    positions = np.array([record.positions[-1][i] for i in range(3)])
    np.testing.assert_allclose(positions, at, atol=1e-4)
    assert record.error[-1] == pytest.approx(aggregate_error(at, polygon), abs=1e-4)


def test_an_e_a_sample_takes_every_robot_at_the_sample_time() -> None:
    # Robots driving at S's speed publish at their own phase: their latest poses are 0, 20
    # and 45 ms old at each tick. The sample moves each to the one time it is placed at.
    core = make_core(agents=3, duration=30.0)
    started = start(core)
    velocity = np.array([0.19, 0.05])
    origin = np.array([[1.0, 0.0], [1.5, 0.4], [2.0, -0.3]])
    phases = (0.0, 0.02, 0.045)
    for k in range(1, 21):
        now = round(started + 0.05 * k, 10)
        for i, phase in enumerate(phases):
            stamp = WALL0 + now - phase
            x, y = origin[i] + velocity * (stamp - WALL0)
            pose = Pose(id=i, x=x, y=y, theta=0.0, stamp=stamp, seq=k)
            core.on_pose(pose_key(SWARM, i), pose.encode())
        core.tick(now, WALL0 + now)
    record = core.observed.record
    assert len(record.t) >= 5
    for t, positions in zip(record.t[-3:], record.positions[-3:], strict=True):
        at = origin + velocity * (started + t)  # the sample's wall time, since WALL0
        np.testing.assert_allclose([positions[i] for i in range(3)], at, atol=1e-9)


def test_while_waiting_the_core_names_the_missing_processes_and_the_swarm(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # A process started by hand under another --swarm hears nothing and says nothing: the
    # coordinator's log is where its operator finds what is missing.
    from covswarm.coordinator.core import WAITING_REPORT

    core = make_core(agents=4)
    join(core, [0, 1])
    core.on_liveliness(alive_key(SWARM, "robot", 2), True, 0.0, WALL0)
    with caplog.at_level(logging.INFO, logger="covswarm.coordinator"):
        now = 0.0
        while now < 2.5 * WAITING_REPORT:
            core.tick(now, WALL0 + now)
            now += 0.05
    lines = [r.getMessage() for r in caplog.records if "still waiting" in r.getMessage()]
    assert len(lines) == 2
    assert "agents 2-3 missing; robots 3 missing" in lines[0]
    assert f"--swarm {SWARM}" in lines[0]
