"""Scenarios: exact domain velocities, validity of built-ins, TOML loading and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from covswarm.mission.motion import Keyframes, Rigid
from covswarm.mission.scenario_files import load_scenario, scenario_from_dict
from covswarm.mission.scenarios import BUILTINS, Scenario
from covswarm.tvd.coverage import validate_polygon

RIGID_TOML = """
name = "spin"
agents = 7
kappa = 1.5
duration = 12
dt = 0.05
dynamics = "unicycle"
workspace = [-3.0, 3.0, -3.0, 3.0]
obstacles = [[2.5, 2.9, 2.5, 2.9]]  # clear of S at every instant

[initial]
box = [-0.5, 0.5, -0.5, 0.5]

[domain]
kind = "rigid"
polygon = [[-1.0, -0.5], [1.0, -0.5], [1.2, 0.5], [-1.0, 0.7]]
center = [0.2, -0.1]
radius = 0.8
period = -20.0
phase = 0.5
velocity = [0.01, 0.02]
rotation_rate = 0.3
scale_rate = -0.02
"""


def finite_difference_velocity(scenario: Scenario, t: float, h: float = 1e-5) -> np.ndarray:
    return (scenario.domain(t + h)[0] - scenario.domain(t - h)[0]) / (2 * h)


def signed_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


@pytest.fixture
def rigid_file(tmp_path: Path) -> Path:
    path = tmp_path / "spin.toml"
    path.write_text(RIGID_TOML)
    return path


def all_scenarios(rigid_file: Path) -> list[Scenario]:
    return [load_scenario(name) for name in BUILTINS] + [load_scenario(rigid_file)]


def test_velocities_match_finite_differences(rigid_file: Path) -> None:
    for scenario in all_scenarios(rigid_file):
        knots = getattr(scenario.motion, "times", np.array([]))
        for t in np.linspace(0.013, scenario.duration - 0.013, 37):
            if np.min(np.abs(knots - t), initial=1.0) < 1e-3:
                continue  # velocity jumps at keyframes
            expected = finite_difference_velocity(scenario, t)
            np.testing.assert_allclose(
                scenario.domain(t)[1], expected, atol=1e-7, err_msg=scenario.name
            )


def test_domains_are_valid_ccw_and_inside_the_workspace(rigid_file: Path) -> None:
    for scenario in all_scenarios(rigid_file):
        for t in np.linspace(0.0, scenario.duration, 101):
            vertices, velocities = scenario.domain(t)
            assert vertices.shape == velocities.shape == (len(vertices), 2)
            validate_polygon(vertices)
            assert signed_area(vertices) > 0, (scenario.name, t)
            if scenario.workspace is not None:
                xmin, xmax, ymin, ymax = scenario.workspace
                assert vertices[:, 0].min() >= xmin and vertices[:, 0].max() <= xmax
                assert vertices[:, 1].min() >= ymin and vertices[:, 1].max() <= ymax


def test_passage_avoids_obstacles_and_has_piecewise_constant_sides() -> None:
    scenario = load_scenario("passage")
    assert (scenario.agents, scenario.kappa, scenario.dynamics) == (10, 2.0, "unicycle")
    assert scenario.workspace is not None
    width = scenario.workspace[1] - scenario.workspace[0]
    height = scenario.workspace[3] - scenario.workspace[2]
    assert (width, height) == pytest.approx((5.182, 3.658))
    robot_radius = 0.07
    for t in np.linspace(0.0, scenario.duration, 901):
        vertices = scenario.domain(t)[0]
        xmin, ymin = vertices.min(axis=0)
        xmax, ymax = vertices.max(axis=0)
        for oxmin, oxmax, oymin, oymax in scenario.obstacles:
            overlap_x = xmin < oxmax + robot_radius and xmax > oxmin - robot_radius
            overlap_y = ymin < oymax + robot_radius and ymax > oymin - robot_radius
            assert not (overlap_x and overlap_y), t
    # Within a segment every vertex velocity is constant.
    times = scenario.motion.times
    for a, b in zip(times[:-1], times[1:], strict=True):
        speeds = [scenario.domain(t)[1] for t in np.linspace(a, b, 5, endpoint=False)]
        assert all(np.array_equal(s, speeds[0]) for s in speeds)
    start, goal = scenario.domain(0.0)[0], scenario.domain(scenario.duration)[0]
    assert start[:, 0].max() < -1.0 and goal[:, 0].min() > 1.0


def test_circle_moves_counter_clockwise_at_feasible_speed() -> None:
    scenario = load_scenario("circle")
    assert scenario.agents == 100 and scenario.dynamics == "single"
    centres = np.array([scenario.domain(t)[0].mean(axis=0) for t in (0.0, 1.0)])
    step = centres[1] - centres[0]
    assert centres[0, 0] * step[1] - centres[0, 1] * step[0] > 0
    speed = np.linalg.norm(scenario.domain(3.0)[1], axis=1)
    assert speed.max() < 0.5


def test_initial_positions_are_seeded(rigid_file: Path) -> None:
    for scenario in all_scenarios(rigid_file):
        a = scenario.initial_positions(25, seed=4)
        np.testing.assert_array_equal(a, scenario.initial_positions(25, seed=4))
        assert a.shape == (25, 2)
        assert not np.array_equal(a, scenario.initial_positions(25, seed=5))
    circle = load_scenario("circle")
    square = circle.domain(0.0)[0]
    points = circle.initial_positions(200, seed=1)
    assert np.all(points >= square.min(axis=0)) and np.all(points <= square.max(axis=0))
    boxed = load_scenario(rigid_file).initial_positions(50, seed=0)
    assert np.all(np.abs(boxed) <= 0.5)


def brute_force_initial_positions(scenario: Scenario, n: int, seed: int) -> np.ndarray:
    """Reference for Scenario.initial_positions: the same draws from the same stream
    (uniform in the start box, or by rejection from the domain's bounding box), each robot
    compared with every robot placed before it; redrawn while closer than the separation."""
    rng = np.random.default_rng(seed)
    polygon = scenario.domain(0.0)[0]

    def draw(k: int) -> np.ndarray:
        if scenario.initial_box is not None:
            xmin, xmax, ymin, ymax = scenario.initial_box
            return rng.uniform([xmin, ymin], [xmax, ymax], size=(k, 2))
        points = np.empty((0, 2))
        while len(points) < k:
            batch = rng.uniform(polygon.min(axis=0), polygon.max(axis=0), size=(2 * k + 8, 2))
            inside = [shapely.Polygon(polygon).contains(shapely.Point(p)) for p in batch]
            points = np.concatenate([points, batch[inside]])
        return points[:k]

    positions = draw(n)
    separation = scenario.start_separation(n)
    for i in range(1, n):
        while np.hypot(*(positions[:i] - positions[i]).T).min() < separation:
            positions[i] = draw(1)[0]
    return positions


def test_initial_positions_equal_the_brute_force_placement(rigid_file: Path) -> None:
    """The binned check (mission.scenarios._Placed) places every robot where comparing it
    with every robot placed before would: the same layouts, bit for bit, for packed starts
    (circle-1000 at 1000 robots redraws ~2800 times) and body-limited ones."""
    circle_1000 = load_scenario(Path(__file__).parents[1] / "scenarios" / "circle-1000.toml")
    cases = [(circle_1000, 1000, 0), (circle_1000, 600, 3)]
    cases += [(load_scenario(name), n, seed) for name in ("circle", "passage") for n, seed in
              [(100, 0), (300, 7)]]  # fmt: skip
    cases += [(load_scenario(rigid_file), 40, 2)]  # a start box
    for scenario, n, seed in cases:
        expected = brute_force_initial_positions(scenario, n, seed)
        np.testing.assert_array_equal(
            scenario.initial_positions(n, seed), expected, err_msg=f"{scenario.name} {n} {seed}"
        )
        gaps = np.hypot(*(expected[:, None] - expected[None]).transpose(2, 0, 1))
        assert gaps[np.triu_indices(n, 1)].min() >= scenario.start_separation(n)


def test_rigid_toml_fields(rigid_file: Path) -> None:
    scenario = load_scenario(rigid_file)
    assert (scenario.name, scenario.agents, scenario.kappa) == ("spin", 7, 1.5)
    assert (scenario.duration, scenario.dt, scenario.dynamics) == (12.0, 0.05, "unicycle")
    assert scenario.obstacles == ((2.5, 2.9, 2.5, 2.9),)
    # Clockwise circling (negative period): the origin starts at phase 0.5 on the circle.
    motion = scenario.motion
    assert isinstance(motion, Rigid)
    origin = np.array([0.2, -0.1]) + 0.8 * np.array([math.cos(0.5), math.sin(0.5)])
    np.testing.assert_allclose(scenario.domain(0.0)[0], motion.polygon + origin)


@pytest.mark.parametrize("name", [*BUILTINS, "file"])
def test_toml_round_trip(name: str, rigid_file: Path, tmp_path: Path) -> None:
    original = load_scenario(rigid_file if name == "file" else name)
    path = tmp_path / "copy.toml"
    path.write_text(original.to_toml())
    copy = load_scenario(path)
    for key in ("name", "agents", "kappa", "duration", "dt", "dynamics", "workspace", "obstacles"):
        assert getattr(copy, key) == getattr(original, key), key
    assert copy.initial_box == original.initial_box
    for t in np.linspace(0.0, original.duration, 23):
        for mine, theirs in zip(copy.domain(t), original.domain(t), strict=True):
            np.testing.assert_array_equal(mine, theirs)
    np.testing.assert_array_equal(copy.initial_positions(9, 2), original.initial_positions(9, 2))


def test_keyframes_interpolate_and_hold() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    clockwise = square[::-1]
    motion = Keyframes(times=[1.0, 3.0], vertices=[clockwise, clockwise * 2.0])
    vertices, velocities = motion(2.0)
    np.testing.assert_allclose(vertices, square * 1.5)  # made CCW, correspondence kept
    np.testing.assert_allclose(velocities, square * 0.5)
    for t, scale in ((0.0, 1.0), (5.0, 2.0)):
        vertices, velocities = motion(t)
        np.testing.assert_allclose(vertices, square * scale)
        np.testing.assert_array_equal(velocities, 0.0)


def scenario_text(domain: str, top: str = "") -> str:
    return f'name = "x"\nduration = 10\n{top}\n[domain]\n{domain}\n'


SQUARE = "[[0, 0], [1, 0], [1, 1], [0, 1]]"
BAD_FILES = {
    "not toml": ("name = ", "invalid TOML"),
    "no domain": ('name = "x"\n', "required"),
    "unknown key": (scenario_text(f'kind = "rigid"\npolygon = {SQUARE}', "colour = 1"), "unknown"),
    "bad kind": (scenario_text('kind = "spline"'), "kind"),
    "domain typo": (
        scenario_text(f'kind = "rigid"\npolgon = {SQUARE}'),
        r"\[domain\]: missing \['polygon'\], unknown \['polgon'\]",
    ),
    "non-convex": (
        scenario_text('kind = "rigid"\npolygon = [[0, 0], [2, 0], [0.5, 0.5], [0, 2]]'),
        "t = 0",
    ),
    "two points": (scenario_text('kind = "rigid"\npolygon = [[0, 0], [1, 0]]'), "3"),
    "unsorted times": (
        scenario_text(f'kind = "keyframes"\ntimes = [1, 0]\nvertices = [{SQUARE}, {SQUARE}]'),
        "increasing",
    ),
    "count mismatch": (
        scenario_text(f'kind = "keyframes"\ntimes = [0, 1, 2]\nvertices = [{SQUARE}, {SQUARE}]'),
        "3 times",
    ),
    "vertex mismatch": (
        scenario_text(
            f'kind = "keyframes"\ntimes = [0, 1]\nvertices = [{SQUARE}, [[0, 0], [1, 0], [0, 1]]]'
        ),
        "same number",
    ),
    "mixed orientation": (
        scenario_text(
            'kind = "keyframes"\ntimes = [0, 1]\n'
            f"vertices = [{SQUARE}, [[0, 1], [1, 1], [1, 0], [0, 0]]]"
        ),
        "orientation",
    ),
    "collapses between keyframes": (
        # Both squares are CCW, but every vertex crosses to the opposite corner: the
        # interpolated polygon collapses to a point half-way.
        scenario_text(
            'kind = "keyframes"\ntimes = [0, 1]\n'
            f"vertices = [{SQUARE}, [[1, 1], [0, 1], [0, 0], [1, 0]]]"
        ),
        "t = 0.5",
    ),
    "shrinks to nothing": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}\nscale_rate = -0.2'),
        "t = ",
    ),
    "bad dynamics": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}', 'dynamics = "car"'),
        "dynamics",
    ),
    "bad box": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}', "obstacles = [[1, 0, 0, 1]]"),
        "xmin < xmax",
    ),
    "negative kappa": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}', "kappa = -1"),
        "kappa",
    ),
    "shrinks through zero": (  # past 0 the scale turns S half a turn: still "valid"
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}\nscale_rate = -1.0'),
        "its scale 1 \\+ scale_rate t reaches 0 at t = 1 s, within the 10 s mission",
    ),
    "density without floor": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}')
        + "[density]\n[[density.bumps]]\nmean = [0.5, 0.5]\ncov = [[0.1, 0], [0, 0.1]]\n"
        "weight = 2.0\n",
        r"\[density\]: needs 'floor'",
    ),
    "density key typo": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}') + "[density]\nfloor = 1\nflor = 2\n",
        r"\[density\]: unknown keys \['flor'\]; the keys are floor, bumps$",
    ),
    "bump key typo": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}')
        + "[density]\nfloor = 1\n[[density.bumps]]\nmean = [0.5, 0.5]\n"
        "cov = [[0.1, 0], [0, 0.1]]\nweight = 2.0\nsigma = 3\n",
        r"bump 0: unknown keys \['sigma'\]; the keys are .*weight_rate, turn_rate$",
    ),
    "bump mean of four": (
        scenario_text(f'kind = "rigid"\npolygon = {SQUARE}')
        + "[density]\nfloor = 1\n[[density.bumps]]\nmean = [0.0, 0.5, 1.0, 1.0]\n"
        "cov = [[0.1, 0], [0, 0.1]]\nweight = 2.0\n",
        r"\[density\]: bump 0 mean must be \[x, y\]",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_files_raise_value_error_naming_the_file(case: str, tmp_path: Path) -> None:
    text, fragment = BAD_FILES[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=fragment) as info:
        load_scenario(path)
    assert str(path) in str(info.value)


def test_unknown_names_and_missing_files() -> None:
    with pytest.raises(ValueError, match="circle"):
        load_scenario("nope")
    with pytest.raises(ValueError, match="cannot read"):
        load_scenario("/nonexistent/x.toml")


def test_scenario_from_dict_defaults() -> None:
    scenario = scenario_from_dict(
        {"name": "d", "domain": {"kind": "rigid", "polygon": [[0, 0], [1, 0], [0, 1]]}}
    )
    assert scenario.dynamics == "single" and scenario.initial_box is None
    assert scenario.obstacles == () and scenario.workspace is None


def test_formation_100_is_the_formation_scaled_for_100_robots() -> None:
    """scenarios/formation-100.toml's comment: every length of the built-in times sqrt(5),
    speeds likewise, so that 100 robots have the area per robot that 20 have there."""
    root = Path(__file__).resolve().parents[1]
    big, small = (
        load_scenario(root / "scenarios" / "formation-100.toml"),
        load_scenario("formation"),
    )
    k = math.sqrt(5.0)
    assert (big.agents, small.agents) == (100, 20)
    rng = np.random.default_rng(3)
    for t in (0.0, 7.3, 21.0, 39.9):
        (v_big, u_big), (v_small, u_small) = big.motion(t), small.motion(t)
        np.testing.assert_allclose(v_big, k * v_small, atol=1e-3)
        np.testing.assert_allclose(u_big, k * u_small, atol=1e-3)
        q = rng.uniform(-1.0, 1.0, (50, 2))
        np.testing.assert_allclose(big.density(t).phi(k * q), small.density(t).phi(q), rtol=1e-3)
        area_big, area_small = (shapely.Polygon(v).area for v in (v_big, v_small))
        assert area_big / 100 == pytest.approx(area_small / 20, rel=1e-3)


@pytest.mark.parametrize("name", ["circle-400", "circle-1000"])
def test_the_big_circle_scenarios_keep_the_papers_density_and_motion(name: str) -> None:
    """scenarios/circle-400.toml and circle-1000.toml (the teams of docs/scaling.md): the
    circle scenario's area per robot and centre motion, at their team sizes."""
    paper = load_scenario("circle")
    big = load_scenario(Path(__file__).parents[1] / "scenarios" / f"{name}.toml")
    per_robot = shapely.Polygon(paper.domain(0.0)[0]).area / paper.agents
    assert shapely.Polygon(big.domain(0.0)[0]).area / big.agents == pytest.approx(per_robot, 1e-3)
    for t in (0.0, 7.0, 31.0):
        centre = np.mean(big.domain(t)[0], axis=0)
        assert centre == pytest.approx(np.mean(paper.domain(t)[0], axis=0), abs=1e-3)
