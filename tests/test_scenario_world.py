"""Scenarios know their world: obstacles as boxes, polygons and maps; S checked against them
at load; and scenario files that are not what they claim are refused with a sentence."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from hang_checks import value_errors_within
from PIL import Image
from shapely.geometry import Polygon

from covswarm.mission.motion import Keyframes
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import Scenario

DATA = Path(__file__).resolve().parent / "data"
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
RECT = "[[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]]"


def text(top: str = "", domain: str = "") -> str:
    domain = domain or f'kind = "keyframes"\ntimes = [0.0]\nvertices = [{RECT}]'
    return f'name = "x"\nduration = 10\n{top}\n[domain]\n{domain}\n'


def load_text(tmp_path: Path, body: str, name: str = "s.toml") -> Scenario:
    path = tmp_path / name
    path.write_text(body)
    return load_scenario(path)


def test_through_the_wall_is_refused_with_the_time_and_the_wall() -> None:
    path = DATA / "through_the_wall.toml"
    with pytest.raises(ValueError) as info:
        load_scenario(path)
    message = str(info.value)
    assert str(path) in message and "obstacle 1" in message
    time = float(re.search(r"t = ([0-9.]+) s", message).group(1))
    assert time == pytest.approx(8.75, abs=2e-3)
    # the same S past a wall that leaves it room (moved up out of the way) is accepted
    left = np.array([[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]])
    scenario = Scenario(
        name="clear",
        motion=Keyframes(times=np.array([0.0, 5.0]), vertices=np.array([left, left + [3.6, 0]])),
        workspace=(-2.591, 2.591, -1.829, 1.829),
        obstacles=((-0.3, 0.3, 0.9, 1.8),),
    )
    assert [o.name for o in scenario.world.obstacles] == ["obstacle 1"]
    assert scenario.world.overlap_area(scenario.domain(2.5)[0]) == 0.0


def test_leaving_the_workspace_is_refused() -> None:
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    with pytest.raises(ValueError, match=r"leaves the workspace at t = 2\.50"):
        Scenario(
            name="out",
            motion=Keyframes(times=np.array([0.0, 10.0]), vertices=np.array([square, square + 4])),
            workspace=(-1.0, 2.0, -1.0, 2.0),
        )


def test_polygons_boxes_and_a_map_make_the_world(tmp_path: Path) -> None:
    grey = np.full((20, 20), 254, np.uint8)
    grey[:2, :] = 0  # the top two rows: a wall y in [0.9, 1.0] for origin (-1, -1), 5 cm
    Image.fromarray(grey, mode="L").save(tmp_path / "lab.pgm")
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "lab.yaml").write_text(
        "image: ../lab.pgm\nresolution: 0.1\norigin: [-1.0, -1.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    small = "[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]"
    body = text(
        "obstacles = [[0.6, 0.9, -0.9, -0.6], [[-0.9, -0.9], [-0.6, -0.9], [-0.75, -0.6]]]\n"
        'map = "maps/lab.yaml"',
        f'kind = "keyframes"\ntimes = [0.0]\nvertices = [{small}]',
    )
    scenario = load_text(tmp_path, body)
    world = scenario.world
    assert world.workspace == pytest.approx((-1.0, 1.0, -1.0, 1.0))  # the map's extent
    assert [o.name for o in world.obstacles] == ["obstacle 1", "obstacle 2", "map piece 1"]
    assert world.obstacles[2].box == pytest.approx((-1.0, 1.0, 0.8, 1.0))
    assert scenario.obstacles == ((0.6, 0.9, -0.9, -0.6), world.obstacles[2].box)
    # written back and read again: the same geometry (the map's pieces as boxes)
    copy = load_text(tmp_path, scenario.to_toml(), "copy.toml")
    for a, b in zip(copy.world.obstacles, world.obstacles, strict=True):
        assert Polygon(a.vertices).equals(Polygon(b.vertices))
    # S moved onto the map's wall is refused, naming the piece
    onto = body.replace(f"vertices = [{small}]", f"vertices = [{small.replace('0.5]', '0.85]')}]")
    with pytest.raises(
        ValueError, match=r"touches 'map piece 1' \(\[-1, 1\] x \[0.8, 1\] m\) at t = 0.000 s"
    ):
        load_text(tmp_path, onto)


BAD = {
    "agents true": (text("agents = true"), "agents must be an integer"),
    "agents huge": (text("agents = 10000000000"), "agents must be an integer from 1"),
    "duration 1e300": (
        text().replace("duration = 10", "duration = 1e300"),
        "duration must be at most",
    ),
    "duration nan": (text().replace("duration = 10", "duration = nan"), "duration must be finite"),
    "kappa string": (text('kappa = "2"'), "kappa must be a number"),
    "kappa table": (text("kappa = {x = 1}"), "kappa must be a number"),
    "dt longer": (text("dt = 20.0"), "dt 20.0 s is longer"),
    "name number": (text().replace('name = "x"', "name = 5"), "name must be a string"),
    "dynamics list": (text('dynamics = ["single"]'), "dynamics must be a string"),
    "workspace string": (text('workspace = "arena"'), "workspace: box"),
    "workspace table": (text("workspace = {a = 1}"), "workspace: box"),
    "workspace strings": (text('workspace = ["a", 1, 0, 1]'), "workspace: box must be a number"),
    "obstacles table": (text("obstacles = {a = 1}"), "obstacles must be a list"),
    "obstacle bool": (text("obstacles = [true]"), "obstacle 1: True is neither"),
    "obstacle concave": (
        text("obstacles = [[[0, 0], [2, 0], [1, 0.2], [2, 2], [0, 2]]]"),
        "obstacle 1: the polygon is not convex",
    ),
    "map number": (text("map = 3"), "map must be the path"),
    "map missing": (text('map = "nope.yaml"'), "map: .*nope.yaml: cannot read"),
    "initial number": (text("initial = 5"), r"\[initial\] must be a table"),
    "initial box bool": (text("[initial]\nbox = true"), r"\[initial\] box: box True"),
    "domain number": ('name = "x"\ndomain = 5\n', r"\[domain\] must be a table"),
    "times table": (
        text(domain=f'kind = "keyframes"\ntimes = {{a = 1}}\nvertices = [{RECT}]'),
        "times and vertices must be lists",
    ),
    "times strings": (
        text(domain=f'kind = "keyframes"\ntimes = ["0"]\nvertices = [{RECT}]'),
        r"\[domain\] times must be a number",
    ),
    "vertex strings": (
        text(domain='kind = "keyframes"\ntimes = [0]\nvertices = [[[0, 0], [1, "a"], [1, 1]]]'),
        r"\[domain\] vertices must be a number",
    ),
    "rigid center table": (
        text(domain=f'kind = "rigid"\npolygon = {RECT}\ncenter = {{x = 1}}'),
        r"\[domain\] center: need \[x, y\]",
    ),
    "rigid radius string": (
        text(domain=f'kind = "rigid"\npolygon = {RECT}\nradius = "1"'),
        r"\[domain\] radius must be a number",
    ),
    "rigid period bool": (
        text(domain=f'kind = "rigid"\npolygon = {RECT}\nperiod = true'),
        r"\[domain\] period must be a number",
    ),
    "kind number": (text(domain="kind = 3"), r"\[domain\] kind must be"),
    "density number": (text("density = 3"), r"\[density\]"),
    "not utf-8": ('name = "\xff"\n', "not UTF-8"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_type_errors_get_a_sentence_naming_the_key(case: str, tmp_path: Path) -> None:
    body, fragment = BAD[case]
    path = tmp_path / "bad.toml"
    if case == "not utf-8":
        path.write_bytes(b'name = "\xff"\n')
    else:
        path.write_text(body)
    with pytest.raises(ValueError, match=fragment) as info:
        load_scenario(path)
    assert str(path) in str(info.value)


def test_fifo_device_and_oversize_files_are_refused_without_hanging(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    errors = value_errors_within(load_scenario, fifo)
    assert errors and "not a regular file" in str(errors[0])
    big = tmp_path / "big.toml"
    big.write_text(text() + "#" * (1 << 20))
    with pytest.raises(ValueError, match="more than the 1048576 allowed"):
        load_scenario(big)
    zero = tmp_path / "zero.toml"
    zero.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match="not a regular file"):
        load_scenario(zero)


def smallest_area(scenario: Scenario, samples: int = 400) -> float:
    """m^2: the smallest S over the scenario's motion, sampled."""
    times = np.linspace(0.0, scenario.motion.end, samples)
    return min(Polygon(scenario.domain(float(t))[0]).area for t in times)


