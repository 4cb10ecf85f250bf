"""The agents' latency compensation and safety filter in the in-process replica of a run
(deploy/netsim.py: the real brains and robot sims on a simulated clock, deterministic)."""

from __future__ import annotations

import pytest

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import run_netsim, steady_state
from covswarm.mission.physical import physical_summary
from covswarm.mission.scenario_files import load_scenario

AGENTS, DURATION = 6, 30.0


def passage(**options: object) -> tuple[float, dict]:
    """(steady-state e_a, physical figures) of a short passage run."""
    extra = {k: options.pop(k) for k in ("clock_skew", "command_delay") if k in options}
    result = run_netsim(
        load_scenario("passage"), agents=AGENTS, duration=DURATION,
        config=AgentConfig(**options), **extra,
    )  # fmt: skip
    return steady_state(result), physical_summary(result.t, result.trajectories, 0.14)[0]


@pytest.fixture(scope="module")
def undelayed() -> float:
    return passage()[0]


@pytest.mark.parametrize(
    "impairment",
    [
        {"pose_delay": 0.3},
        {"pose_delay": 0.15, "pose_loss": 0.3},
        {"clock_skew": 0.3},  # the robots' clock 0.3 s ahead of the agents': corrected
    ],
)
def test_compensated_agents_keep_the_undelayed_error(undelayed: float, impairment: dict) -> None:
    error, physical = passage(**impairment)
    # A clock ahead is corrected only to within the least receipt delay the agent sees: it
    # takes poses at its tick, whose phase to the robots' 20 Hz it keeps (0-50 ms). Measured
    # 1.53x the undelayed error here (seed 0), 1.19-1.64x over seeds 0-4 (netsim delivering
    # as Zenoh does, 30 Nov 2026; 1.11-1.51x before), so the band is the spread's top.
    assert error <= (1.7 if "clock_skew" in impairment else 1.5) * undelayed, (error, undelayed)
    # No robots closer than a diameter after the start (robots start apart).
    assert all(a["start"] < 1.0 for a in physical["close_approach_list"])


def test_without_prediction_a_late_pose_breaks_the_team(undelayed: float) -> None:
    error, _ = passage(pose_delay=0.3, prediction=False)
    assert error > 10 * undelayed  # measured without prediction: robots random-walk away


def test_a_pose_over_a_second_late_is_predicted_not_steered_from_as_if_fresh(
    undelayed: float,
) -> None:
    # Poses 1.2 s late (an overloaded host delivered 1000 robots' ~1 s late, p99 1.2 s)
    # were accepted but not predicted beyond 1 s: measured 3.9 m (6 robots), against 0.054
    # m predicted along the command history (covswarm.agent.brain.POSE_HORIZON; 0.050-0.067
    # m over seeds 0-4, 30 Nov 2026); its neighbours' states arrive as late and are
    # dead-reckoned at most 0.5 s. Closest approach after the start here 0.252 m; one of
    # seeds 0-4 (3) has one at 0.125 m, 1.4 s in (docs/scaling.md, "Phantom beacons").
    error, physical = passage(pose_delay=1.2)
    assert error < 0.3, (error, undelayed)
    assert all(a["start"] < 1.0 for a in physical["close_approach_list"])


def test_robots_whose_poses_are_too_old_to_predict_stop() -> None:
    # Accepted (a clock skew allowance of 3 s) but older than the command history: the
    # robots stop rather than steer from them, and each such step is counted.
    result = run_netsim(
        load_scenario("passage"), agents=AGENTS, duration=10.0,
        config=AgentConfig(pose_delay=2.5, max_clock_skew=3.0),
    )  # fmt: skip
    moved = result.trajectories[-1] - result.trajectories[0]
    assert float(abs(moved).max()) < 0.01
    assert all(stats["pose_too_old"] > 0 for stats in result.stats.values())


def test_robots_of_dead_brains_stand_and_the_others_take_them_as_still_generators() -> None:
    # Brains 0 and 3 never run: their robots stand where placed; every live brain sees them
    # stranded (a robot's token without its agent's) and follows them as still generators.
    result = run_netsim(load_scenario("passage"), agents=AGENTS, duration=6.0, dead=(0, 3))
    moved = abs(result.trajectories[-1] - result.trajectories[0]).max(axis=1)
    assert moved[[0, 3]].max() == 0.0
    assert moved[[1, 2, 4, 5]].min() > 0.05, moved
    assert result.started < 2.0 + 1.0, result.started  # no wait for the dead brains' tokens
    for index in (1, 2, 4, 5):
        assert result.stats[index]["stranded_followed"] >= 1, result.stats[index]


@pytest.mark.parametrize("dead", [(6,), (-1,), (0, 1, 2, 3, 4, 5)])
def test_dead_brains_are_refused_unless_indices_of_some_of_the_team(dead: tuple) -> None:
    with pytest.raises(ValueError, match="dead"):
        run_netsim(load_scenario("passage"), agents=AGENTS, duration=1.0, dead=dead)
