"""``covswarm bench`` refuses what it cannot measure as the command line is read: sizes that
are not positive integers, empty samples, an output folder that is a file, options of
another mode, a pack larger than its team. Nothing is timed before the refusal."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from covswarm.deploy.bench import bench_command

REFUSED = {
    ("--sizes", "abc"): "'--sizes': 'abc': expected positive integers separated by commas",
    ("--sizes", "0"): "'--sizes': '0': expected positive integers",
    ("--sizes", "10,,50"): "'--sizes': '10,,50': expected positive integers",
    ("--sizes", "-5"): "'--sizes': '-5': expected positive integers",
    ("--sizes", ""): "'--sizes': '': expected positive integers",
    ("--seeds", "0"): "'--seeds': 0 is not in the range x>=1",
    ("--sample", "0"): "'--sample': 0 is not in the range x>=1",
    ("--repeats", "-1"): "'--repeats': -1 is not in the range x>=1",
    ("--live", "--live-sizes", "10,x"): "'--live-sizes': '10,x': expected positive integers",
    ("--live-sizes", "10"): "--live-sizes: only with --live",
    ("--live-duration", "5", "--live-per-process", "2"): (
        "--live-duration and --live-per-process: only with --live"
    ),
    ("--brain-tick-team", "50"): "--brain-tick-team: only with --brain-tick",
    ("--brain-tick", "--sizes", "10", "--live"): (
        "--brain-tick times packed processes only: no --sizes, --live"
    ),
    ("--brain-tick", "--brain-tick-sizes", "0"): "'--brain-tick-sizes': '0': expected positive",
    ("--brain-tick", "--brain-tick-sizes", "50", "--brain-tick-team", "20"): (
        "a process of 50 brains in a team of 20: give --brain-tick-team 50 or more"
    ),
}


@pytest.mark.parametrize(("args", "reason"), REFUSED.items())
def test_bad_options_are_refused_with_the_reason(args: tuple[str, ...], reason: str) -> None:
    result = CliRunner().invoke(bench_command, list(args))
    assert result.exit_code == 2, result.output
    assert reason in " ".join(result.output.split())
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_an_output_folder_that_is_a_file_is_refused_first(tmp_path: Path) -> None:
    taken = tmp_path / "taken"
    taken.write_text("")
    result = CliRunner().invoke(bench_command, ["--sizes", "10", "--out", str(taken)])
    assert result.exit_code == 2
    assert "is a file" in result.output
    assert taken.read_text() == ""


def test_a_failed_live_run_fails_the_bench(tmp_path: Path, monkeypatch) -> None:
    """The compute rows are still written; the exit status and the last line say which live
    run failed (run_live stands in for ``covswarm run``, which fails with status 2)."""
    import covswarm.deploy.bench as bench

    def failing(sizes, duration, out, per_process, time_scale, progress):
        for n in sizes:
            progress(n, 2)
        return []

    monkeypatch.setattr(bench, "run_live", failing)
    out = tmp_path / "bench"
    argv = ["--sizes", "5", "--seeds", "1", "--sample", "1", "--repeats", "1", "--live"]
    result = CliRunner().invoke(bench_command, [*argv, "--live-sizes", "3,4", "--out", str(out)])
    assert result.exit_code == 1, result.output
    assert f"live runs failed at N = 3, 4 (their logs in {out})" in " ".join(result.output.split())
    assert (out / "bench.json").exists()
