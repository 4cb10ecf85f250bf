"""Robots whose brains are dead in ``covswarm sim`` (simulate's ``still``): they stand where
they start, still generators of the diagram (their cells bound the others'), out of e_a, and
the others' safety filters keep them as still rows, as the agents keep a stranded robot. A
robot the filter stops dead beside one takes its slide (covswarm.tvd.drive.steer) as an
agent's brain does (tests/test_slide.py): the simulator's path is checked against one
AgentBrain's (scripts/slide_escape.py)."""

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
from covswarm.tvd.coverage import aggregate_error

escape = load_script("slide_escape")
waiting = load_script("beside_slide").slides_only_after_waiting  # SLIDE_AFTER alone
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


def passing(degrees: float) -> tuple[SimResult, tuple[float, float], object, np.ndarray]:
    """The simulator's run beside a still robot ``degrees`` off the aim, its still robot,
    and the brain's (scripts/slide_escape.py): (result, still, brain, brain's path)."""
    result, still = beside_a_still_robot(math.radians(degrees))
    brain, brain_path, _ = escape.drive_past(math.radians(degrees), SECONDS)
    return result, still, brain, np.array(brain_path)


def in_step(result: SimResult, brain_path: np.ndarray) -> float:
    """m: how far the simulator's robot 0 is from the brain's at the brain's commands, in
    step or the brain's one command ahead (the less of the two worst distances)."""
    path = result.trajectories[:, 0]
    commanded = brain_path[::10, :2]  # robot 0 at each of the brain's commands
    ahead = np.hypot(*(commanded[:-1] - path[1:]).T).max()
    return float(min(np.hypot(*(commanded - path).T).max(), ahead))


@pytest.mark.parametrize("degrees", [0, 3, 10, 30, 60, -40])
def test_the_simulator_passes_a_still_robot_as_a_brain_does(degrees: int) -> None:
    # The slide's machinery, taken after SLIDE_AFTER in both: where the robot stopped dead
    # with none ahead slides at once (below), the brain, a command ahead of the simulator
    # at the end of the harness's pin, starts its slide from a step's different state, and
    # at 50-65 and 80 degrees the two paths part by 0.14-0.40 m (both get past).
    with waiting():
        result, still, brain, brain_path = passing(degrees)
    path = result.trajectories[:, 0]
    assert np.array_equal(result.trajectories[:, 1], np.tile(still, (len(path), 1)))
    closest = float(np.hypot(*(path - np.array(still)).T).min())
    assert closest >= escape.SAFE - 5e-4  # the sampled barrier's give, as the brain's
    assert path[-1, 0] > still[0] + 0.25  # past it, on to S
    assert result.slid >= 1
    # The same steps slid (3-32 over these angles, equal in both but one at 60 degrees, 1
    # Dec 2026), and the same path at every command, in step or the brain's one command
    # ahead: the brain's 1 s wait for its slide may start a period before the end of the
    # harness's pin (scripts/slide_escape.py), so its slide starts a step sooner (at 0, 3,
    # 10 and -40 degrees: the paths then 0.5-1.1 mm apart one step shifted, against up to
    # 0.079 m in step). In step at 30 and 60 degrees: 0.6 and 16 mm apart, the simulator's
    # reciprocal split taking the centre's velocity from the wheels, the brain's from its
    # last command.
    assert abs(result.slid - brain.counters.slid) <= 3
    assert in_step(result, brain_path) < 0.03


@pytest.mark.parametrize("degrees", [70, 75, -70])
def test_with_none_ahead_the_simulator_slides_at_once_as_a_brain_does(degrees: int) -> None:
    # The still robot more than BESIDE_ANGLE off the heading (covswarm.tvd.drive.
    # stopped_beside): both slide from their first stopped step, the same steps, the same
    # path (2-4 mm apart), and get past it sooner than after SLIDE_AFTER.
    result, still, brain, brain_path = passing(degrees)
    assert result.slid == brain.counters.slid >= 1
    assert in_step(result, brain_path) < 0.01
    with waiting():
        later, _ = beside_a_still_robot(math.radians(degrees))
    assert result.trajectories[-1, 0, 0] > later.trajectories[-1, 0, 0] + 0.1
    assert float(np.hypot(*(result.trajectories[:, 0] - np.array(still)).T).min()) >= (
        escape.SAFE - 5e-4
    )


