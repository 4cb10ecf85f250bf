"""``covswarm sim`` in an arena: solid walls, the safety filter's wall rows, the arena
metrics in summary.json and domain.csv."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner

from covswarm.deploy.cli import main
from covswarm.deploy.simulate import build_summary, simulate
from covswarm.mission.motion import Keyframes
from covswarm.mission.scenarios import Scenario

WALL = (-0.3, 0.3, -1.0, 1.0)
ARENA = (-2.591, 2.591, -1.829, 1.829)
GOAL_BOX = [[0.8, -0.6], [2.0, -0.6], [2.0, 0.6], [0.8, 0.6]]

WALL_TOML = f"""
name = "behind-the-wall"
agents = 6
kappa = 2.0
duration = 6.0
dt = 0.05
dynamics = "{{dynamics}}"
workspace = {list(ARENA)}
obstacles = [{list(WALL)}]

[initial]
box = [-2.0, -1.0, -0.5, 0.5]

[domain]
kind = "keyframes"
times = [0.0, 6.0]
vertices = [{GOAL_BOX}, {GOAL_BOX}]
"""


def behind_the_wall(dynamics: str = "single", agents: int = 6) -> Scenario:
    """The robots start left of a wall, S waits right of it (S itself clear of the wall):
    the coverage law drives them straight at the wall."""
    return Scenario(
        name="behind-the-wall",
        motion=Keyframes(times=np.array([0.0, 6.0]), vertices=np.array([GOAL_BOX, GOAL_BOX])),
        agents=agents,
        duration=6.0,
        dt=0.05,
        dynamics=dynamics,
        workspace=ARENA,
        obstacles=(WALL,),
        initial_box=(-2.0, -1.0, -0.5, 0.5),
    )


def body_clearance(trajectories: np.ndarray, radius: float) -> np.ndarray:
    """Shapely: every sampled body's distance to the wall (negative: overlapping)."""
    wall = shapely.box(WALL[0], WALL[2], WALL[1], WALL[3])
    points = shapely.points(trajectories.reshape(-1, 2))
    return shapely.distance(wall, points) - radius


@pytest.mark.parametrize("dynamics", ["single", "unicycle"])
def test_robots_stop_at_the_wall_instead_of_passing_through(dynamics: str) -> None:
    scenario = behind_the_wall(dynamics)
    result = simulate(scenario)
    radius = 0.5 * scenario.robot_diameter
    gaps = body_clearance(result.trajectories, radius)
    assert gaps.min() >= -1e-9  # bodies touch the wall at most
    assert gaps.min() <= 1e-9 and result.contact_stops > 0  # and they did reach it
    assert np.all(result.trajectories[..., 0] <= WALL[0])  # nobody got through
    summary = build_summary(
        scenario, result, law="da", feedforward=True, kappa=2.0, dt=0.05, duration=6.0,
        seed=0, dynamics=dynamics,
    )  # fmt: skip
    assert summary["obstacle_contacts"] >= 1
    assert summary["obstacle_contact_list"][0]["what"] == "obstacle 1"
    assert summary["min_obstacle_clearance"] == pytest.approx(gaps.min(), abs=1e-9)
    assert summary["domain_obstacle_overlap"] == 0.0
    assert summary["contact_stops"] == result.contact_stops


def test_the_safety_filter_keeps_them_off_the_wall() -> None:
    # Single integrators at gamma dt = 1: the sampled guarantee is exact, so every body stays
    # the filter's margin (0.02 m) from the wall: no contact, no stop.
    scenario = behind_the_wall()
    result = simulate(scenario, safety=True)
    gaps = body_clearance(result.trajectories, 0.5 * scenario.robot_diameter)
    assert gaps.min() >= 0.02 - 1e-9
    assert gaps.min() < 0.03  # it held them at the wall, not far from it
    assert result.contact_stops == 0 and result.safety_active > 0


def test_sim_writes_arena_metrics_and_domain_csv(tmp_path: Path) -> None:
    toml = tmp_path / "wall.toml"
    toml.write_text(WALL_TOML.format(dynamics="unicycle"))
    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["sim", "--scenario", str(toml), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "obstacle contacts" in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["obstacle_contacts"] >= 1
    assert summary["min_obstacle_clearance"] >= -1e-9
    assert (summary["goals"], summary["goals_reached"], summary["goal_times"]) == (0, 0, [])
    # domain.csv: S's vertices at the instants of trajectories.csv.
    domain = np.loadtxt(out / "domain.csv", delimiter=",", skiprows=1)
    poses = np.loadtxt(out / "trajectories.csv", delimiter=",", skiprows=1)
    assert (out / "domain.csv").read_text().startswith("t,vertex,x,y\n")
    np.testing.assert_array_equal(np.unique(domain[:, 0]), np.unique(poses[:, 0]))
    assert domain[:, 1].tolist() == [0, 1, 2, 3] * len(np.unique(poses[:, 0]))
    np.testing.assert_allclose(domain[:4, 2:], GOAL_BOX)


def test_goals_reach_the_summary() -> None:
    # S waits on (1.4, 0): a goal there is reached at t = 0, one elsewhere never.
    scenario = behind_the_wall()
    result = simulate(scenario, duration=1.0)
    summary = build_summary(
        scenario, result, law="da", feedforward=True, kappa=2.0, dt=0.05, duration=1.0,
        seed=0, dynamics="single", goals=[(1.4, 0.0), (0.0, 1.5)],
    )  # fmt: skip
    assert (summary["goals"], summary["goals_reached"]) == (2, 1)
    assert summary["goal_times"] == [0.0, None]
