"""Pure bookkeeping of the coordinator: mission clock, liveness, error record, figures."""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.coordinator.monitor import (
    DONE,
    MAX_POSE_AGE,
    RUNNING,
    WAITING,
    ErrorRecord,
    Liveness,
    MissionPhase,
    agent_figures,
    clip_sample_time,
    losses_summary,
    mean_pose_time,
    positions_at,
)


def test_clock_waits_until_the_team_is_ready() -> None:
    clock = MissionPhase(duration=10.0)
    assert clock.update(100.0, team_ready=False) == WAITING
    assert clock.mission_time(105.0) == 0.0
    assert clock.update(107.0, team_ready=True) == RUNNING
    assert clock.mission_time(110.5) == pytest.approx(3.5)


def test_clock_is_done_at_duration_and_time_is_frozen_there() -> None:
    clock = MissionPhase(duration=10.0)
    clock.update(0.0, team_ready=True)
    assert clock.update(9.99, team_ready=True) == RUNNING
    # A late tick (overloaded machine) still ends the mission exactly at its duration.
    assert clock.update(10.7, team_ready=True) == DONE
    assert clock.mission_time(10.7) == 10.0
    assert clock.mission_time(50.0) == 10.0


def test_clock_never_goes_back_to_waiting_when_processes_die() -> None:
    clock = MissionPhase(duration=10.0)
    clock.update(0.0, team_ready=True)
    assert clock.update(1.0, team_ready=False) == RUNNING


def test_stop_ends_a_running_mission_early_but_not_a_waiting_one() -> None:
    waiting = MissionPhase(duration=10.0)
    waiting.stop(1.0)
    assert waiting.state == WAITING
    running = MissionPhase(duration=10.0)
    running.update(0.0, team_ready=True)
    running.stop(4.0)
    assert running.update(5.0, team_ready=True) == DONE
    assert running.mission_time(5.0) == 4.0


def test_liveness_counts_and_records_changes_only() -> None:
    live = Liveness()
    assert live.update("robot", 1, True, wall=1.0, t=None) is not None
    assert live.update("robot", 1, True, wall=1.1, t=None) is None  # repeated put
    live.update("robot", 2, True, wall=1.2, t=None)
    live.update("agent", 1, True, wall=1.3, t=None)
    assert live.count("robot") == 2 and live.count("agent") == 1 and live.count("x") == 0
    lost = live.update("robot", 2, False, wall=5.0, t=3.0)
    assert lost is not None and not lost.alive and lost.t == 3.0
    assert live.update("robot", 9, False, wall=5.0, t=3.0) is None  # never seen
    assert live.count("robot") == 1
    assert losses_summary(live.events) == [{"role": "robot", "id": 2, "t": 3.0, "wall": 5.0}]


def test_liveness_records_a_process_that_comes_back() -> None:
    live = Liveness()
    live.update("agent", 4, True, wall=0.0, t=None)
    live.update("agent", 4, False, wall=1.0, t=0.5)
    live.update("agent", 4, True, wall=2.0, t=1.5)
    assert live.count("agent") == 1
    assert [e.alive for e in live.events] == [True, False, True]


def test_error_record_trajectories_have_nan_where_unknown() -> None:
    record = ErrorRecord()
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    record.add(0.0, 0.5, {3: (0.1, 0.2), 7: (0.3, 0.4)}, square)
    record.add(0.1, 0.4, {7: (0.35, 0.45)}, square)  # robot 3 died
    record.add(0.2, 0.3, {3: (0.2, 0.2), 5: (0.9, 0.9), 7: (0.4, 0.5)}, square)
    assert record.robot_ids() == [3, 5, 7]
    traj = record.trajectories()
    assert traj.shape == (3, 3, 2)
    np.testing.assert_array_equal(traj[0, 0], [0.1, 0.2])
    assert np.isnan(traj[1, 0]).all() and np.isnan(traj[0, 1]).all()
    np.testing.assert_array_equal(traj[2, 2], [0.4, 0.5])


def test_agent_figures_summarise_whatever_stats_agents_send() -> None:
    stats = {
        2: {"rate_hz": 9.0, "step_us_p99": 4000.0},
        1: {"rate_hz": 10.0, "step_us_p99": 2000.0, "extra": 1},
    }
    figures = agent_figures(stats)
    assert figures["team"]["rate_hz"] == {"mean": 9.5, "min": 9.0, "max": 10.0}
    assert figures["team"]["extra"] == {"mean": 1.0, "min": 1.0, "max": 1.0}
    # Per agent: only the headline figures, those it reports.
    assert figures["per_agent"] == {
        "1": {"rate_hz": 10.0, "step_us_p99": 2000.0},
        "2": {"rate_hz": 9.0, "step_us_p99": 4000.0},
    }
    assert agent_figures({}) == {"team": {}, "per_agent": {}}


def test_the_mission_waits_for_the_team_to_settle() -> None:
    clock = MissionPhase(duration=10.0, settle=1.5)
    assert clock.update(0.0, team_ready=True) == WAITING
    assert clock.update(1.0, team_ready=False) == WAITING  # a member left: start over
    assert clock.update(2.0, team_ready=True) == WAITING
    assert clock.update(3.4, team_ready=True) == WAITING
    assert clock.update(3.5, team_ready=True) == RUNNING
    assert clock.mission_time(4.0) == pytest.approx(0.5)


