"""The in-process simulator and ``covswarm sim``: determinism, convergence, outputs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from covswarm.deploy.cli import main
from covswarm.deploy.simulate import simulate
from covswarm.mission.report import neighbor_histogram, steady_state_mean, write_outputs
from covswarm.mission.scenario_files import load_scenario

OUTPUTS = ("summary.json", "error.csv", "error.png", "trajectories.png")

SMALL_TOML = """
name = "small"
agents = 6
kappa = 3.0
duration = 2.0
dt = 0.05

[domain]
kind = "rigid"
polygon = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
radius = 0.3
period = 20.0
"""


@pytest.fixture
def small(tmp_path: Path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL_TOML)
    return path


def run_cli(*args: str) -> str:
    result = CliRunner().invoke(main, ["sim", *args], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.output


def test_same_seed_gives_byte_identical_files(small: Path, tmp_path: Path) -> None:
    for name in ("a", "b"):
        run_cli("--scenario", str(small), "--seed", "3", "--out", str(tmp_path / name))
    for name in ("summary.json", "error.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    run_cli("--scenario", str(small), "--seed", "4", "--out", str(tmp_path / "c"))
    assert (tmp_path / "a" / "error.csv").read_bytes() != (
        tmp_path / "c" / "error.csv"
    ).read_bytes()


@pytest.mark.parametrize("law", ["c", "d1"])
@pytest.mark.parametrize("dynamics", ["single", "unicycle"])
def test_error_decreases_for_a_small_team(small: Path, law: str, dynamics: str) -> None:
    scenario = load_scenario(small)
    result = simulate(scenario, law=law, dynamics=dynamics, duration=3.0, seed=1)
    assert result.t.shape == result.error.shape == (61,)
    assert result.trajectories.shape == (61, 6, 2) and len(result.polygons) == 61
    assert result.error[-1] < 0.35 * result.error[0]
    np.testing.assert_array_equal(result.trajectories[-1], result.positions)


def test_unicycle_headings_move_and_single_keeps_zero(small: Path) -> None:
    scenario = load_scenario(small)
    unicycle = simulate(scenario, dynamics="unicycle", duration=1.0)
    single = simulate(scenario, dynamics="single", duration=1.0)
    assert np.any(unicycle.headings[-1] != unicycle.headings[0])
    np.testing.assert_array_equal(single.headings, 0.0)
    np.testing.assert_array_equal(unicycle.trajectories[0], single.trajectories[0])


def test_bad_options_are_rejected(small: Path) -> None:
    scenario = load_scenario(small)
    with pytest.raises(ValueError, match="law"):
        simulate(scenario, law="d2")
    with pytest.raises(ValueError, match="dynamics"):
        simulate(scenario, dynamics="car")
    result = CliRunner().invoke(main, ["sim", "--scenario", "nope.toml"])
    assert result.exit_code != 0 and "cannot read" in result.output
    result = CliRunner().invoke(main, ["sim", "--compare", "--no-feedforward"])
    assert result.exit_code != 0
    with pytest.raises(ValueError, match="a step of 5 s is longer than the mission"):
        simulate(scenario, dt=5.0, duration=2.0)
    refused = {
        ("--kappa", "1e9"): "'--kappa': 1000000000.0 is not in the range 0.0<x<=1000.0",
        ("--dt", "5", "--duration", "2"): "--dt: a step of 5 s is longer than the mission (2 s)",
        ("--law", "da", "--damping", "0.5"): "--damping: only with --law c (TVD-C)",
        ("--law", "d1", "--prior", "zero"): "--prior: only with --law c (TVD-C)",
        ("--dynamics", "single", "--heading", "0.5"): "--heading: only with unicycles",
        ("--dynamics", "single", "--projection-distance", "0.05"): (
            "--projection-distance: only with unicycles"
        ),
        ("--deploy-timeout", "5"): "--deploy-timeout: only with --deploy-error",
    }
    for args, reason in refused.items():
        result = CliRunner().invoke(main, ["sim", "--scenario", str(small), *args])
        assert result.exit_code == 2 and reason in " ".join(result.output.split()), result.output


def test_cli_without_a_terminal_prints_plain_progress(small: Path, tmp_path: Path) -> None:
    output = run_cli("--scenario", str(small), "--out", str(tmp_path / "run"))
    # CliRunner's output is no terminal: the bar would show nothing until the end
    assert "small tvd_da with dc/dt: step 1 of 40" in " ".join(output.split())


def test_cli_compare_writes_both_curves(small: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    output = run_cli("--scenario", str(small), "--compare", "--law", "d1", "--out", str(out))
    assert "better with it" in output
    for name in OUTPUTS:
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "scenario", "agents", "law", "feedforward", "kappa", "dt", "duration", "seed",
        "dynamics", "steady_state_error_mean", "final_error", "neighbor_histogram",
        "steady_state_error_mean_without_feedforward", "improvement",
    ):  # fmt: skip
        assert key in summary, key
    assert summary["scenario"] == "small" and summary["agents"] == 6
    assert summary["feedforward"] is True and summary["law"] == "d1"
    with_ff = summary["steady_state_error_mean"]
    without = summary["steady_state_error_mean_without_feedforward"]
    assert summary["improvement"] == pytest.approx((without - with_ff) / without)
    assert sum(summary["neighbor_histogram"].values()) == 6
    with (out / "error.csv").open() as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["t", "e_a", "e_a_without_feedforward"]
    assert len(rows) == 2.0 / 0.05 + 2
    table = np.array(rows[1:], dtype=float)
    assert steady_state_mean(table[:, 0], table[:, 1]) == pytest.approx(with_ff)
    assert steady_state_mean(table[:, 0], table[:, 2]) == pytest.approx(without)


def test_cli_options_override_scenario_defaults(small: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run_cli(
        "--scenario", str(small), "--agents", "4", "--no-feedforward", "--kappa", "1.5",
        "--dt", "0.1", "--duration", "1", "--seed", "7", "--dynamics", "unicycle",
        "--law", "c", "--out", str(out),
    )  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    expected = {
        "agents": 4, "feedforward": False, "kappa": 1.5, "dt": 0.1, "duration": 1.0,
        "seed": 7, "dynamics": "unicycle", "law": "c", "steps": 10,
    }  # fmt: skip
    assert {key: summary[key] for key in expected} == expected
    assert "improvement" not in summary
    header = (out / "error.csv").read_text().splitlines()[0]
    assert header == "t,e_a"


def test_cli_via_installed_entry_point(tmp_path: Path) -> None:
    import subprocess
    import sys

    out = tmp_path / "run"
    script = Path(sys.executable).parent / "covswarm"
    if not script.exists():
        pytest.skip("covswarm console script not installed next to the interpreter")
    subprocess.run(
        [str(script), "sim", "--scenario", "passage", "--agents", "3", "--duration", "0.4",
         "--out", str(out)],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    assert all((out / name).exists() for name in OUTPUTS)


def test_write_outputs_handles_unknown_positions(tmp_path: Path) -> None:
    """The coordinator passes NaN for robots it has not heard from."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trajectories = np.full((3, 3, 2), np.nan)
    trajectories[:, 0] = [0.2, 0.2]
    trajectories[:2, 1] = [0.8, 0.7]
    write_outputs(
        tmp_path,
        summary={"scenario": "x"},
        t=np.array([0.0, 1.0, 2.0]),
        error=np.array([0.3, np.nan, 0.1]),
        trajectories=trajectories,
        polygons=[square] * 3,
        obstacles=[np.array([[0.4, 0.4], [0.6, 0.4], [0.6, 0.6], [0.4, 0.6]])],
        workspace=(-1.0, 2.0, -1.0, 2.0),
    )
    assert all((tmp_path / name).exists() for name in OUTPUTS)
    assert json.loads((tmp_path / "summary.json").read_text()) == {"scenario": "x"}