@pytest.mark.parametrize("agents", [4, 12, 30])
def test_a_route_is_planned_for_the_team_that_runs_it(agents: int) -> None:
    # --agents of sim and run: S never smaller than that team may take, nor held to the size
    # the file's team needs.
    from covswarm.mission.crowding import least_domain

    scenario = load_scenario(str(SCENARIOS / "lab-route.toml"), agents)
    assert scenario.agents == agents
    least = least_domain(agents, scenario.robot_diameter)[0]
    assert smallest_area(scenario) >= least * (1 - 1e-6)


def test_the_warehouse_shrinks_for_a_small_team_as_far_as_it_may() -> None:
    from covswarm.mission.crowding import least_domain

    small, own = load_scenario("warehouse", 6), load_scenario("warehouse")
    assert (small.agents, own.agents) == (6, 20)
    assert smallest_area(small) >= least_domain(6, small.robot_diameter)[0] * (1 - 1e-6)
    assert smallest_area(small) < 0.5 * smallest_area(own)


def test_a_door_too_narrow_for_the_files_team_passes_a_smaller_one(tmp_path: Path) -> None:
    text = (SCENARIOS / "lab-route.toml").read_text(encoding="utf-8")
    text = text.replace('map = "lab.yaml"', f'map = "{SCENARIOS / "lab.yaml"}"\n'
                        "obstacles = [[-0.1, 0.1, 0.3, 0.8]]")  # fmt: skip
    # Without the file's 110 s: two robots' route through the narrower door ends at 112 s,
    # so the mission lasts the route's own length (a 110 s one is refused).
    text = text.replace("duration = 110.0\n", "")
    path = tmp_path / "door.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ValueError, match="too-narrow"):
        load_scenario(str(path))  # the file's 12 robots: the 0.7 m door is too narrow
    assert load_scenario(str(path), 2).agents == 2


def test_sim_plans_the_route_for_its_agents_option(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    text = (SCENARIOS / "lab-route.toml").read_text(encoding="utf-8")
    text = text.replace('map = "lab.yaml"', f'map = "{SCENARIOS / "lab.yaml"}"\n'
                        "obstacles = [[-0.1, 0.1, 0.3, 0.8]]")  # fmt: skip
    # Without the file's 110 s: two robots' route through the narrower door ends at 112 s,
    # so the mission lasts the route's own length (a 110 s one is refused).
    text = text.replace("duration = 110.0\n", "")
    (tmp_path / "door.toml").write_text(text, encoding="utf-8")
    sim = ["sim", "--scenario", str(tmp_path / "door.toml"), "--dt", "0.1"]
    refused = CliRunner().invoke(main, [*sim, "--out", str(tmp_path / "a")])
    assert refused.exit_code == 2 and "too-narrow" in refused.output
    ran = CliRunner().invoke(main, [*sim, "--agents", "2", "--out", str(tmp_path / "b")])
    assert ran.exit_code == 0, ran.output
    assert "goals reached 2 of 2" in " ".join(ran.output.split())  # the whole route
