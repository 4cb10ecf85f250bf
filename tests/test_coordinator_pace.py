"""Pacing the script to what the team holds (coordinator.pace), sans-IO: a core fed agents'
stats as a starved team would report them, checked against finite differences of S."""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.agent.faults import delay_steps
from covswarm.coordinator.core import (
    DONE,
    RUNNING,
    WAITING,
    CoordinatorCore,
    CoordinatorSettings,
    PublishDomain,
    PublishStatus,
    RecordScriptClock,
)
from covswarm.coordinator.monitor import MAX_POSE_AGE
from covswarm.coordinator.pace import (
    BAND_PACE,
    DROP_BAND,
    PACE_FLOOR,
    RISE_BAND,
    RISE_RATE,
    Pace,
    ScriptClock,
    broadcast_motion,
    held_fraction,
    next_pace,
    pace_sentence,
    team_target,
)
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import AgentState, Pose, agent_state_key, alive_key, pose_key
from covswarm.tvd.density import Density

SWARM = "pace-test"
WALL0 = 1.7e9
TICK = 0.05  # s: the core's broadcast period (20 Hz)
ASKED = 10.0  # Hz


def make_core(scenario: str = "circle", duration: float = 20.0, pace: bool = True, n: int = 4):
    settings = CoordinatorSettings(
        scenario=load_scenario(scenario), swarm=SWARM, agents=n, duration=duration,
        kappa=2.0, rate=1 / TICK, sample_rate=10.0, feedforward=True, tile_size=0.5,
        agent_rate=ASKED, pace=pace,
    )  # fmt: skip
    return CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)


class Team:
    """The agents of a core, each stepping at ``held`` Hz, with an AgentState each step (a
    brain's exchange round: the start waits for START_ROUNDS of the slowest's), its stats
    in one a second (its mission steps counted from the start, as AgentBrain.stats)."""

    def __init__(self, core: CoordinatorCore, held: float) -> None:
        self.core, self.held = core, held
        self.steps = dict.fromkeys(range(core.settings.agents), 0.0)
        self.next_report = self.next_step = 0.0
        for i in self.steps:
            for role in ("robot", "agent"):
                core.on_liveliness(alive_key(SWARM, role, i), True, 0.0, WALL0)

    def ring(self, i: int) -> tuple[int, ...]:
        """Agent ``i``'s neighbours: those next to it in a ring of the team (each names the
        other, so nothing is missing from the team's discovery)."""
        n = len(self.steps)
        return tuple({(i - 1) % n, (i + 1) % n} - {i})

    def run(self, now: float, until: float) -> tuple[float, list]:
        """Tick the core every TICK from ``now`` to ``until``; (now, every tick's actions)."""
        ticks = []
        while now < until - 1e-9:
            now = round(now + TICK, 9)
            running = self.core.phase.state == RUNNING
            for i in self.steps:
                self.steps[i] += self.held * TICK * running
            if now >= self.next_report:
                for i, steps in self.steps.items():
                    stats = {"rate_hz": self.held, "mission_steps": round(steps), "late_held": 0.5}
                    state = AgentState(
                        id=i, x=0.0, y=0.0, stamp=WALL0 + now, neighbors=self.ring(i), stats=stats
                    )
                    self.core.on_agent_state(agent_state_key(SWARM, i), state.encode())
                self.next_report = now + 1.0
            if now >= self.next_step:  # (with the stats' state of this tick: one round)
                for i in self.steps:
                    state = AgentState(
                        id=i, x=0.0, y=0.0, stamp=WALL0 + now, neighbors=self.ring(i)
                    )
                    self.core.on_agent_state(agent_state_key(SWARM, i), state.encode())
                self.next_step = now + 1.0 / self.held
            ticks.append((now, self.core.tick(now, WALL0 + now)))
        return now, ticks


def domains(ticks: list) -> list:
    return [
        (now, a.domain) for now, actions in ticks for a in actions if isinstance(a, PublishDomain)
    ]


def test_the_held_fraction_of_an_agent_and_of_the_team() -> None:
    stats = {"mission_steps": 40, "rate_hz": 7.0}
    assert held_fraction(stats, 12.0, (10.0, 30), 10.0) == pytest.approx(0.5)
    assert held_fraction(stats, 12.0, None, 10.0) == pytest.approx(0.7)  # no earlier report
    assert held_fraction(stats, 12.0, (10.0, 0), 10.0) == pytest.approx(0.7)  # before the start
    assert held_fraction({}, 12.0, None, 10.0) == 0.0
    assert team_target([]) == 1.0
    assert team_target([0.82] * 9 + [1.0]) == 1.0  # FULL and above: the rate is held
    assert team_target([0.001, 0.002]) == PACE_FLOOR
    # The slowest tenth: one stalled member of twenty does not set the pace alone.
    assert team_target([0.0] + [0.5] * 19) == pytest.approx(0.5)
    assert team_target([0.3] * 10) == pytest.approx(0.3)


