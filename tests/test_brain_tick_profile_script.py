"""scripts/brain_tick_profile.py: its pack runs the bench's brain-tick (at the asked rate and
overloaded), and its shares count each sample inside a timed tick once per phase its stack
holds."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from script_modules import SCRIPTS, load_script

SCRIPT = SCRIPTS / "brain_tick_profile.py"


def test_shares_count_the_samples_inside_a_tick_by_phase(tmp_path: Path) -> None:
    raw = tmp_path / "raw.txt"
    raw.write_text(
        "<module> (a.py:1);timed_tick (p.py:7);Pack.tick (pack.py:9);"
        "AgentBrain.receive_all (brain.py:3) 6\n"
        "<module> (a.py:1);timed_tick (p.py:7);Pack.tick (pack.py:9);"
        "Neighborhood.refresh (n.py:4);Neighborhood.refresh (n.py:5) 3\n"
        "<module> (a.py:1);timed_tick (p.py:7);Pack.tick (pack.py:9) 1\n"
        "<module> (a.py:1);make_layout (bench.py:2);Neighborhood.refresh (n.py:4) 50\n"
        # the warm-up's ticks are not timed
        "<module> (a.py:1);run_pack (p.py:5);Pack.tick (pack.py:9);"
        "AgentBrain.receive_all (brain.py:3) 40\n"
    )
    shares = load_script("brain_tick_profile").shares(raw)
    assert shares["AgentBrain.receive_all"] == pytest.approx(60.0)
    assert shares["Neighborhood.refresh"] == pytest.approx(30.0)  # once, not per frame
    assert shares["local_steps"] == 0.0


@pytest.mark.parametrize("late", [1.0, 4.0])
def test_the_inner_run_times_a_small_pack(late: float) -> None:
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--inner", "--brains", "12", "--ticks", "8"]
        + ["--late", str(late)],
        capture_output=True, text=True, check=True, timeout=120,
    )  # fmt: skip
    assert float(out.stdout.split()[0]) > 0.0
