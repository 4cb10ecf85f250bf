"""The launcher times a brain-tick on its host (deploy.host_speed) before it plans a packed
team, and everything the plan derives from a brain-tick follows what it measured."""

from __future__ import annotations

import io

import pytest
from rich.console import Console

from covswarm.deploy.host_speed import LIVE_PER_BENCH, measure_brain_tick
from covswarm.deploy.launcher import host_brain_tick
from covswarm.deploy.plan import BRAIN_TICK, RunConfig, auto_per_process


def test_a_measured_brain_tick_is_the_calibration_packs_scaled_to_live() -> None:
    measured = measure_brain_tick(brains=20, warm=3, rounds=2)
    assert 1e-6 < measured.bench < 0.1  # s per brain-tick: a real, finite figure
    assert measured.brain_tick == pytest.approx(LIVE_PER_BENCH * measured.bench)
    assert measured.took > 0.0
    line = measured.describe()
    assert f"~{1e3 * measured.brain_tick:.3g} ms" in line and "--brain-tick" in line


def _console() -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, width=200), out


def test_the_launcher_measures_only_a_team_beyond_a_process_per_brain() -> None:
    console, out = _console()
    # a process per brain
    assert host_brain_tick(RunConfig(), 16, 2, console) == (BRAIN_TICK, "reference")
    assert out.getvalue() == ""
    assert host_brain_tick(RunConfig(brain_tick=2e-3), 1000, 2, console) == (2e-3, "given")
    assert out.getvalue() == ""
    measured, source = host_brain_tick(RunConfig(), 17, 2, console)
    assert measured > 0.0 and source == "measured" and "this host: ~" in out.getvalue()


def test_a_slower_host_packs_as_its_brain_tick_says() -> None:
    """The same team on a host twice as slow: fewer brains per process where the team
    fits, one process per core where it does not."""
    assert auto_per_process(700, 8, 10.0, 2 * BRAIN_TICK) == 75 < auto_per_process(700, 8, 10.0)
    assert auto_per_process(300, 2, 10.0, 4 * BRAIN_TICK) == 150