def test_the_pace_falls_at_once_rises_slowly_and_ignores_jitter() -> None:
    assert next_pace(1.0, 0.3, 0.05) == 0.3
    assert next_pace(0.3, 1.0, 0.05) == pytest.approx(0.3 + RISE_RATE * 0.05)
    assert next_pace(0.3, 0.32, 0.05) == 0.3  # within the dead band, either way
    assert next_pace(0.5, 0.5 - DROP_BAND / 2, 0.05) == 0.5
    pace = 0.3
    for _ in range(round(10 / 0.05)):  # 10 s of a team back at full rate
        pace = next_pace(pace, 1.0, 0.05)
    assert pace == 1.0


def test_at_a_low_pace_the_band_shrinks_with_it() -> None:
    # At the floor a team holding 2.4 % of its rate is followed (the band there is 0.0025,
    # not 0.05), and one holding 2 % more than the pace of 0.4 is not.
    assert next_pace(PACE_FLOOR, 0.024, 0.05) == pytest.approx(PACE_FLOOR + RISE_RATE * 0.05)
    assert next_pace(0.02, 0.026, 1.0) == 0.026
    assert next_pace(0.02, 0.0195, 0.05) == 0.02  # within the band, either way
    assert next_pace(0.02, 0.016, 0.05) == 0.016
    assert next_pace(0.4, 0.42, 0.05) == 0.4
    assert next_pace(BAND_PACE, BAND_PACE + RISE_BAND * 0.9, 0.05) == BAND_PACE


def test_script_time_and_mission_time_are_inverse_along_a_varying_pace() -> None:
    rng = np.random.default_rng(3)
    pace = Pace(ASKED)
    pace.target = lambda team: float(rng.uniform(PACE_FLOOR, 1.0))  # a team in turmoil
    t = 0.0
    for _ in range(200):
        pace.advance(t, ())
        t += float(rng.uniform(0.01, 0.1))
    assert len(set(pace.pace_log)) > 50
    for when in rng.uniform(0.0, t, 50):
        assert pace.mission_time(pace.script_time(when)) == pytest.approx(when, abs=1e-9)
    # Between two ticks tau runs at the pace broadcast at the first.
    k = 77
    mid = 0.5 * (pace.t_log[k] + pace.t_log[k + 1])
    slope = (pace.script_time(pace.t_log[k + 1]) - pace.script_time(mid)) / (
        pace.t_log[k + 1] - mid
    )
    assert slope == pytest.approx(pace.pace_log[k])
    with pytest.raises(ValueError, match="rate"):
        Pace(0.0)


def test_a_starved_team_slows_the_script_with_exact_velocities_then_recovers() -> None:
    core = make_core()
    team = Team(core, held=3.0)  # 3 Hz of 10 asked
    now, ticks = team.run(0.0, 5.0)
    assert core.phase.state == RUNNING
    # Below 0.5 within 2.5 s of the start: the measure does not wait for a 5 s window.
    assert min(core.pace.pace_log[: round(2.5 / TICK)]) < 0.5
    # The velocities broadcast are dS/dt: a finite difference of S over mission time, at a
    # pace of 0.3 (the script's own derivative is 1 / 0.3 times larger).
    scenario = core.settings.scenario
    tick = core.tick(now + 1e-4, WALL0 + now + 1e-4)
    for h in (1e-4,):
        before = domains([(now, ticks[-1][1])])[0][1]
        after = domains([(now + h, tick)])[0][1]
        fd = (np.asarray(after.vertices) - np.asarray(before.vertices)) / h
        np.testing.assert_allclose(before.velocities, fd, atol=2e-4)
        script_velocity = scenario.domain(core.pace.script_time(before.t))[1]
        np.testing.assert_allclose(before.velocities, core.pace.pace * script_velocity)
        assert np.abs(fd).max() < 0.4 * np.abs(script_velocity).max()
        assert np.abs(script_velocity).max() > 0.05
    assert core.pace.tau < 0.5 * before.t  # the script is behind mission time
    status = [a.status for _, acts in ticks for a in acts if isinstance(a, PublishStatus)][-1]
    assert status.pace == pytest.approx(core.pace.pace) and status.script_t is not None
    assert type(status).decode(status.encode()) == status
    # Back at full rate: the pace climbs at most RISE_RATE per s and reaches 1.
    team.held = ASKED
    rising_from = core.pace.pace
    now, ticks = team.run(now + 1e-4, now + 3.0)
    assert core.pace.pace <= rising_from + RISE_RATE * 3.0 + 1e-9
    now, ticks = team.run(now, now + 8.0)
    assert core.pace.pace == 1.0


