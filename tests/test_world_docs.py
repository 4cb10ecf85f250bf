"""docs/world.md's quoted output of scripts/warehouse_goto.py is what the script prints."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_goto_lines_quoted_are_the_scripts_output() -> None:
    page = (ROOT / "docs" / "world.md").read_text(encoding="utf-8")
    block = page.split("python scripts/warehouse_goto.py\n", 1)[1].split("```", 1)[0]
    quoted = [line[2:] for line in block.splitlines() if line.startswith("# ")]
    assert len(quoted) == 3, block
    done = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "warehouse_goto.py")],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    printed = [re.sub(r"\s+", " ", line).strip() for line in done.stdout.splitlines()]
    for line in quoted:
        assert re.sub(r"\s+", " ", line).strip() in printed, (line, done.stdout)