def test_summary_has_the_sim_keys_and_process_figures() -> None:
    from covswarm.coordinator.core import CoordinatorSettings, Observed
    from covswarm.coordinator.outputs import build_summary
    from covswarm.mission.scenario_files import load_scenario

    scenario = load_scenario("passage")
    settings = CoordinatorSettings(
        scenario=scenario, swarm="s", agents=2, duration=4.0, kappa=2.0, rate=20.0,
        sample_rate=10.0, feedforward=False, law="d1",
    )  # fmt: skip
    observed = Observed()
    polygon = scenario.domain(0.0)[0]
    for k, error in enumerate([0.4, 0.3, 0.2, 0.1, 0.1]):
        observed.record.add(k, error, {0: (-2.0, 0.0), 1: (-1.5, 0.1)}, polygon)
    observed.liveness.update("agent", 1, True, wall=0.0, t=None)
    observed.liveness.update("agent", 1, False, wall=3.0, t=2.0)
    observed.agent_stats = {0: {"rate_hz": 10.0}}
    summary = build_summary(settings, observed)
    sim_keys = {
        "scenario", "agents", "law", "feedforward", "kappa", "steady_state_error_mean",
        "final_error", "neighbor_histogram",
    }  # fmt: skip
    assert sim_keys <= summary.keys()
    assert summary["law"] == "d1" and summary["feedforward"] is False
    assert summary["steady_state_error_mean"] == pytest.approx((0.2 + 0.1 + 0.1) / 3)
    assert summary["initial_error"] == 0.4 and summary["final_error"] == 0.1
    assert summary["neighbor_histogram"] == {1: 2}
    assert summary["lost_processes"] == [{"role": "agent", "id": 1, "t": 2.0, "wall": 3.0}]
    assert summary["agent_stats"]["per_agent"] == {"0": {"rate_hz": 10.0}}
    # Physical figures: the two robots stay 0.51 m apart; no agent reported its wheels.
    assert summary["min_pairwise_distance"] == pytest.approx(np.hypot(0.5, 0.1))
    assert summary["close_approaches"] == 0 and summary["max_wheel_speed_used"] is None
    observed.agent_stats = {
        0: {"wheel_max": 0.8, "saturated_s": 1.0},
        1: {"wheel_max": 0.3, "saturated_s": 0.0},
    }
    summary = build_summary(settings, observed)
    assert summary["max_wheel_speed_used"] == 0.8 and summary["saturated_time"] == 1.0
    assert summary["saturated_fraction"] == pytest.approx(1.0 / (2 * 4.0))


def test_the_swarm_tile_size_follows_the_team_spacing() -> None:
    from covswarm.coordinator.core import TILE_SPACINGS, swarm_tile_size
    from covswarm.mission.scenario_files import load_scenario

    circle = load_scenario("circle")  # a 2 m square
    assert swarm_tile_size(circle, 100) == pytest.approx(TILE_SPACINGS * 0.2)
    assert swarm_tile_size(circle, 400) == pytest.approx(TILE_SPACINGS * 0.1)
    passage = load_scenario("passage")  # starts in a 1.2 m x 1.6 m box
    assert swarm_tile_size(passage, 10) == pytest.approx(
        TILE_SPACINGS * (1.2 * 1.6 / 10) ** 0.5, abs=1e-3
    )


def measurement_time(t: float, wall_now: float, stamps: list[float], earliest: float) -> float:
    """Where the coordinator places an e_a sample."""
    return clip_sample_time(mean_pose_time(t, wall_now, stamps), t, earliest)


def test_e_a_is_placed_at_the_mean_time_its_poses_were_measured() -> None:
    # Mission time 10 s at wall 1000 s: poses 20 ms and 40 ms old were measured at 9.97 s.
    assert measurement_time(10.0, 1000.0, [999.98, 999.96], earliest=9.5) == pytest.approx(9.97)
    assert measurement_time(10.0, 1000.0, [], earliest=9.5) == 10.0


def test_measurement_time_stays_in_order_and_within_the_age_bound() -> None:
    # A pose from a robot that went quiet long ago does not drag the sample back further.
    assert measurement_time(10.0, 1000.0, [990.0], earliest=0.0) == 10.0 - MAX_POSE_AGE
    # Never before the previous sample, never after now (a clock ahead of ours).
    assert measurement_time(10.0, 1000.0, [999.9], earliest=9.95) == 9.95
    assert measurement_time(10.0, 1000.0, [1000.3], earliest=9.0) == 10.0
    assert measurement_time(10.0, 1000.0, [float("nan")], earliest=9.0) == 10.0
    # At the mission's start there is nothing earlier than 0.
    assert measurement_time(0.0, 1000.0, [999.9], earliest=0.0) == 0.0


def test_e_a_compares_every_robot_at_one_time() -> None:
    # Three robots on straight lines at 0.2 m/s, their latest poses 0, 20 and 45 ms old.
    velocity = np.array([[0.2, 0.0], [0.0, -0.2], [0.1, 0.1]])
    start = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.5]])

    def at(when: np.ndarray) -> np.ndarray:
        return start + velocity * when[:, None]

    stamps = np.array([100.0, 99.98, 99.955])
    earlier = stamps - np.array([0.05, 0.05, 0.1])
    moved = positions_at(99.99, stamps, at(stamps), earlier, at(earlier))
    np.testing.assert_allclose(moved, at(np.full(3, 99.99)), atol=1e-12)
    # No velocity known: no earlier pose, one not older, one older than MAX_POSE_AGE.
    unknown = np.array([np.nan, stamps[1], stamps[2] - 2 * MAX_POSE_AGE])
    points = at(stamps)
    np.testing.assert_array_equal(positions_at(99.99, stamps, points, unknown, points), points)
    # A stamp far off moves a robot by at most MAX_POSE_AGE of its velocity.
    far = positions_at(120.0, stamps, points, earlier, at(earlier))
    np.testing.assert_allclose(far, points + velocity * MAX_POSE_AGE, atol=1e-12)