def test_the_mission_ends_when_the_script_does_and_the_summary_says_what_was_held() -> None:
    core = make_core(duration=4.0)
    team = Team(core, held=2.0)
    for i in range(core.settings.agents):
        core.on_pose(pose_key(SWARM, i), Pose(id=i, x=0.1 * i, y=0.0, theta=0.0,
                                              stamp=WALL0, seq=0).encode())  # fmt: skip
    now, ticks = team.run(0.0, 60.0)
    assert core.phase.state == DONE
    mission = core.phase.mission_time(now)
    assert mission > 4.0 / 0.3  # at 0.2 x for most of it
    assert core.pace.tau == pytest.approx(4.0)
    last = domains(ticks)[-1][1]
    np.testing.assert_allclose(last.vertices, core.settings.scenario.domain(4.0)[0])
    # The final e_a sample is against S on the script's clock, not the mission's: at the
    # script time of its poses (stamped long ago: the sample is placed MAX_POSE_AGE back).
    record = core.observed.record
    assert record.t[-1] == pytest.approx(mission - MAX_POSE_AGE)
    script = core.pace.script_time(record.t[-1])
    assert 4.0 - MAX_POSE_AGE <= script < 4.0
    np.testing.assert_allclose(record.polygons[-1], core.settings.scenario.domain(script)[0])
    summary = core.pace.summary(core.observed.agent_stats, mission)
    assert summary["held_rate_hz"] == pytest.approx(2.0, rel=0.1)
    assert summary["periods_missed"] == pytest.approx(0.8, abs=0.03)
    assert summary["pace_min"] == pytest.approx(0.2, abs=0.05)  # whole steps in a window
    assert summary["script_time"] == pytest.approx(4.0)
    assert summary["pace_mean"] == pytest.approx(4.0 / mission)
    words = pace_sentence(summary)
    assert f"held {summary['held_rate_hz']:.3g} Hz of 10 asked" in words
    assert f"ran at {summary['pace_mean']:.2f}x" in words and "50% skipped" in words


def test_without_pacing_the_script_keeps_its_speed_whatever_is_held() -> None:
    core = make_core(duration=3.0, pace=False)
    team = Team(core, held=2.0)
    now, ticks = team.run(0.0, 10.0)
    assert core.phase.state == DONE and core.phase.mission_time(now) == pytest.approx(3.0)
    assert set(core.pace.pace_log) == {1.0}
    assert core.pace.tau == pytest.approx(3.0)
    summary = core.pace.summary(core.observed.agent_stats, 3.0)
    assert not summary["enabled"] and summary["held_rate_hz"] == pytest.approx(2.0, rel=0.15)
    assert pace_sentence(summary).count("pacing off") == 1


def test_the_team_is_paced_by_its_latest_reports_of_its_members() -> None:
    pace = Pace(ASKED)
    for i in range(20):
        pace.report(i, {"rate_hz": 10.0 if i else 0.5}, WALL0)
    assert pace.target(range(20)) == 1.0  # one slow member of twenty does not set it
    for i in range(3):
        pace.report(i, {"rate_hz": 3.0}, WALL0 + 1.0)
    assert pace.target(range(20)) == pytest.approx(0.3)  # three of twenty: the slowest tenth
    assert pace.target(range(3, 20)) == 1.0  # the slow ones left the team
    assert pace.target([]) == 1.0  # no member known: nothing to wait for


def test_a_moving_density_is_broadcast_with_its_rates_scaled_by_the_pace() -> None:
    core = make_core("formation", n=4)
    team = Team(core, held=4.0)
    now, ticks = team.run(0.0, 5.0)
    before = domains(ticks)[-1][1]
    h = 1e-3
    after = domains([(now + h, core.tick(now + h, WALL0 + now + h))])[0][1]
    assert core.pace.pace < 0.5
    points = np.random.default_rng(0).uniform(-1.0, 1.0, (200, 2))
    then, later = Density.from_dict(before.density), Density.from_dict(after.density)
    # What an agent extrapolates (its advance by h) is what the coordinator sends at t + h.
    np.testing.assert_allclose(then.at(then.time + h).phi(points), later.phi(points), rtol=1e-6)
    assert np.abs(later.phi(points) - then.phi(points)).max() > 1e-6  # it does move
    assert then.time == pytest.approx(before.t)


