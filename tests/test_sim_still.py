"""Robots whose brains are dead in ``covswarm sim`` (simulate's ``still``): they stand where
they start, out of every cell and of e_a, and the others' safety filters keep them as still
rows, as the agents keep a stranded robot. A robot the filter stops dead beside one takes
its slide (covswarm.tvd.drive.steer) as an agent's brain does (tests/test_slide.py): the
simulator's path is checked against one AgentBrain's (scripts/slide_escape.py)."""

from __future__ import annotations

import json
import math
from unittest import mock

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree
from script_modules import load_script

from covswarm.deploy.simulate import SimResult, moving_robots, sim_command, simulate
from covswarm.mission.motion import Keyframes
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import Scenario
from covswarm.tvd import drive

escape = load_script("slide_escape")
SECONDS = 6.0


class _Placed(Scenario):
    """A scenario whose robots start at the positions ``at`` (set after construction)."""

    def initial_positions(self, n: int, seed: int) -> np.ndarray:
        at = np.array(self.at, dtype=float)  # type: ignore[attr-defined]
        assert len(at) == n
        return at


def placed(at: list[tuple[float, float]], vertices: list[list[float]], **options) -> Scenario:
    scenario = _Placed(
        name="placed", motion=Keyframes([0.0, SECONDS], [vertices, vertices]), **options
    )
    object.__setattr__(scenario, "at", at)
    return scenario


def beside_a_still_robot(angle: float) -> tuple[SimResult, tuple[float, float]]:
    """scripts/slide_escape.py's layout in the simulator: robot 0 at START facing +x, its
    aim along +x (S far to its right), robot 1 dead 1 mm outside the safe distance,
    ``angle`` rad to the left of that aim."""
    still = (
        escape.START[0] + (escape.SAFE + 1e-3) * math.cos(angle),
        escape.START[1] + (escape.SAFE + 1e-3) * math.sin(angle),
    )
    scenario = placed(
        [escape.START, still], escape.FAR_SQUARE, agents=2, kappa=escape.KAPPA,
        duration=SECONDS, dt=0.1, dynamics="unicycle",
    )  # fmt: skip
    # The agents' projection distance (covswarm.agent.config), as the brain steers.
    result = simulate(scenario, safety=True, heading=0.0, projection_distance=0.05, still=[1])
    return result, still


@pytest.mark.parametrize("degrees", [0, 3, 10, 30, 60, -40])
def test_the_simulator_passes_a_still_robot_as_a_brain_does(degrees: int) -> None:
    result, still = beside_a_still_robot(math.radians(degrees))
    brain, brain_path, _ = escape.drive_past(math.radians(degrees), SECONDS)
    path = result.trajectories[:, 0]
    assert np.array_equal(result.trajectories[:, 1], np.tile(still, (len(path), 1)))
    closest = float(np.hypot(*(path - np.array(still)).T).min())
    assert closest >= escape.SAFE - 5e-4  # the sampled barrier's give, as the brain's
    assert path[-1, 0] > still[0] + 0.25  # past it, on to S
    assert result.slid >= 1
    # The same steps slid (4-29 over these angles, equal in both on 1 Dec 2026), and the
    # same path within 5 cm at every command: identical up to the slide, then the
    # simulator's reciprocal split takes the centre's velocity from the wheels, the
    # brain's from its last command (0.030 m apart at most).
    assert abs(result.slid - brain.counters.slid) <= 3
    commanded = np.array(brain_path)[::10, :2]  # robot 0 at each of the brain's commands
    assert np.hypot(*(commanded - path).T).max() < 0.05


def test_without_the_slide_the_simulated_robot_waits_for_ever() -> None:
    # The rule before 1 Dec 2026: never stopped dead, never slides.
    never = mock.patch.object(drive, "stopped_dead", lambda headings, *_: headings < -10.0)
    with never:
        result, still = beside_a_still_robot(math.radians(30))
    assert result.slid == 0
    assert result.trajectories[-1, 0, 0] < still[0]


