"""A packed run of a few hundred robots holds its rate (issue 24), as real processes over
loopback Zenoh.

200 agents and 200 simulated robots, ``auto`` packing (one agent process per core, 100
brains each on this 2-core machine, the brains due in a tick stepped as one batch), at a
twentieth of real time: the 1000-robot runs belong in the README's commands, not in CI. The
run must hold its 10 Hz of mission time with at most 1 % of periods missed, never slow its
script down, cover the domain, and leave no process behind.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from live_runs import launch, new_swarm, swarm_pids

from covswarm.deploy.simulate import simulate
from covswarm.mission.report import steady_state_mean
from covswarm.mission.scenario_files import load_scenario

AGENTS = 200
# mission s per wall s. On a host three times slower than usual (a 500-brain bench tick of
# 0.9 ms), with the suite's other worker busy beside it, the run held 8.7 Hz at 0.25 and 8.9
# Hz at 0.15 (30 Nov 2026); at 0.1, 9.9999 Hz alone but 9.876 Hz once in four clean-clone CI
# runs with the other worker busy (2 Dec 2026): half that, for the margin.
TIME_SCALE = 0.05
# Steady-state e_a of the run over that of `covswarm sim` of the same mission stepped at
# 10 Hz. e_a is the norm over the team, so one or two robots decide it: before 3 Dec 2026 a
# corner robot held back outside S by two robots that stopped each other dead side by side
# ahead of it (docs/real-robots.md, "Side by side, none ahead"): 0.47-0.58 idle, 0.93 with
# one core kept busy, 1.10 and 1.48 with both, 2.72 in a clean-clone CI run, against a
# reference of 0.0624 m. With their slide at once the reference is 0.0364 m (the simulator
# has the rule too) and the runs (4 s at 0.05x, 3 Dec 2026): 0.97-0.98 in three on an idle
# machine, 1.88 with one core kept busy, 1.02 with both, 1.26 and 1.01 beside tests/test_e2e.py
# (no robot's cell empty in any). The target (1.5) belongs to the 1000-robot run of
# the README; this bound is twice the measured spread's top, and a team that flies apart
# (tens of metres) is hundreds of times the reference.
RATIO_BOUND = 4.0
SCENARIO = Path(__file__).parent / "data" / "square-200.toml"
DURATION = 4.0  # s of mission (the file's 6 s in docs/scaling.md)


@pytest.mark.e2e
def test_a_packed_team_of_two_hundred_holds_its_rate(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "packed"
    args = ["--scenario", str(SCENARIO), "--agents", str(AGENTS), "--duration", str(DURATION),
            "--time-scale", str(TIME_SCALE), "--no-record"]  # fmt: skip
    with launch(out, *args, swarm=swarm) as launcher:
        code = launcher.wait(timeout=240)
        assert code == 0, (tmp_path / "packed.launcher.log").read_text()
    assert swarm_pids(swarm) == set()
    resources = json.loads((out / "resources.json").read_text())
    assert len(resources["robots_per_process"]["agent"]) <= 4  # packed, not 200 processes
    summary = json.loads((out / "summary.json").read_text())
    assert summary["alive_at_end"] == {"agents": AGENTS, "robots": AGENTS}
    team = summary["agent_stats"]["team"]
    assert team["step_errors"]["max"] == 0 and team["batch_fallbacks"]["max"] == 0
    # The rate held: 10 Hz of mission time, at most 1 % of periods missed on average.
    pace = summary["pace"]
    assert pace["held_rate_hz"] >= 9.9 and pace["periods_missed"] <= 0.01
    assert team["late_held"]["mean"] <= 0.01
    assert pace["pace_min"] == pytest.approx(1.0)  # the script never had to slow down
    # The team covers its moving domain about as well as the same mission stepped at 10 Hz
    # in one process (RATIO_BOUND).
    sim = simulate(
        load_scenario(SCENARIO), dt=0.1, duration=DURATION, dynamics="unicycle", safety=True
    )
    assert summary["initial_error"] == pytest.approx(float(sim.error[0]))  # same start
    live, reference = summary["steady_state_error_mean"], steady_state_mean(sim.t, sim.error)
    assert live <= RATIO_BOUND * reference, (live, reference, team["cell_empty"], pace)
    # Converging: the second half's mean e_a over the start's, measured 0.28-0.33 (two runs,
    # 27 Nov 2026 18:34 UTC), and 0.56 in a CI run where one robot's cell stayed empty for
    # 24 steps near the end (the trap, docs/scaling.md), whose final e_a was 0.63 of the
    # start's: the mean, not the last instant, with the trap's spread.
    assert summary["steady_state_error_mean"] < 0.7 * summary["initial_error"]
