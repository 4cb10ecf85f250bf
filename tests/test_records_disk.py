"""A full disk stops the records, never the run (issue 21, item 5): the recorder checks the
free space and stops writing files with a warning and a count, closes run.mcap properly
(readable, with its summary) and never raises into the coordinator's loop."""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from covswarm.records import recorder as recorder_module
from covswarm.records.recorder import MIN_FREE_BYTES, RunRecorder
from covswarm.records.trajectories import read_trajectories

IDS = list(range(20))


def feed(recorder: RunRecorder, steps: int, rng: np.random.Generator, t0: float = 0.0) -> None:
    """What the coordinator writes per tick at 20 Hz: poses, S, e_a."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    for k in range(steps):
        t = t0 + 0.05 * k
        recorder.poses(t, IDS, rng.random((len(IDS), 3)))
        recorder.domain(t, square)
        recorder.error(t, 0.1, len(IDS))


def read_mcap(path: Path) -> tuple[int, float]:
    """(messages, last log time in s) of a run.mcap, through its summary section: a file
    that was not closed properly has none and fails here."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no summary: not closed"
        times = [m.log_time for _, _, m in reader.iter_messages()]
    assert len(times) == summary.statistics.message_count
    return len(times), max(times) / 1e9


def test_low_free_space_stops_the_files_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    free = {"bytes": 10 * MIN_FREE_BYTES}
    recorder = RunRecorder(tmp_path, run_metadata={}, free_space=lambda _: free["bytes"])
    rng = np.random.default_rng(0)
    with caplog.at_level(logging.WARNING, logger="covswarm.records"):
        feed(recorder, 100, rng)  # 5 s
        free["bytes"] = MIN_FREE_BYTES - 1  # the disk fills
        feed(recorder, 100, rng, t0=5.0)
        recorder.trajectory_rows(np.array([9.0]), [0], np.zeros((1, 3)))  # after: ignored
        recorder.note("recording", {"cost": 1})
        recorder.close()
    assert recorder.disk["stopped"].startswith(f"{MIN_FREE_BYTES - 1} bytes left")
    assert 5.0 <= recorder.disk["t"] <= 5.0 + recorder_module.SPACE_CHECK_PERIOD + 1e-9
    assert recorder.disk["writes_lost"] >= 3 * 100 - 3 * 3
    assert sum("recording stopped" in r.getMessage() for r in caplog.records) == 1
    messages, last = read_mcap(tmp_path / "run.mcap")
    assert last <= recorder.disk["t"] and messages >= 3 * 100
    rows = read_trajectories(tmp_path / "trajectories.csv")
    assert rows[:, 0].max() <= recorder.disk["t"] and len(rows) >= 100 * len(IDS)


def test_no_room_at_the_start_writes_nothing_and_raises_nothing(tmp_path: Path) -> None:
    recorder = RunRecorder(tmp_path, run_metadata={}, free_space=lambda _: 1000)
    feed(recorder, 10, np.random.default_rng(1))
    recorder.close()
    assert "1000 bytes free" in recorder.disk["stopped"] and recorder.disk["t"] is None
    assert recorder.disk["writes_lost"] == 30
    assert not (tmp_path / "run.mcap").exists()


class FullFile:
    """A text file whose writes fail as on a full disk."""

    def write(self, text: str) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_enospc_while_writing_stops_the_records_and_keeps_run_mcap(tmp_path: Path) -> None:
    recorder = RunRecorder(tmp_path, run_metadata={})
    rng = np.random.default_rng(2)
    feed(recorder, 40, rng)
    recorder._trajectories._file = FullFile()  # another process filled the disk
    feed(recorder, 40, rng, t0=2.0)  # raises nothing
    recorder.close()
    assert "No space left on device" in recorder.disk["stopped"]
    assert recorder.disk["t"] == pytest.approx(2.0)
    assert "trajectories" in recorder.disk["close_errors"][0]
    messages, last = read_mcap(tmp_path / "run.mcap")
    assert last == pytest.approx(2.0) and messages == 3 * 40 + 1


def test_a_live_view_goes_on_after_the_files_stop(tmp_path: Path) -> None:
    free = {"bytes": 10 * MIN_FREE_BYTES}
    recorder = RunRecorder(
        tmp_path, run_metadata={}, live_port=0, free_space=lambda _: free["bytes"]
    )
    try:
        free["bytes"] = 0
        feed(recorder, 5, np.random.default_rng(3))
        assert recorder.disk["stopped"] is not None and recorder.recording
    finally:
        recorder.close()
    assert not recorder.recording


def test_a_real_full_tmpfs(require) -> None:
    require(os.geteuid() == 0 and shutil.which("mount") is not None, "mounting a tmpfs needs root")
    mount = Path(tempfile.mkdtemp(prefix="covswarm-full-"))
    size = 2 * MIN_FREE_BYTES + 256 * 1024
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)], check=True)
    try:
        out = mount / "run"
        recorder = RunRecorder(out, run_metadata={"scenario": "full-disk"})
        rng = np.random.default_rng(4)
        t = 0.0
        while recorder.disk["stopped"] is None and t < 600.0:
            feed(recorder, 20, rng, t0=t)
            t += 1.0
        feed(recorder, 100, rng, t0=t)  # the mission goes on
        recorder.close()
        assert recorder.disk["stopped"] is not None, "the tmpfs never filled"
        assert "close_errors" not in recorder.disk
        messages, last = read_mcap(out / "run.mcap")
        assert messages > 0 and last <= recorder.disk["t"]
        read_trajectories(out / "trajectories.csv")
        # Room is left for the coordinator's summary.json.
        (out / "summary.json").write_text(json.dumps({"e_a": list(range(10_000))}))
    finally:
        subprocess.run(["umount", str(mount)], check=True)
        mount.rmdir()