def test_the_step_delay_fault_sleeps_after_every_step_begins() -> None:
    slept: list[float] = []

    class Brain:
        def begin(self, now: float, wall: float) -> str:
            slept.append(-1.0)  # the step's first phase, before the sleep
            return "begun"

    brains = [Brain(), Brain()]
    delay_steps(brains, 0.04, sleep=slept.append)
    assert brains[0].begin(0.0, WALL0) == "begun" and slept == [-1.0, 0.04]
    delay_steps(brains[1:], 0.0, sleep=slept.append)  # no fault: left as it was
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="step delay"):
            delay_steps(brains, bad)


def test_a_waiting_core_keeps_s_still_at_the_script_start() -> None:
    core = make_core()
    domain = [a for a in core.tick(0.0, WALL0) if isinstance(a, PublishDomain)][0].domain
    assert domain.state == WAITING and not np.any(domain.velocities)
    np.testing.assert_allclose(domain.vertices, core.settings.scenario.domain(0.0)[0])


def test_a_resumed_coordinator_continues_the_script_where_the_first_left_it() -> None:
    first = make_core()
    now, ticks = Team(first, held=3.0).run(0.0, 6.0)  # the script slowed to ~0.3x
    recorded = [a.clock for _, acts in ticks for a in acts if isinstance(a, RecordScriptClock)]
    assert len(recorded) >= 6 / 0.5 - 4  # with every status while running
    clock = ScriptClock.from_json(recorded[-1].to_json(SWARM), SWARM)
    assert clock == recorded[-1] and clock.tau < 0.6 * clock.t and clock.pace < 0.5
    # Restarted 2 s of mission later, on another monotonic clock.
    gap = 2.0
    second = make_core()
    later = clock.t + gap
    started = WALL0 + now - first.phase.mission_time(now)  # the first's start, wall
    second.resume(started, 100.0, started + later, [], clock)
    domain = domains([(100.0, second.tick(100.0, started + later))])[0][1]
    assert domain.t == pytest.approx(later)
    tau = clock.tau + clock.pace * gap  # what the agents extrapolated meanwhile
    scenario = second.settings.scenario
    np.testing.assert_allclose(domain.vertices, scenario.domain(tau)[0], atol=1e-9)
    # From there the pace follows the team (unheard yet: up by at most RISE_RATE per s).
    assert clock.pace < second.pace.pace <= clock.pace + RISE_RATE * gap + 1e-9
    np.testing.assert_allclose(domain.velocities, second.pace.pace * scenario.domain(tau)[1])
    # Not from the mission time: that S is far ahead (~0.19 m/s over the slowed seconds).
    assert np.abs(np.asarray(domain.vertices) - scenario.domain(later)[0]).max() > 0.3
    for bad in (
        "{}",
        "[1]",
        clock.to_json("another-swarm"),
        ScriptClock(1.0, 1.0, 1.0).to_json(SWARM).replace('"pace": 1.0', '"pace": 0.0'),
        ScriptClock(1.0, 1.0, 1.0).to_json(SWARM).replace('"script_t": 1.0', '"script_t": NaN'),
    ):
        with pytest.raises(ValueError):
            ScriptClock.from_json(bad, SWARM)


def test_the_held_rate_is_measured_up_to_each_agents_last_report() -> None:
    # A team that holds the asked 10 Hz, whose last stats (once a second) came 0.9 s
    # before the mission's end: over the mission's length it would read as 18 % missed.
    pace = Pace(asked=10.0)
    stats = {}
    for i in range(3):
        for k in range(5):
            stats[i] = {"mission_steps": 10.0 * k + 3.0, "rate_hz": 10.0}
            pace.report(i, stats[i], 100.0 + k + 0.3)
    summary = pace.summary(stats, 4.3 + 0.9)
    assert summary["held_rate_hz"] == pytest.approx(10.0)
    assert summary["periods_missed"] == pytest.approx(0.0)
    # One report only: its steps over the whole mission.
    single = Pace(asked=10.0)
    single.report(0, {"mission_steps": 26.0}, 100.0)
    assert single.summary({0: {"mission_steps": 26.0}}, 5.2)["held_rate_hz"] == pytest.approx(5.0)


def test_only_a_running_s_moves_and_a_waiting_one_announces_its_start() -> None:
    moving = np.array([[0.1, 0.0], [0.1, 0.05], [0.0, 0.2]])
    velocities, start = broadcast_motion("running", moving, 0.25)
    np.testing.assert_array_equal(velocities, 0.25 * moving)
    assert start is None
    velocities, start = broadcast_motion("waiting", moving, 0.25)
    assert not np.any(velocities) and velocities.shape == moving.shape
    np.testing.assert_array_equal(start, moving)  # the script's, not paced
    assert broadcast_motion("waiting", np.zeros((3, 2)))[1] is None  # S starts still
    velocities, start = broadcast_motion("done", moving)
    assert not np.any(velocities) and start is None