def test_without_the_slide_the_simulated_robot_waits_for_ever() -> None:
    # The rule before 1 Dec 2026: never stopped dead, never slides.
    never = mock.patch.object(drive, "stopped_dead", lambda headings, *_: headings < -10.0)
    with never:
        result, still = beside_a_still_robot(math.radians(30))
    assert result.slid == 0
    assert result.trajectories[-1, 0, 0] < still[0]


def test_a_still_robot_keeps_its_cell_and_is_out_of_e_a() -> None:
    # Without the filter: the dead brain's robot stands at S's centre, one robot beside it
    # and eight on a ring; the others end at a CVT around it, not on it, and e_a is theirs,
    # in the cells it bounds.
    square = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]
    ring = [(0.7 * math.cos(a), 0.7 * math.sin(a)) for a in np.linspace(0, 2 * np.pi, 9)[:-1]]
    at = [(0.05, 0.0), *ring[:2], (0.0, 0.0), *ring[2:]]
    options = {"kappa": 2.0, "duration": SECONDS, "dt": 0.05}
    result = simulate(placed(at, square, agents=10, **options), still=[3], duration=6.0)
    assert np.array_equal(result.trajectories[:, 3], np.tile(at[3], (len(result.t), 1)))
    standing = np.arange(10) == 3
    for k in (0, len(result.t) // 2, len(result.t) - 1):
        expected = aggregate_error(result.trajectories[k], result.polygons[k], None, standing)
        assert abs(result.error[k] - expected) <= 1e-12
    assert result.error[-1] < 0.01  # measured 0.00016 m
    # Robot 0 started 5 cm from it; now its cell's centroid is a cell's size away.
    final = result.trajectories[-1]
    assert np.hypot(*(final[~standing] - final[3]).T).min() > 0.3  # measured 0.39 m
    # Out of the diagram, as before this rule, robot 0 ended on top of it.
    others = at[:3] + at[4:]
    without = simulate(placed(others, square, agents=9, **options), duration=6.0)
    assert np.hypot(*(without.trajectories[-1] - at[3]).T).min() < 0.05  # measured 0.009 m


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
    for text in ("one", "0,,1", ","):  # as --ids: no empty or unreadable part
        bad = runner.invoke(sim_command, [*args, "--still", text, "--out", str(tmp_path / "bad")])
        assert bad.exit_code == 2
        assert f"invalid id list {text!r}" in bad.output
    ranged = runner.invoke(sim_command, [*args, "--still", "0-1", "--out", str(tmp_path / "r")])
    assert ranged.exit_code == 0, ranged.output
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["still"] == [0, 1]


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

    # STOPPED_SPEED's part with SLIDE_AFTER alone (the slide at once of a robot with none
    # ahead, 3 Dec 2026, frees many of those queues too: 70 left behind with it, against 107
    # with the test <= 0).
    with waiting():
        results = [run(seed) for seed in (0, 1)]
        with mock.patch.object(drive, "STOPPED_SPEED", 0.0):
            strict = [run(seed) for seed in (0, 1)]
    behind = sum(_left_behind(r, still) for r in results)
    assert behind <= 0.6 * sum(_left_behind(r, still) for r in strict)  # 90 against 212
    results = [run(seed) for seed in (0, 1)]
    assert sum(_left_behind(r, still) for r in results) <= behind  # 70 against 90
    assert all(r.slid > 0 for r in results)
    # No robot drives into another, dead or alive (the start layout is 0.14 m apart).
    for r in results:
        closest = min(cKDTree(frame).query(frame, k=2)[0][:, 1].min() for frame in r.trajectories)
        assert closest >= 0.14 - 1e-3


def test_the_trajectory_plot_marks_the_dead_robots_where_they_stand() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covswarm.mission.report import _trajectory_figure

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trajectories = np.array([[[0.2, 0.2], [0.8, 0.3], [0.5, 0.8]]] * 3)
    trajectories[:, 0] += np.linspace(0.0, 0.1, 3)[:, None]  # robot 0 moves; 1 and 2 stand
    for still, expected in (([1, 2], [[0.8, 0.3], [0.5, 0.8]]), ([], None)):
        fig = _trajectory_figure(plt, {"still": still}, trajectories, [square] * 3, (), None, None)
        ax = fig.axes[0]
        marked = [c for c in ax.collections if c.get_label().startswith("dead robots")]
        if expected is None:
            assert marked == []
        else:
            assert len(marked) == 1
            np.testing.assert_allclose(marked[0].get_offsets(), expected)
        plt.close(fig)
