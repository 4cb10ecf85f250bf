"""Whether a team fits its domain (covswarm.mission.crowding), against independent references:
shapely for areas, dblquad for the density integral, converged simulations for the cells."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from scipy.integrate import dblquad

from covswarm.deploy.simulate import build_summary, simulate
from covswarm.mission.crowding import crowding, robot_room, smallest_cell_area
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import BUILTINS
from covswarm.tvd.density import Density

ROOT = Path(__file__).resolve().parents[1]


def random_convex(rng: np.random.Generator) -> np.ndarray:
    hull = shapely.MultiPoint(rng.uniform(-2.0, 2.0, (12, 2))).convex_hull
    return np.asarray(shapely.geometry.polygon.orient(hull).exterior.coords)[:-1]


def test_uniform_cells_are_the_area_over_the_team() -> None:
    rng = np.random.default_rng(11)
    for _ in range(5):
        polygon = random_convex(rng)
        area = shapely.Polygon(polygon).area
        assert smallest_cell_area(polygon, 25) == pytest.approx(area / 25, rel=0.01)


def test_density_integral_matches_dblquad() -> None:
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    bump = Density(floor=1.0, means=[[0.3, -0.2]], covariances=[[[0.09, 0.02], [0.02, 0.04]]],
                   weights=[6.0])  # fmt: skip

    def root_phi(y: float, x: float) -> float:
        return float(np.sqrt(bump.phi(np.array([[x, y]]))[0]))

    integral, _ = dblquad(root_phi, -1.0, 1.0, -1.0, 1.0, epsabs=1e-8)
    peak = float(bump.phi(np.array([[0.3, -0.2]]))[0])  # the bump's centre is the maximum
    expected = integral / (10 * math.sqrt(peak))
    assert smallest_cell_area(square, 10, bump) == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize(("name", "agents"), [("formation", 20), ("formation", 40), ("circle", 30)])
def test_estimate_is_within_a_third_of_a_converged_cvt(name: str, agents: int) -> None:
    """Measured: the smallest cell of the converged team is 0.84-0.85 of the estimate."""
    scenario = load_scenario(name)
    result = simulate(scenario, agents=agents, duration=scenario.duration, seed=1)
    polygon = result.polygons[-1]
    domain = shapely.Polygon(polygon)
    cells = shapely.voronoi_polygons(shapely.MultiPoint(result.positions), extend_to=domain)
    smallest = min(cell.intersection(domain).area for cell in cells.geoms)
    estimate = smallest_cell_area(polygon, agents, scenario.density(float(result.t[-1])))
    assert 0.7 < smallest / estimate < 1.3


def test_which_missions_are_crowded() -> None:
    # docs/density.md: the built-in formation with 100 Khepera IV is over-packed; formation-100
    # and the 100-robot circle are not.
    assert crowding(load_scenario("formation"), 100, 40.0).crowded
    assert not crowding(load_scenario("formation"), 20, 40.0).crowded
    formation_100 = load_scenario(ROOT / "scenarios" / "formation-100.toml")
    assert not crowding(formation_100, 100, 40.0).crowded
    assert not crowding(load_scenario("circle"), 100, 30.0).crowded
    assert crowding(load_scenario("circle"), 200, 30.0).crowded
    for name, make in BUILTINS.items():  # every built-in fits its own team
        scenario = make()
        assert not crowding(scenario, scenario.agents, scenario.duration).crowded, name
    # Hexagonal packing at the safe distance: sqrt(3)/2 (d + m)^2.
    assert robot_room(0.14, 0.02) == pytest.approx(0.5 * math.sqrt(3.0) * 0.16**2)


def test_summary_reports_crowding() -> None:
    scenario = load_scenario("formation")
    result = simulate(scenario, agents=100, duration=0.2, seed=0)
    summary = build_summary(scenario, result, law="da", feedforward=True, kappa=2.0, dt=0.02,
                            duration=0.2, seed=0, dynamics="single")  # fmt: skip
    crowd = summary["crowding"]
    assert crowd["crowded"] and crowd["smallest_cell_m2"] < crowd["needed_m2"]
