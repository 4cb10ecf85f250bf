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


# e2e: were the check to let the scenario through, `covswarm run` would start its router.
@pytest.mark.e2e
@pytest.mark.parametrize(
    ("vertices", "kappa", "why"), [(100, 2.0, "vertices"), (8, 2000.0, "kappa")]
)
def test_sim_and_run_refuse_what_the_agents_could_not_decode(
    tmp_path: Path, vertices: int, kappa: float, why: str
) -> None:
    path = scenario_file(tmp_path, vertices, kappa)
    with pytest.raises(ValueError, match="cannot be broadcast") as refused:
        scenario = load_scenario(str(path))
        check_broadcastable(scenario, scenario.kappa, scenario.duration)
    assert why in str(refused.value)
    runner = CliRunner()
    for command in (
        ["sim", "--out", str(tmp_path / "sim")],
        ["run", "--out", str(tmp_path / "run")],
    ):
        result = runner.invoke(main, [*command, "--scenario", str(path)])
        assert result.exit_code == 2, (command, result.output)
        assert "cannot be broadcast" in result.output and why in result.output
    assert not (tmp_path / "run" / "logs").exists()  # nothing started
    assert not (tmp_path / "sim").exists()


def test_a_scenario_within_the_wire_limits_is_accepted(tmp_path: Path) -> None:
    scenario = load_scenario(str(scenario_file(tmp_path, 64, 1000.0)))
    check_broadcastable(scenario, scenario.kappa, scenario.duration)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_every_builtin_is_broadcastable(name: str) -> None:
    scenario = load_scenario(name)
    check_broadcastable(scenario, scenario.kappa, scenario.duration)
