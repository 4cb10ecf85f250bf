"""scripts/density_peer.py refuses a wrong --peer folder and malformed --sizes in one line,
before importing anything of the peer (which is not installed here)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "density_peer.py"


def test_bad_arguments_are_refused_in_one_line(tmp_path: Path) -> None:
    for args, said in (
        (["--peer", str(tmp_path)], "no coveragecontrol_2d.py there"),
        (["--peer", str(tmp_path), "--sizes", "5,x"], "'5,x': expected positive integers"),
    ):
        done = subprocess.run(
            [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120
        )
        assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr
        assert said in done.stderr
