"""Every obstacle of the world, whatever its shape, in a run's outputs: trajectories.png
(``covswarm sim`` and the coordinator's), run.mcap (metadata ``obstacle_polygons`` and the
/arena scene) and ``covswarm replay``; a recording from before ``obstacle_polygons`` (its
metadata ``obstacles`` holds boxes) still replays with its boxes.

Drawn means painted: each figure is caught as it is closed and its pixels read at the
obstacles' insides (and at an empty point, which stays white).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.backends.backend_agg import FigureCanvasAgg
from mcap.reader import make_reader
from mcap.writer import Writer

from covswarm.coordinator import outputs
from covswarm.coordinator.config import CoordinatorConfig
from covswarm.coordinator.core import WAITING, CoordinatorCore, CoordinatorSettings
from covswarm.deploy.simulate import sim_command
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import Scenario
from covswarm.protocol import Pose, alive_key, pose_key
from covswarm.records.recorder import ARENA_TOPIC, MCAP_FILE, METADATA_NAME
from covswarm.records.replay import decoder_factories, obstacle_polygons, replay_command

BOX = [-0.2, 0.2, -2.5, -2.0]  # xmin, xmax, ymin, ymax
TRIANGLE = [[1.0, -1.5], [1.8, -1.5], [1.4, -0.8]]
INSIDE_BOX, INSIDE_TRIANGLE, EMPTY = (0.0, -2.25), (1.4, -1.25), (2.5, 0.0)
SCENARIO = f"""
name = "triangle"
agents = 3
duration = 1.0
workspace = [-3.0, 3.0, -3.0, 3.0]
obstacles = [{BOX}, {TRIANGLE}]

[domain]
kind = "rigid"
polygon = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
center = [-1.5, 1.5]
radius = 0.3
period = 50.0
"""
SWARM, WALL0 = "obstacle-test", 1.7e9


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scenario") / "triangle.toml"
    path.write_text(SCENARIO, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def scenario(scenario_file: Path) -> Scenario:
    return load_scenario(scenario_file)


@pytest.fixture(scope="module")
def sim_run(scenario_file: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """(the run folder of a short ``covswarm sim`` of the scenario, its trajectories figure)."""
    out = tmp_path_factory.mktemp("sim") / "triangle"
    with closed_figures() as figures:
        result = CliRunner().invoke(
            sim_command, ["--scenario", str(scenario_file), "--seed", "1", "--out", str(out)]
        )
    assert result.exit_code == 0, result.output
    (trajectories,) = [f for f in figures if f.axes[0].get_xlabel() == "x [m]"]
    return out, trajectories


@contextmanager
def closed_figures() -> Iterator[list[Any]]:
    """The figures pyplot closes inside the block, in order (closed, still drawable)."""
    figures: list[Any] = []
    close = plt.close

    def spy(fig: Any = None) -> None:
        figures.append(fig)
        close(fig)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plt, "close", spy)
        yield figures


def painted(fig: Any, point: tuple[float, float]) -> bool:
    """Whether the figure's first axes are painted red-brown (an obstacle's colours, tab:red
    in trajectories.png, brown in the replay) at ``point`` (m)."""
    canvas = FigureCanvasAgg(fig)  # a closed figure keeps no canvas of its own
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba()).astype(int)
    x, y = fig.axes[0].transData.transform(point)
    r, g, b = rgba[round(rgba.shape[0] - y), round(x), :3]
    return r - g > 20 and r - b > 20


def metadata_and_arena(path: Path) -> tuple[dict[str, Any], Any]:
    """(the run metadata, decoded from JSON; the first /arena SceneUpdate) of a run.mcap."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=decoder_factories())
        (raw,) = [m.metadata for m in reader.iter_metadata() if m.name == METADATA_NAME]
        arena = next(u for _, _, _, u in reader.iter_decoded_messages(topics=[ARENA_TOPIC]))
    return {k: _json_or_text(v) for k, v in raw.items()}, arena


def _json_or_text(value: str) -> Any:
    try:
        return json.loads(value)
    except ValueError:
        return value


def test_sim_plot_draws_every_obstacle(sim_run: tuple[Path, Any]) -> None:
    _, figure = sim_run
    assert painted(figure, INSIDE_TRIANGLE) and painted(figure, INSIDE_BOX)
    assert not painted(figure, EMPTY)


def test_sim_records_every_obstacle_as_a_polygon(
    sim_run: tuple[Path, Any], scenario: Scenario
) -> None:
    metadata, arena = metadata_and_arena(sim_run[0] / MCAP_FILE)
    world = [o.vertices for o in scenario.world.obstacles]
    assert len(world) == 2 and len(world[1]) == 3
    assert "obstacles" not in metadata  # one representation, the polygons
    recorded = metadata["obstacle_polygons"]
    assert len(recorded) == 2
    for got, want in zip(recorded, world, strict=True):
        np.testing.assert_allclose(got, want)
    np.testing.assert_allclose(
        sorted(map(tuple, recorded[1])), sorted(map(tuple, TRIANGLE)), atol=1e-12
    )
    # /arena: one entity per obstacle, its polygon filled as an indexed triangle fan.
    entities = {e.id: e for e in arena.entities}
    assert set(entities) == {"workspace", "obstacle/0", "obstacle/1"}
    for k, want in enumerate(world):
        (fill,) = entities[f"obstacle/{k}"].triangles
        points = np.array([[p.x, p.y] for p in fill.points])
        np.testing.assert_allclose(points, want)
        n = len(want)
        assert list(fill.indices) == [i for j in range(1, n - 1) for i in (0, j, j + 1)]
        assert not entities[f"obstacle/{k}"].cubes


