"""``covswarm sim`` and ``covswarm run`` accept and refuse the same scenarios (issue 21):
what the agents could not decode is refused by both, before anything starts."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from click.testing import CliRunner

from covswarm.coordinator.broadcastable import check_broadcastable
from covswarm.deploy.cli import main
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import BUILTINS


def polygon(k: int) -> str:
    points = [(math.cos(2 * math.pi * i / k), math.sin(2 * math.pi * i / k)) for i in range(k)]
    return "[" + ", ".join(f"[{x:.6f}, {y:.6f}]" for x, y in points) + "]"


def scenario_file(tmp_path: Path, vertices: int, kappa: float) -> Path:
    path = tmp_path / f"s{vertices}-{kappa:g}.toml"
    path.write_text(
        f'name = "probe"\nagents = 4\nkappa = {kappa}\nduration = 2.0\n'
        f'workspace = [-3.0, 3.0, -3.0, 3.0]\n\n[domain]\nkind = "rigid"\n'
        f"polygon = {polygon(vertices)}\nradius = 0.0\nperiod = 50.0\n",
        encoding="utf-8",
    )
    return path


def refused_by_sim_and_run(tmp_path: Path, path: Path, why: str) -> None:
    """covswarm sim and run both refuse the scenario at ``path`` as a bad option, saying
    ``why``, before anything starts."""
    runner = CliRunner()
    for command in (
        ["sim", "--out", str(tmp_path / "sim")],
        ["run", "--out", str(tmp_path / "run")],
    ):
        result = runner.invoke(main, [*command, "--scenario", str(path)])
        assert result.exit_code == 2, (command, result.output)
        assert why in result.output and "Traceback" not in result.output
    assert not (tmp_path / "run" / "logs").exists()  # nothing started
    assert not (tmp_path / "sim").exists()


# e2e: were the check to let the scenario through, `covswarm run` would start its router.
@pytest.mark.e2e
@pytest.mark.parametrize(
    ("vertices", "kappa", "why"), [(100, 2.0, "vertices"), (8, 2000.0, "kappa")]
)
def test_sim_and_run_refuse_what_the_agents_could_not_decode(
    tmp_path: Path, vertices: int, kappa: float, why: str
) -> None:
    path = scenario_file(tmp_path, vertices, kappa)
    with pytest.raises(ValueError, match="does not fit a Domain message") as refused:
        scenario = load_scenario(str(path))
        check_broadcastable(scenario, scenario.kappa, scenario.duration)
    assert why in str(refused.value) and "covswarm run could not send it" in str(refused.value)
    refused_by_sim_and_run(tmp_path, path, why)


def test_a_density_past_the_wire_limits_is_named_and_its_turning_explained(tmp_path: Path):
    """A turn_rate so fast that the covariance's rate on the wire exceeds its bound: the
    refusal names the density (not the domain) and says where that rate comes from."""
    path = scenario_file(tmp_path, 4, 1.0)
    path.write_text(
        path.read_text() + "[density]\nfloor = 1.0\n[[density.bumps]]\nmean = [0.0, 0.5]\n"
        "cov = [[0.09, 0.0], [0.0, 0.01]]\nweight = 8.0\nturn_rate = 1e300\n",
        encoding="utf-8",
    )
    scenario = load_scenario(str(path))
    with pytest.raises(ValueError, match="its density at t = 0 s does not fit a Domain") as refused:
        check_broadcastable(scenario, scenario.kappa, scenario.duration)
    assert str(refused.value).endswith("(a bump's cov_rate includes its turn_rate's turning)")


def test_s_is_checked_over_the_runs_duration_not_only_the_scenarios(tmp_path: Path) -> None:
    """A scenario of 2 s whose S shrinks to nothing at 20 s: fine as it is, refused for a
    run of 30 s (covswarm run broadcast S shrinking through a point and back out)."""
    path = scenario_file(tmp_path, 4, 1.0)
    path.write_text(path.read_text() + "scale_rate = -0.05\n", encoding="utf-8")
    scenario = load_scenario(str(path))
    check_broadcastable(scenario, scenario.kappa, 10.0)
    with pytest.raises(ValueError, match="reaches 0 at t = 20 s, within the 30 s mission"):
        check_broadcastable(scenario, scenario.kappa, 30.0)


def test_a_scenario_within_the_wire_limits_is_accepted(tmp_path: Path) -> None:
    scenario = load_scenario(str(scenario_file(tmp_path, 64, 1000.0)))
    check_broadcastable(scenario, scenario.kappa, scenario.duration)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_every_builtin_is_broadcastable(name: str) -> None:
    scenario = load_scenario(name)
    check_broadcastable(scenario, scenario.kappa, scenario.duration)


def map_scenario(tmp_path: Path, name: str, resolution: float, speckle: bool) -> Path:
    """A 200 x 200 px map: free, or with a corner of isolated occupied pixels (a
    checkerboard: one obstacle each, 5000 of them), S a square at its middle."""
    import numpy as np
    from PIL import Image

    grey = np.full((200, 200), 254, dtype=np.uint8)
    if speckle:
        corner = grey[:100, :100]
        corner[::2, ::2] = 0
        corner[1::2, 1::2] = 0
    else:
        grey[0, 0] = 0  # one obstacle, at the map's far corner
    Image.fromarray(grey, mode="L").save(tmp_path / f"{name}.pgm")
    half = 100 * resolution
    (tmp_path / f"{name}.yaml").write_text(
        f"image: {name}.pgm\nresolution: {resolution}\norigin: [{-half}, {-half}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        encoding="utf-8",
    )
    path = tmp_path / f"{name}.toml"
    path.write_text(
        f'name = "{name}"\nagents = 4\nduration = 2.0\nmap = "{name}.yaml"\n\n[domain]\n'
        'kind = "rigid"\npolygon = [[0.5, -0.5], [1.5, -0.5], [1.5, 0.5], [0.5, 0.5]]\n'
        "radius = 0.0\nperiod = 50.0\n",
        encoding="utf-8",
    )
    return path


@pytest.mark.e2e
@pytest.mark.parametrize(
    ("name", "resolution", "speckle", "why"),
    [
        # refused by the map reader, before any of its 5000 pieces is built
        ("speckle", 0.05, True, "5000 occupied rectangles, at most 4096 fit a World message"),
        ("huge", 5000.0, False, "outside [-10000.0"),
    ],
)
def test_sim_and_run_refuse_a_map_the_agents_could_not_decode(
    tmp_path: Path, name: str, resolution: float, speckle: bool, why: str
) -> None:
    path = map_scenario(tmp_path, name, resolution, speckle)
    with pytest.raises(ValueError, match="World message") as refused:
        scenario = load_scenario(str(path))
        check_broadcastable(scenario, scenario.kappa, scenario.duration)
    assert why in str(refused.value)
    refused_by_sim_and_run(tmp_path, path, why)


def test_a_map_within_the_wire_limits_is_accepted(tmp_path: Path) -> None:
    scenario = load_scenario(str(map_scenario(tmp_path, "fine", 0.05, False)))
    check_broadcastable(scenario, scenario.kappa, scenario.duration)