def test_neighbor_histogram_counts_robots() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    grid = np.array([[x, y] for x in (0.25, 0.75) for y in (0.25, 0.75)])
    histogram = neighbor_histogram(grid + [[0.01, 0.0], [0, 0], [0, 0], [0, 0.02]], square)
    assert sum(histogram.values()) == 4
    assert list(histogram) == sorted(histogram)


SQUEEZE = Path(__file__).parent / "data" / "squeeze.toml"


def test_safety_keeps_squeezed_robots_apart_in_the_simulator(tmp_path: Path) -> None:
    """As in covswarm run (tests/test_real_robots_e2e.py): S shrinks to a point, the two
    robots' bodies overlap without the filter and stay a diameter apart with --safety."""
    for flag, name in (((), "unsafe"), (("--safety", "--projection-distance", "0.05"), "safe")):
        run_cli("--scenario", str(SQUEEZE), "--seed", "1", "--out", str(tmp_path / name), *flag)
    unsafe = json.loads((tmp_path / "unsafe" / "summary.json").read_text())
    safe = json.loads((tmp_path / "safe" / "summary.json").read_text())
    assert unsafe["safety"] == {
        "on": False,
        "active_robot_steps": 0,
        "relaxed_robot_steps": 0,
        "slid_robot_steps": 0,
    }
    assert unsafe["min_pairwise_distance"] < 0.14 and unsafe["close_approaches"] >= 1
    assert safe["safety"]["on"] and safe["safety"]["active_robot_steps"] > 0
    assert safe["min_pairwise_distance"] >= 0.14 and safe["close_approaches"] == 0
    assert safe["safety"]["relaxed_robot_steps"] == 0
    assert (unsafe["projection_distance"], safe["projection_distance"]) == (0.03, 0.05)


