"""Planned scenarios: ``[domain] kind = "route"`` files, the warehouse and the lab map.

Every S is checked with shapely at dense instants against the obstacles as the world holds
them (boxes, a map's pieces): never overlapping, inside the workspace, never smaller than
the team's least S.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner

from covswarm.deploy.cli import main
from covswarm.mission.crowding import least_domain
from covswarm.mission.scenario_files import load_scenario, scenario_from_dict
from covswarm.mission.scenarios import route_lines

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"


def assert_clear(scenario, samples: int = 2000) -> float:
    """shapely at ``samples`` instants over the route: S clear of every obstacle and inside
    the workspace, at least the team's least area. Returns the smallest scale of S's area."""
    obstacles = shapely.union_all([shapely.Polygon(o.vertices) for o in scenario.world.obstacles])
    xmin, xmax, ymin, ymax = scenario.workspace
    least, _ = least_domain(scenario.agents, scenario.robot_diameter)
    start_area = shapely.Polygon(scenario.domain(0.0)[0]).area
    smallest = 1.0
    for t in np.linspace(0.0, max(scenario.duration, scenario.motion.end), samples):
        vertices, _ = scenario.domain(t)
        s = shapely.Polygon(vertices)
        assert s.is_valid and s.distance(obstacles) > 0.0, f"S touches an obstacle at t = {t}"
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        assert low[0] >= xmin and high[0] <= xmax and low[1] >= ymin and high[1] <= ymax
        assert s.area >= least - 1e-9
        smallest = min(smallest, s.area / start_area)
    return smallest


def test_through_the_wall_as_a_route_goes_round_the_wall() -> None:
    scenario = load_scenario(DATA / "through_the_wall_route.toml")
    assert scenario.goals == ((1.8, 0.0),)
    assert_clear(scenario)
    final = scenario.domain(scenario.motion.end)[0]
    np.testing.assert_allclose(shapely.Polygon(final).centroid.coords[0], (1.8, 0.0), atol=1e-9)
    # The keyframed original goes straight through the wall and is refused at load.
    with pytest.raises(ValueError, match="obstacle 1"):
        load_scenario(DATA / "through_the_wall.toml")


def test_a_route_scenario_round_trips_through_toml() -> None:
    scenario = load_scenario(DATA / "through_the_wall_route.toml")
    again = scenario_from_dict(tomllib.loads(scenario.to_toml()))
    assert again.goals == scenario.goals
    for t in np.linspace(0.0, scenario.duration, 50):
        np.testing.assert_allclose(again.domain(t)[0], scenario.domain(t)[0], atol=1e-12)


def _route_file(**domain) -> dict:
    table = {
        "kind": "route",
        "polygon": [[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]],
        "goals": [[1.8, 0.0]],
    }
    table.update(domain)
    return {
        "name": "r",
        "workspace": [-2.591, 2.591, -1.829, 1.829],
        "obstacles": [[-0.3, 0.3, -1.829, 0.6], [-0.3, 0.3, 0.75, 1.829]],
        "domain": {k: v for k, v in table.items() if v is not None},
    }


@pytest.mark.parametrize(
    ("domain", "message"),
    [
        ({"goals": None}, "missing"),
        ({"goals": []}, "goals"),
        ({"speed": -1.0}, "speed"),
        ({"hold": "long"}, "hold"),
        ({"turn": 1.0}, "unknown"),
        ({"goals": [[1.8]]}, "goals"),
        ({"goals": [[9.0, 0.0]]}, "outside-workspace"),
        ({}, "too-narrow"),  # a 0.15 m door: narrower than any S of 10 robots
    ],
)
def test_bad_routes_are_refused_with_the_reason(domain: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        scenario_from_dict(_route_file(**domain))


def test_warehouse_needs_the_planner_and_clears_every_shelf() -> None:
    scenario = load_scenario("warehouse")
    assert scenario.agents == 20 and scenario.dynamics == "unicycle"
    door = 0.9 - (-0.2)
    height = np.ptp(scenario.domain(0.0)[0][:, 1])
    assert height > door, "S must not fit the door as it is"
    smallest = assert_clear(scenario)
    assert smallest < (door / height) ** 2  # it shrank to pass
    end = scenario.domain(scenario.duration)[0]
    np.testing.assert_allclose(shapely.Polygon(end).centroid.coords[0], scenario.goals[0])
    assert shapely.Polygon(end).area == pytest.approx(2.4 * 1.6)


def test_lab_map_route_clears_the_map() -> None:
    scenario = load_scenario(ROOT / "scenarios" / "lab-route.toml")
    assert len(scenario.world.obstacles) < 40  # merged pieces, not one box per pixel
    assert scenario.motion.end <= scenario.duration
    assert_clear(scenario)
    # Two goals, S rests hold = 5 s at each with its start shape and size, centred there.
    motion = scenario.motion
    assert [h for h in motion.holds if h > 0.0] == [5.0, 5.0]
    start_area = shapely.Polygon(motion.polygons[0]).area
    for goal, hold in zip(scenario.goals, [h for h in motion.holds if h > 0], strict=True):
        k = [i for i, p in enumerate(motion.polygons) if np.allclose(p.mean(axis=0), goal)][0]
        arrive = motion.arrivals[k - 1]
        for t in (arrive, arrive + hold / 2, arrive + hold):
            vertices, velocities = motion(t)
            assert np.abs(velocities).max() < 1e-9
            assert shapely.Polygon(vertices).area == pytest.approx(start_area)


def test_sim_runs_the_warehouse(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["sim", "--scenario", "warehouse", "--out", str(out)]
    result = CliRunner().invoke(main, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["domain_obstacle_overlap"] == 0.0
    assert summary["obstacle_contacts"] == 0
    # The README's figures (0.110 m and 0.15 mm measured), held to what it says of them.
    assert summary["min_obstacle_clearance"] >= 0.1 and summary["final_error"] < 1e-3
    assert summary["goals_reached"] == summary["goals"] == 1


def _planned_legs(scenario, polygon, goals, speed: float, hold: float) -> list[str]:
    """The route lines sim and run print, from plan_route called here leg by leg on the
    scenario's world (not from the scenario's own plan): stops, length, arrival, and the
    mission the whole route needs (its end to the second, up, plus 10 s) on the last."""
    from covswarm.world.planner import plan_route

    least_area, least_width = least_domain(scenario.agents, scenario.robot_diameter)
    lines, current, t = [], np.array(polygon, dtype=float), 0.0
    for x, y in goals:
        route = plan_route(
            scenario.world, current, (x, y), min_area=least_area, min_width=least_width,
            max_speed=speed, t0=t, hold=hold,
        )  # fmt: skip
        arrival = route.motion.end - hold
        lines.append(
            f"route to goal ({x!r}, {y!r}): {len(route.waypoints)} waypoints, "
            f"{route.length:.1f} m, arrives at {arrival:.1f} s"
        )
        current, t = route.motion.polygons[-1], route.motion.end
    lines[-1] += f" (mission {math.ceil(t) + 10:g} s)"
    return lines


def test_the_route_lines_are_each_goals_plan() -> None:
    """Two goals (the lab's map, 5 s held at each): one line per goal, the mission on the
    last; the figures are the planner's for each leg."""
    scenario = load_scenario(ROOT / "scenarios" / "lab-route.toml")
    domain = tomllib.loads((ROOT / "scenarios" / "lab-route.toml").read_text())["domain"]
    expect = _planned_legs(
        scenario, domain["polygon"], [tuple(g) for g in domain["goals"]], domain["speed"],
        domain["hold"],
    )  # fmt: skip
    assert route_lines(scenario.motion) == expect
    assert len(expect) == 2 and "mission" not in expect[0] and "(mission 1" in expect[1]
    leg = scenario.motion.legs[0]  # arrival and end: the hold apart, the end the next start
    assert leg.end - leg.arrival == pytest.approx(5.0)
    assert scenario.motion.legs[1].end == pytest.approx(scenario.motion.end)
    assert route_lines(load_scenario("circle").motion) == []  # nothing planned, nothing said
    page = (ROOT / "docs" / "world.md").read_text(encoding="utf-8")  # its quoted example
    block = page.split("`scenarios/lab-route.toml`:\n\n```text\n", 1)[1].split("```", 1)[0]
    assert block.splitlines() == expect


def test_sim_gets_through_the_wall_mission_by_route(tmp_path: Path) -> None:
    """Issue 20's check: the mission refused at load as keyframes gets through as a route,
    the whole mission simulated: no contact, S never over the wall, the goal reached. sim
    says the planned route before simulating it."""
    out = tmp_path / "run"
    path = DATA / "through_the_wall_route.toml"
    args = ["sim", "--scenario", str(path), "--out", str(out)]
    result = CliRunner().invoke(main, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    domain = tomllib.loads(path.read_text())["domain"]
    (line,) = _planned_legs(
        load_scenario(path), domain["polygon"], [(1.8, 0.0)], domain["speed"], domain["hold"]
    )
    assert line.startswith("route to goal (1.8, 0.0): ") and line.endswith("(mission 59 s)")
    assert result.output.startswith(line + "\n")  # before the simulation's progress
    summary = json.loads((out / "summary.json").read_text())
    assert summary["obstacle_contacts"] == 0 and summary["domain_obstacle_overlap"] == 0.0
    assert summary["goals"] == 1 and summary["goals_reached"] == 1
    assert summary["final_error"] < 0.02
