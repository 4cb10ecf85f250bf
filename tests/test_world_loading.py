"""Loading a world: what a scenario file, its map and the commands' --duration refuse, each
with one line naming the problem and what to do (the walk-through of docs/world.md).

Route length (a route's mission lasts its end, never cut short), the start box (in the
workspace, clear of obstacles), maps too fine to send (refused in seconds, before building
their pieces), a workspace beyond the map, obstacles wholly outside the workspace, a map's
YAML syntax errors and 16-bit images.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hang_checks import value_errors_within
from PIL import Image
from shapely.geometry import Point, box

from covswarm.coordinator.broadcastable import check_broadcastable
from covswarm.deploy.cli import main
from covswarm.mission.motion import Keyframes
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import SETTLE, Scenario, warehouse
from covswarm.world.maps import (
    EDGE_TOLERANCE,
    count_rectangles,
    cover_rectangles,
    read_map,
    world_from_map,
)

ROOT = Path(__file__).resolve().parents[1]
ARENA = [-2.591, 2.591, -1.829, 1.829]
WALL = [-0.3, 0.3, -1.0, 1.0]
LEFT = [[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]]
FREE, OCC = 254, 0


def route_toml(duration: float | None = None) -> str:
    """S sent round the wall to (1.8, 0): a route that ends at 57.5 s, past the 40 s default."""
    line = "" if duration is None else f"duration = {duration}\n"
    return (
        f'name = "round"\nagents = 4\n{line}workspace = {ARENA}\nobstacles = [{WALL}]\n\n'
        f'[domain]\nkind = "route"\npolygon = {LEFT}\ngoals = [[1.8, 0.0]]\nspeed = 0.3\n'
    )


def keyframes_text(top: str, still: list[list[float]] | None = None) -> str:
    s = LEFT if still is None else still
    return (
        f'name = "x"\nduration = 10\n{top}\n[domain]\nkind = "keyframes"\ntimes = [0.0]\n'
        f"vertices = [{s}]\n"
    )


def write(tmp_path: Path, body: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(body, encoding="utf-8")
    return path


def one_line(message: str) -> None:
    assert "\n" not in message and "Traceback" not in message


# ----------------------------------------------------------------- 1. a route's duration


def test_a_route_without_duration_lasts_its_end_plus_the_warehouses_margin(tmp_path) -> None:
    scenario = load_scenario(write(tmp_path, route_toml()))
    end = scenario.motion.end
    assert end > 40.0  # the default 40 s would have cut it short
    assert scenario.duration == math.ceil(end) + SETTLE
    # the S the mission ends with is S at the goal, at rest
    vertices, velocities = scenario.domain(scenario.duration)
    np.testing.assert_allclose(vertices.mean(axis=0), (1.8, 0.0), atol=1e-9)
    assert np.abs(velocities).max() == 0.0
    # the built-in warehouse keeps the same margin
    built = warehouse(6)
    assert built.duration == math.ceil(built.motion.end) + SETTLE


def test_a_duration_ending_before_the_route_is_refused_with_the_routes_end(tmp_path) -> None:
    path = write(tmp_path, route_toml(duration=40.0))
    with pytest.raises(ValueError) as info:
        load_scenario(path)
    message = str(info.value)
    one_line(message)
    assert message.startswith(f"{path}: the route ends at 57.5 s, after the mission's 40 s")
    assert "give duration >= 57.6 or fewer goals" in message
    # a duration that covers it is kept as given
    assert load_scenario(write(tmp_path, route_toml(duration=58.0), "ok.toml")).duration == 58.0


def test_sim_refuses_a_duration_option_ending_before_the_route(tmp_path) -> None:
    path = write(tmp_path, route_toml())
    args = ["sim", "--scenario", str(path), "--duration", "5", "--out", str(tmp_path / "sim")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    assert "the route ends at 57.5 s, after the mission's 5 s: give --duration >= 57.6" in text
    assert "Traceback" not in result.output and not (tmp_path / "sim").exists()
    # and the shared check itself, as covswarm run calls it with its effective duration
    scenario = load_scenario(path)
    with pytest.raises(ValueError, match=r"give --duration >= 57\.6 or fewer goals"):
        check_broadcastable(scenario, scenario.kappa, 5.0)
    check_broadcastable(scenario, scenario.kappa, 60.0)


@pytest.mark.e2e  # were the check to let it through, covswarm run would start its router
def test_run_refuses_a_duration_option_ending_before_the_route(tmp_path) -> None:
    path = write(tmp_path, route_toml())
    args = ["run", "--scenario", str(path), "--duration", "5", "--out", str(tmp_path / "run")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert "the route ends at 57.5 s" in " ".join(result.output.split())
    assert not (tmp_path / "run" / "logs").exists()


# ------------------------------------------------------------------------ 2. the start box


@pytest.mark.parametrize(
    ("start", "named"),
    [
        ([-0.5, 0.5, -0.2, 0.2], r"touches 'obstacle 1' \(\[-0.3, 0.3\] x \[-1, 1\] m\)"),
        ([-0.35, -0.3, -1.2, -0.9], "touches 'obstacle 1'"),  # a corner on the wall's
        ([2.0, 3.0, -0.5, 0.5], r"leaves the workspace \[-2.591, 2.591\]"),
    ],
)
def test_a_start_box_in_an_obstacle_or_outside_the_workspace_is_refused(
    tmp_path, start, named
) -> None:
    body = keyframes_text(f"workspace = {ARENA}\nobstacles = [{WALL}]\n[initial]\nbox = {start}")
    with pytest.raises(ValueError, match=named) as info:
        load_scenario(write(tmp_path, body))
    message = str(info.value)
    one_line(message)
    assert "the initial box" in message and "drop it to start the robots inside S(0)" in message


def test_a_start_box_clear_of_the_wall_places_every_body_clear(tmp_path) -> None:
    start = [-2.4, -0.4, -1.6, 1.6]  # left of the wall, 0.1 m from it
    body = keyframes_text(f"workspace = {ARENA}\nobstacles = [{WALL}]\n[initial]\nbox = {start}")
    scenario = load_scenario(write(tmp_path, body))
    wall = box(WALL[0], WALL[2], WALL[1], WALL[3])
    for p in scenario.initial_positions(30, seed=3):
        assert wall.distance(Point(p)) > 0.09
    # the same refusal for a scenario built in code
    with pytest.raises(ValueError, match="touches 'obstacle 1'"):
        Scenario(
            name="in-code",
            motion=Keyframes(times=np.array([0.0]), vertices=np.array([LEFT])),
            workspace=tuple(ARENA),
            obstacles=(tuple(WALL),),
            initial_box=(-0.4, 0.0, 0.0, 0.5),
        )


# ----------------------------------------------------------------- 3. maps too fine to send


def write_map(folder: Path, grey: np.ndarray, name: str = "lab", origin=(-1.0, -1.0)) -> Path:
    Image.fromarray(grey.astype(np.uint8), mode="L").save(folder / f"{name}.pgm")
    yaml = folder / f"{name}.yaml"
    yaml.write_text(
        f"image: {name}.pgm\nresolution: 0.05\norigin: [{origin[0]}, {origin[1]}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        encoding="utf-8",
    )
    return yaml


def test_count_rectangles_is_the_covers_length_across_blocks() -> None:
    rng = np.random.default_rng(11)
    for shape in ((1, 1), (1, 9), (9, 1), (7, 13), (60, 80)):
        for density in (0.0, 0.05, 0.3, 0.7, 0.95, 1.0):
            grid = rng.random(shape) < density
            expect = len(cover_rectangles(grid))
            for block_cells in (1, 17, 1 << 22):  # a row a block, a few, all at once
                assert count_rectangles(grid, block_cells) == expect
    stripes = np.zeros((40, 30), bool)
    stripes[:, 3:5] = stripes[10:30, 20:29] = True
    assert count_rectangles(stripes, 1) == len(cover_rectangles(stripes)) == 2


def test_a_speckled_map_is_refused_in_seconds_saying_what_to_do(tmp_path) -> None:
    rng = np.random.default_rng(2)
    grey = np.where(rng.random((2000, 2000)) < 0.02, OCC, FREE)  # 2 % speckle
    grey[990:1010, 990:1010] = FREE  # round S, at (0, 0): only the map is wrong
    write_map(tmp_path, grey, origin=(-50.0, -50.0))
    path = write(
        tmp_path,
        'name = "speckle"\nmap = "lab.yaml"\nduration = 2.0\n\n[domain]\nkind = "keyframes"\n'
        "times = [0.0]\nvertices = [[[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]]]\n",
    )
    started = time.monotonic()
    errors = value_errors_within(load_scenario, path, seconds=20.0)
    elapsed = time.monotonic() - started
    assert errors, "not refused within 20 s"
    message = str(errors[0])
    one_line(message)
    count = len(cover_rectangles(grey[::-1] != FREE))
    assert f"lab.yaml: {count} occupied rectangles, at most 4096 fit a World message" in message
    assert "clean speckle" in message and "coarser resolution" in message
    assert elapsed < 10.0, elapsed


def _dotted_map_scenario(tmp_path: Path, boxes: int) -> Path:
    """A 10 m x 10 m map of 4000 isolated occupied pixels (4000 pieces: within a World
    message's 4096 alone) and a file adding ``boxes`` small boxes of its own."""
    grey = np.full((200, 200), FREE)
    grey[0:160:2, 0:100:2] = OCC  # 80 x 50 dots, the map's upper left
    write_map(tmp_path, grey, origin=(-5.0, -5.0))
    entries = ", ".join(
        f"[{1 + 0.03 * i:.2f}, {1.01 + 0.03 * i:.2f}, 2.0, 2.01]" for i in range(boxes)
    )
    still = [[2.0, -4.0], [3.0, -4.0], [3.0, -3.0], [2.0, -3.0]]
    return write(tmp_path, keyframes_text(f'map = "lab.yaml"\nobstacles = [{entries}]\n', still))


def test_the_files_obstacles_and_the_maps_pieces_are_counted_together(tmp_path) -> None:
    """4000 map pieces and 97 boxes of the file: over the 4096 a World message carries,
    refused at load in one line naming both counts (not later by check_broadcastable);
    with 96 boxes the 4096 obstacles load and broadcast."""
    path = _dotted_map_scenario(tmp_path, 97)
    started = time.monotonic()
    with pytest.raises(ValueError) as refused:
        load_scenario(path)
    assert time.monotonic() - started < 5.0  # counted, not built
    message = str(refused.value)
    one_line(message)
    assert "4000 occupied rectangles and the scenario's 97 other obstacles make 4097" in message
    assert "at most 4096 fit a World message" in message
    assert "give fewer obstacles" in message and "coarser resolution" in message
    scenario = load_scenario(_dotted_map_scenario(tmp_path, 96))
    assert len(scenario.world.obstacles) == 4096
    check_broadcastable(scenario, scenario.kappa, scenario.duration)


def test_a_file_of_more_obstacles_than_a_world_message_is_refused_at_load(tmp_path) -> None:
    entries = ", ".join(
        f"[{0.01 * i:.2f}, {0.01 * i + 0.005:.3f}, 1.0, 1.005]" for i in range(4097)
    )
    with pytest.raises(ValueError) as refused:
        load_scenario(write(tmp_path, keyframes_text(f"obstacles = [{entries}]\n")))
    message = str(refused.value)
    one_line(message)
    assert "obstacles: 4097 entries, at most 4096 fit a World message" in message
    assert "give fewer obstacles" in message


def test_a_noise_map_of_16_million_pixels_is_refused_in_seconds(tmp_path) -> None:
    rng = np.random.default_rng(3)
    grey = np.where(rng.random((4000, 4000)) < 0.5, OCC, FREE)
    yaml = write_map(tmp_path, grey)
    errors = value_errors_within(lambda path: read_map(path).obstacles(), yaml, seconds=30.0)
    assert errors, "not refused within 30 s"  # it took over 300 s building pieces
    assert "occupied rectangles, at most 4096 fit a World message" in str(errors[0])


def test_sim_says_what_run_could_not_send_not_that_it_broadcasts(tmp_path) -> None:
    many = [[x * 0.01, x * 0.01 + 0.005, 0.0, 0.005] for x in range(4100)]
    scenario = Scenario(
        name="crowded",
        motion=Keyframes(times=np.array([0.0]), vertices=np.array([LEFT])),
        world=None,
        workspace=(-3.0, 45.0, -1.0, 1.0),
        obstacles=tuple(tuple(b) for b in many),
    )
    with pytest.raises(ValueError) as info:
        check_broadcastable(scenario, 2.0, 10.0)
    message = str(info.value)
    one_line(message)
    assert "its world does not fit a World message" in message
    assert "4100 obstacles, at most 4096" in message and "covswarm run could not send" in message
    assert "broadcast to the agents" not in message


# ------------------------------------------------------------ 4. a workspace beyond the map


def test_a_workspace_reaching_beyond_the_map_is_refused_naming_both(tmp_path) -> None:
    write_map(tmp_path, np.full((40, 40), FREE))  # x, y in [-1, 1]
    small = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
    wide = keyframes_text('map = "lab.yaml"\nworkspace = [-2.0, 2.0, -1.0, 1.0]', small)
    with pytest.raises(ValueError) as info:
        load_scenario(write(tmp_path, wide))
    message = str(info.value)
    one_line(message)
    assert "workspace [-2, 2] x [-1, 1] m reaches beyond the map" in message
    assert "lab.yaml ([-1, 1] x [-1, 1] m)" in message and "within the map" in message
    with pytest.raises(ValueError, match="reaches beyond the map"):
        world_from_map(tmp_path / "lab.yaml", (-1.0, 1.0, -1.0, 1.5))
    # within the map (its edge up to rounding), or none: the map's extent
    inside = keyframes_text(
        f'map = "lab.yaml"\nworkspace = [-0.9, {1.0 + EDGE_TOLERANCE / 2}, -1.0, 1.0]', small
    )
    assert load_scenario(write(tmp_path, inside, "in.toml")).workspace[0] == -0.9
    none = keyframes_text('map = "lab.yaml"', small)
    assert load_scenario(write(tmp_path, none, "none.toml")).workspace == (-1.0, 1.0, -1.0, 1.0)


# --------------------------------------------------- 5. an obstacle wholly outside the room


def test_an_obstacle_wholly_outside_the_workspace_is_refused_naming_it(tmp_path) -> None:
    typo = f"workspace = {ARENA}\nobstacles = [{WALL}, [[30.0, 1.0], [31.0, 1.0], [30.5, 2.0]]]"
    with pytest.raises(ValueError) as info:
        load_scenario(write(tmp_path, keyframes_text(typo)))
    message = str(info.value)
    one_line(message)
    assert "obstacle 2 ([30, 31] x [1, 2] m) lies wholly outside the workspace" in message
    # a wall crossing the workspace's edge, or one resting on it from outside, is kept
    crossing = f"workspace = {ARENA}\nobstacles = [[2.4, 3.0, -0.2, 0.2], [-3.0, -2.591, 1, 2]]"
    scenario = load_scenario(write(tmp_path, keyframes_text(crossing), "ok.toml"))
    assert len(scenario.world.obstacles) == 2
    # with a map and no workspace, the map's extent is the workspace it is checked against
    write_map(tmp_path, np.full((40, 40), FREE))
    small = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
    far = keyframes_text('map = "lab.yaml"\nobstacles = [[5.0, 6.0, 0.0, 1.0]]', small)
    with pytest.raises(ValueError, match="obstacle 1 .* lies wholly outside"):
        load_scenario(write(tmp_path, far, "far.toml"))


# ------------------------------------------------------- 6. and 7. the map's files themselves


def test_a_yaml_syntax_error_is_one_line_with_file_line_and_column(tmp_path) -> None:
    (tmp_path / "lab.yaml").write_text("image: lab.pgm\n  resolution: 0.05\n", encoding="utf-8")
    path = write(tmp_path, keyframes_text('map = "lab.yaml"'))
    with pytest.raises(ValueError) as info:
        load_scenario(path)
    message = str(info.value)
    one_line(message)
    assert f"map: {tmp_path / 'lab.yaml'}: not YAML: line 2, column 13: " in message
    assert "mapping values are not allowed here" in message and "unicode string" not in message


@pytest.mark.parametrize("kind", ["png I;16", "pgm 16-bit"])
def test_a_16_bit_image_is_refused_saying_to_save_it_with_8_bits(tmp_path, kind) -> None:
    if kind == "png I;16":
        Image.new("I;16", (4, 4), 300).save(tmp_path / "deep.png")
        image = "deep.png"
    else:  # P5 with maxval 65535: two bytes a pixel
        (tmp_path / "deep.pgm").write_bytes(b"P5\n4 4\n65535\n" + b"\xff\xff" * 16)
        image = "deep.pgm"
    (tmp_path / "deep.yaml").write_text(
        f"image: {image}\nresolution: 0.05\norigin: [0, 0, 0]\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n",
        encoding="utf-8",
    )
    with pytest.raises(ValueError) as info:
        read_map(tmp_path / "deep.yaml")
    message = str(info.value)
    one_line(message)
    assert f"{image}: not an 8-bit image (mode I" in message and "8 bits a channel" in message
    # and docs/world.md no longer lists 16-bit among what is read
    doc = " ".join((ROOT / "docs" / "world.md").read_text(encoding="utf-8").split())
    assert "palette, 16-bit" not in doc and "16-bit images are refused" in doc
