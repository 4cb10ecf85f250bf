"""Overload degrades gracefully (issue 24, item 4), as real processes over loopback Zenoh.

An artificially starved team: ``--fault-step-delay`` makes every brain step sleep, so two
agent processes of six brains each hold only a few of their 10 Hz, whatever the machine's
load (the sleep loads no core). The coordinator must slow the script down to what they
hold (coordinator.pace), the team must stay together (e_a bounded like an unstarved run's,
where without pacing it grows to tenths of metres: docs/scaling.md), and the launcher and
summary.json must say which rate was held.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from live_runs import launch, new_swarm, swarm_pids

# Measured (12 robots, circle, 6 per process, 0.05 s per step, see the report of branch
# overload): the team holds about 3 Hz of 10 and the script runs at about 0.3x.
STEP_DELAY = 0.05
DURATION = 4.0  # s of script


@pytest.mark.e2e
def test_a_starved_team_slows_down_and_stays_together(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "starved"
    args = [
        "--scenario", "circle", "--agents", "12", "--duration", str(DURATION),
        "--agents-per-process", "6", "--fault-step-delay", str(STEP_DELAY), "--no-record",
    ]  # fmt: skip
    with launch(out, *args, swarm=swarm) as launcher:
        assert launcher.wait(timeout=150) == 0, (tmp_path / "starved.launcher.log").read_text()
    assert swarm_pids(swarm) == set()
    summary = json.loads((out / "summary.json").read_text())
    pace = summary["pace"]
    # Six brains of 0.05 s each per 0.1 s period: two step per period, each about 3.3 Hz.
    assert pace["enabled"] and pace["asked_rate_hz"] == 10.0
    assert 1.0 < pace["held_rate_hz"] < 5.0 and pace["periods_missed"] > 0.4
    assert pace["late_held"] > 0.3  # the packed processes skipped late brains' periods
    # The script slowed down to about what was held, and the mission ended with the script.
    assert pace["pace_min"] < 0.6
    assert pace["pace_mean"] == pytest.approx(pace["held_rate_hz"] / 10.0, abs=0.15)
    assert pace["script_time"] == pytest.approx(DURATION)
    assert summary["mission_time"] > DURATION / 0.6
    # The team stayed together: e_a never rose far above its start and ended near an unstarved
    # run's (measured with this mission, load 17-19: starved and paced 0.012-0.019 m over
    # the second half and 0.006-0.011 m at the end; starved with --no-pace 0.50 m and 0.58 m;
    # covswarm sim at 10 Hz 0.006 m and 0.013 m. Bound 0.05 m, the fault tests' own).
    with (out / "error.csv").open() as rows:
        errors = [float(row["e_a"]) for row in csv.DictReader(rows)]
    assert max(errors) <= 1.25 * summary["initial_error"]  # measured up to 1.06x: turning
    assert summary["steady_state_error_mean"] < 0.05
    assert summary["final_error"] < 0.05
    # The launcher says so in plain words.
    log = " ".join((tmp_path / "starved.launcher.log").read_text().split())
    assert f"the machine held {pace['held_rate_hz']:.3g} Hz of 10 asked" in log.replace("│ ", "")