def test_a_still_robot_is_out_of_every_cell_and_of_e_a() -> None:
    # Without the filter a dead brain's robot changes nothing for the others: the team with
    # it still is the team without it, to the bit.
    square = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]
    at = [(-0.5, -0.4), (0.3, -0.2), (0.0, 0.6), (0.6, 0.5), (-0.7, 0.7)]
    options = {"kappa": 2.0, "duration": SECONDS, "dt": 0.05}
    with_still = simulate(placed(at, square, agents=5, **options), still=[2], duration=1.0)
    others = at[:2] + at[3:]
    without = simulate(placed(others, square, agents=4, **options), duration=1.0)
    assert np.array_equal(with_still.error, without.error)
    assert np.array_equal(with_still.trajectories[:, [0, 1, 3, 4]], without.trajectories)
    assert np.array_equal(with_still.trajectories[:, 2], np.tile(at[2], (len(without.t), 1)))


def test_still_robots_are_refused_out_of_range_or_all() -> None:
    with pytest.raises(ValueError, match="robot 5 is not in a team of 5"):
        moving_robots(5, [5])
    with pytest.raises(ValueError, match="at least one must move"):
        moving_robots(2, [0, 1])
    with pytest.raises(ValueError, match="integers"):
        moving_robots(3, [True])
    assert moving_robots(3, [1]).tolist() == [True, False, True]


def test_sim_command_records_its_still_robots(tmp_path) -> None:
    runner = CliRunner()
    out = tmp_path / "run"
    args = ["--scenario", "circle", "--agents", "6", "--duration", "0.5", "--dt", "0.05"]
    done = runner.invoke(sim_command, [*args, "--still", "1,4", "--out", str(out)])
    assert done.exit_code == 0, done.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["still"] == [1, 4]
    bad = runner.invoke(sim_command, [*args, "--still", "7", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2
    assert "robot 7 is not in a team of 6" in bad.output
    bad = runner.invoke(sim_command, [*args, "--still", "one", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2
    assert "robot indices separated by commas" in bad.output


def _left_behind(result: SimResult, still: list[int]) -> int:
    """Moving robots more than 5 cm outside S at the end."""
    from shapely.geometry import Point, Polygon

    final = Polygon(result.final_polygon).buffer(0.05)
    moving = np.setdiff1d(np.arange(len(result.positions)), still)
    return sum(not final.contains(Point(*result.positions[i])) for i in moving)


def test_a_team_gets_past_its_dead_robots() -> None:
    # circle-400 with 10 robots dead where they started (covswarm sim --still 0,...,9), the
    # agents' settings, 15 s. Robots queue behind a dead one, each held at the safe distance
    # by the robot ahead with a forward speed of +-1e-17 m/s; tested as <= 0, their
    # SLIDE_AFTER wait restarted at every positive one, and the queues stood. Left behind at
    # the end, seeds 0-3 (1 Dec 2026): 37, 53, 43, 47 robots with STOPPED_SPEED, 85, 127,
    # 96, 105 with the test <= 0.
    scenario = load_scenario("scenarios/circle-400.toml")
    still = list(range(10))

    def run(seed: int) -> SimResult:
        return simulate(
            scenario, safety=True, dt=0.1, projection_distance=0.05, seed=seed, still=still,
            dynamics="unicycle", face_start=True, duration=15.0,
        )  # fmt: skip

    results = [run(seed) for seed in (0, 1)]
    with mock.patch.object(drive, "STOPPED_SPEED", 0.0):
        strict = [run(seed) for seed in (0, 1)]
    behind = sum(_left_behind(r, still) for r in results)
    assert behind <= 0.6 * sum(_left_behind(r, still) for r in strict)  # 90 against 212
    assert all(r.slid > 0 for r in results)
    # No robot drives into another, dead or alive (the start layout is 0.14 m apart).
    for r in results:
        closest = min(cKDTree(frame).query(frame, k=2)[0][:, 1].min() for frame in r.trajectories)
        assert closest >= 0.14 - 1e-3