def test_safety_holds_a_crowded_team_apart_at_a_cost_in_coverage() -> None:
    """docs/real-robots.md, "Safety filter": the formation with 40 robots is crowded under its bump;
    without the filter bodies overlap (closest 0.095 m), with it the closest pair stays
    above a diameter and e_a pays for it (0.016 m -> 0.044 m). On the passage the filter
    never acts (robots at least 0.187 m apart): the run is the unfiltered one exactly."""
    formation = load_scenario("formation")
    plain = simulate(formation, agents=40)
    safe = simulate(formation, agents=40, safety=True)
    for result, closest in ((plain, lambda d: d < 0.14), (safe, lambda d: d >= 0.14)):
        gaps = np.linalg.norm(
            result.trajectories[:, :, None] - result.trajectories[:, None], axis=3
        ) + 9.0 * np.eye(40)
        assert closest(gaps.min()), gaps.min()
    assert safe.safety_active > 0 and safe.safety_relaxed == 0
    assert steady_state_mean(safe.t, safe.error) > 2.0 * steady_state_mean(plain.t, plain.error)
    passage = load_scenario("passage")
    plain, safe = simulate(passage, duration=10.0), simulate(passage, duration=10.0, safety=True)
    assert safe.safety_active == 0
    np.testing.assert_array_equal(safe.trajectories, plain.trajectories)


def test_unicycles_at_a_long_step_drive_rather_than_spin() -> None:
    """A step's command is held for the step, and the turn rate capped for it as the agents
    cap theirs (covswarm.tvd.drive.steer's hold): uncapped, 30 robots of the circle at 0.6 s
    steps spun in place and fell behind S (second-half e_a 5.5 m; capped 0.70-0.76 m over
    seeds 0-4, 28 Nov 2026)."""
    from covswarm.mission.scenarios import circle

    result = simulate(
        circle(), agents=30, dt=0.6, duration=30.0, dynamics="unicycle",
        projection_distance=0.05, seed=2,
    )  # fmt: skip
    assert steady_state_mean(result.t, result.error) < 1.5
