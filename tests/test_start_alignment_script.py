"""scripts/start_alignment.py: the table docs/scaling.md quotes, one row per seed with e_a
at 5 s, its second-half mean and its end, facing S's start and as placed, and the means."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "start_alignment.py"


def test_the_script_prints_both_starts_per_seed_and_their_means() -> None:
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "--agents", "12", "--duration", "6", "--seeds", "0,2"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    lines = result.stdout.splitlines()
    rows = [line.split("|")[1:-1] for line in lines if line.startswith(("| 0 ", "| 2 "))]
    assert [row[0].strip() for row in rows] == ["0", "2"], result.stdout
    for row in rows:
        for cell in row[1:]:
            at5, half, end = (float(v) for v in cell.split(","))
            assert 0.0 < half < 1.0 and 0.0 < at5 < 1.0 and 0.0 < end < 1.0, row
    means = [line for line in lines if line.startswith("| mean")]
    assert len(means) == 1 and len(means[0].split("|")) == 5, result.stdout
