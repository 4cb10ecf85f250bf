"""scripts/missed_deadlines.py on a recording written here: when the misses happened."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from mcap.writer import Writer

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "missed_deadlines.py"


def write_run(folder: Path, fractions: list[float]) -> None:
    """A run.mcap with e_a from t = 0 and agents' stats at 1, 2, ... s with these mean
    missed fractions (two agents around each mean)."""
    folder.mkdir()
    with (folder / "run.mcap").open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("any", "jsonschema", b"{}")
        error = writer.register_channel("/error", "json", schema)
        stats = writer.register_channel("/agents/stats", "json", schema)
        start = 5_000_000_000
        writer.add_message(error, start, b'{"e_a": 1.0, "robots": 2}', start)
        for second, fraction in enumerate(fractions, start=1):
            agents = [{"missed_deadline": fraction * 0.5}, {"missed_deadline": fraction * 1.5}]
            data = json.dumps({"agents": agents}).encode()
            when = start + second * 1_000_000_000
            writer.add_message(stats, when, data, when)
        writer.finish()


def test_misses_of_the_first_seconds_are_told_from_later_ones(tmp_path: Path) -> None:
    # 2 periods missed per agent in the first 2 s at 10 Hz, none after, then 1 more at 8 s.
    fractions = [2 / 10, 2 / 20, 2 / 30, 2 / 40, 2 / 50, 2 / 60, 2 / 70, 3 / 80]
    write_run(tmp_path / "run", fractions)
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "run"), "--start", "5"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    result = json.loads(done.stdout)
    assert [t for t, _ in result["missed_per_agent"]] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    assert result["by_5_s"] == 2.0 and result["by_end"] == 3.0 and result["after_5_s"] == 1.0


def test_a_recording_without_a_mission_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "empty"
    folder.mkdir()
    with (folder / "run.mcap").open("wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.finish()
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(folder)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode != 0 and "no /error sample" in done.stderr


def test_a_folder_without_a_recording_is_refused_in_one_line(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "nothing")], capture_output=True, text=True
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "no run.mcap there (a covswarm run's output folder)" in done.stderr