def test_replay_draws_every_obstacle(sim_run: tuple[Path, Any]) -> None:
    out = sim_run[0]
    with closed_figures() as figures:
        result = CliRunner().invoke(replay_command, [str(out), "--fps", "2"])
    assert result.exit_code == 0, result.output
    (figure,) = figures
    assert painted(figure, INSIDE_TRIANGLE) and painted(figure, INSIDE_BOX)
    assert not painted(figure, EMPTY)


def rewrite_metadata(
    src: Path, dst: Path, change: Callable[[dict[str, str]], dict[str, str]]
) -> None:
    """Copy the MCAP file ``src`` to ``dst`` with its run metadata changed."""
    with src.open("rb") as stream, dst.open("wb") as sink:
        reader = make_reader(stream)
        summary = reader.get_summary()
        writer = Writer(sink)
        writer.start()
        schemas = {
            k: writer.register_schema(s.name, s.encoding, s.data)
            for k, s in summary.schemas.items()
        }
        channels = {
            k: writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0))
            for k, c in summary.channels.items()
        }
        for _, channel, message in reader.iter_messages(log_time_order=True):
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        for entry in reader.iter_metadata():
            data = change(dict(entry.metadata)) if entry.name == METADATA_NAME else entry.metadata
            writer.add_metadata(entry.name, data)
        writer.finish()


def test_replay_of_an_older_recording_draws_its_boxes(
    sim_run: tuple[Path, Any], tmp_path: Path
) -> None:
    """A run.mcap written before obstacle_polygons: metadata ``obstacles``, boxes only."""

    def old(metadata: dict[str, str]) -> dict[str, str]:
        del metadata["obstacle_polygons"]
        return {**metadata, "obstacles": json.dumps([BOX])}

    rewrite_metadata(sim_run[0] / MCAP_FILE, tmp_path / MCAP_FILE, old)
    with closed_figures() as figures:
        result = CliRunner().invoke(replay_command, [str(tmp_path), "--fps", "2"])
    assert result.exit_code == 0, result.output
    (figure,) = figures
    assert painted(figure, INSIDE_BOX) and not painted(figure, INSIDE_TRIANGLE)


def test_obstacle_polygons_of_both_metadata_formats() -> None:
    box = np.array([[-0.2, -2.5], [0.2, -2.5], [0.2, -2.0], [-0.2, -2.0]])
    (old,) = obstacle_polygons({"obstacles": [BOX]})
    np.testing.assert_allclose(old, box)
    new = obstacle_polygons({"obstacle_polygons": [box.tolist(), TRIANGLE], "obstacles": []})
    np.testing.assert_allclose(new[1], TRIANGLE)
    assert obstacle_polygons({}) == [] and obstacle_polygons({"obstacle_polygons": None}) == []


@pytest.fixture
def core(scenario: Scenario) -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=scenario, swarm=SWARM, agents=3, duration=1.0, kappa=2.0, rate=20.0,
        sample_rate=10.0, feedforward=True, tile_size=0.5,
    )  # fmt: skip
    return CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)


def test_run_outputs_draw_and_record_every_obstacle(
    core: CoordinatorCore, scenario: Scenario, tmp_path: Path
) -> None:
    """The coordinator's trajectories.png and its recorder get every obstacle."""
    for i in range(3):
        for role in ("robot", "agent"):
            core.on_liveliness(alive_key(SWARM, role, i), True, 0.0, WALL0)
    now = 0.0
    while core.phase.state == WAITING or now < 2.0:  # a second of mission past the start
        centre = scenario.domain(0.0)[0].mean(axis=0)
        for i, dx in enumerate((-0.2, 0.0, 0.2)):
            x, y = centre + (dx, 0.1 * i)
            core.on_pose(pose_key(SWARM, i), Pose(i, x, y, 0.0, WALL0 + now, 1).encode())
        core.tick(now, WALL0 + now)
        now = round(now + 0.05, 10)
    with closed_figures() as figures:
        outputs.write_run_outputs(tmp_path, core.settings, core.observed, core.steering)
    (figure,) = [f for f in figures if f.axes[0].get_xlabel() == "x [m]"]
    assert painted(figure, INSIDE_TRIANGLE) and painted(figure, INSIDE_BOX)

    config = CoordinatorConfig(swarm=SWARM, out=tmp_path)
    with outputs.open_recorder(config, core.settings) as recorder:
        recorder.poses(0.0, [0], np.zeros((1, 3)))
    metadata, arena = metadata_and_arena(tmp_path / MCAP_FILE)
    np.testing.assert_allclose(
        metadata["obstacle_polygons"][1], scenario.world.obstacles[1].vertices
    )
    assert len(arena.entities[2].triangles[0].points) == 3
