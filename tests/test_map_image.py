"""The occupancy map's picture: world.map_image against the map it draws (decoded back with
Pillow and read at world coordinates: origin, row flip, resolution, downsampling), the
strict protocol.MapImage, and the coordinator core's answer to a map query."""

from __future__ import annotations

import io
import math
from pathlib import Path

import msgpack
import numpy as np
import pytest
from PIL import Image

from covswarm.coordinator.core import CoordinatorCore, CoordinatorSettings
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import MapImage, ProtocolError
from covswarm.protocol.messages import MAX_MAP_PAYLOAD, MAX_MAP_PNG, MAX_MAP_SIDE, png_size
from covswarm.world.map_image import downsample, map_image
from covswarm.world.maps import OccupancyMap, read_map

SCENARIOS = Path(__file__).parents[1] / "scenarios"


def grid(occupied: np.ndarray, origin=(0.0, 0.0), resolution=0.05) -> OccupancyMap:
    return OccupancyMap(Path("test.yaml"), np.asarray(occupied, dtype=bool), resolution, origin)


def picture(message: MapImage) -> np.ndarray:
    """(height, width) bool, True where the PNG is black (occupied), row 0 the top."""
    with Image.open(io.BytesIO(message.png)) as image:
        assert image.size == (message.width, message.height)
        return np.asarray(image.convert("L")) < 128


def black_at(message: MapImage, x: float, y: float) -> bool:
    """Whether the picture is black at world point (x, y) m: read where the message says
    that point is (origin: lower-left corner; row 0 the top)."""
    x0, y0 = message.origin
    col = math.floor((x - x0) / message.resolution)
    row = message.height - 1 - math.floor((y - y0) / message.resolution)
    return bool(picture(message)[row, col])


def occupied_at(occupancy: OccupancyMap, x: float, y: float) -> bool:
    """The map's own answer at (x, y): cell (i, j) spans origin + [j, j+1] h, [i, i+1] h."""
    x0, y0 = occupancy.origin
    i = math.floor((y - y0) / occupancy.resolution)
    j = math.floor((x - x0) / occupancy.resolution)
    return bool(occupancy.occupied[i, j])


def test_the_picture_is_the_maps_occupancy_at_every_world_point() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        rows, cols = rng.integers(1, 90, size=2)
        occupancy = grid(
            rng.random((rows, cols)) < rng.uniform(0.05, 0.6),
            origin=tuple(rng.uniform(-20.0, 20.0, size=2).round(3)),
            resolution=float(rng.choice([0.02, 0.05, 0.1, 0.25])),
        )
        message = MapImage.decode(map_image(occupancy, seq=4).encode())
        assert message.seq == 4 and message.origin == pytest.approx(occupancy.origin)
        assert (message.width, message.height, message.resolution) == (
            cols, rows, occupancy.resolution
        )  # fmt: skip
        xmin, xmax, ymin, ymax = occupancy.extent
        # Cell centres and random points (away from cell edges, where rounding decides).
        h = occupancy.resolution
        for _ in range(200):
            j, i = rng.integers(cols), rng.integers(rows)
            x, y = (
                xmin + (j + rng.uniform(0.05, 0.95)) * h,
                ymin + (i + rng.uniform(0.05, 0.95)) * h,
            )
            assert black_at(message, x, y) == occupied_at(occupancy, x, y), (x, y)


def test_the_lab_maps_picture_has_its_walls_where_the_map_has_them() -> None:
    lab = read_map(SCENARIOS / "lab.yaml")
    message = map_image(lab)
    assert (message.width, message.height, message.resolution) == (200, 120, 0.05)
    assert message.origin == (-5.0, -3.0) and len(message.encode()) < 1000
    # The bench at x in [-4.6, -2.2], y in [2.0, 2.6] (scripts/make_lab_map.py): black; the
    # same point mirrored to y < 0 is free floor (a picture drawn upside down would fail).
    assert black_at(message, -3.0, 2.3) and not black_at(message, -3.0, -2.3)
    assert black_at(message, 0.0, -1.5) and not black_at(message, 0.0, 0.2)  # wall, door


def test_a_large_map_is_downsampled_keeping_every_wall() -> None:
    rng = np.random.default_rng(5)
    occupied = np.zeros((301, 517), dtype=bool)
    occupied[rng.integers(301, size=60), rng.integers(517, size=60)] = True  # specks
    occupied[100:103, :] = True  # a wall
    occupancy = grid(occupied, origin=(-3.0, 1.5), resolution=0.05)
    message = map_image(occupancy, max_side=100)
    factor = 6  # ceil(517 / 100)
    assert message.resolution == pytest.approx(0.05 * factor)
    assert (message.width, message.height) == (math.ceil(517 / 6), math.ceil(301 / 6))
    assert message.origin == (-3.0, 1.5)
    black = picture(message)
    # Brute force: every source cell, through world coordinates.
    for i in range(301):
        for j in range(517):
            if occupied[i, j]:
                x, y = -3.0 + (j + 0.5) * 0.05, 1.5 + (i + 0.5) * 0.05
                assert black_at(message, x, y), (i, j)
    # A white pixel has no occupied cell under it.
    for row, col in zip(*np.nonzero(~black), strict=True):
        i0, j0 = (message.height - 1 - row) * factor, col * factor
        assert not occupied[i0 : i0 + factor, j0 : j0 + factor].any(), (row, col)
    # Past the map's edge (padding up to a whole pixel) counts as occupied, like unknown.
    assert black[0, -1]


def test_downsample_against_a_loop() -> None:
    rng = np.random.default_rng(11)
    for _ in range(30):
        occupied = rng.random(rng.integers(1, 40, size=2)) < 0.1
        f = int(rng.integers(1, 7))
        out = downsample(occupied, f)
        rows, cols = occupied.shape
        for r in range(out.shape[0]):
            for c in range(out.shape[1]):
                block = occupied[r * f : (r + 1) * f, c * f : (c + 1) * f]
                partial = block.shape != (f, f)
                assert out[r, c] == (block.any() or partial)
    with pytest.raises(ValueError):
        downsample(np.zeros((3, 3), dtype=bool), 0)
    with pytest.raises(ValueError):
        downsample(np.zeros(3, dtype=bool), 2)


def test_the_worst_map_stays_under_the_size_limit() -> None:
    # Noise compresses worst: fair coin flips at the largest side, and a larger map whose
    # downsampled cells are still noise.
    rng = np.random.default_rng(2)
    for noise in (rng.random((1024, 1024)) < 0.5, rng.random((2500, 1800)) < 0.05):
        message = map_image(grid(noise, resolution=0.05))
        assert max(message.width, message.height) <= MAX_MAP_SIDE
        assert len(message.png) <= MAX_MAP_PNG and len(message.encode()) <= MAX_MAP_PAYLOAD
        print(f"{noise.shape} noise map: {len(message.png)} bytes of PNG")


# -- protocol.MapImage ------------------------------------------------------------------------


def good_fields() -> dict:
    message = map_image(grid(np.eye(4, 6, dtype=bool), origin=(1.0, -2.0), resolution=0.1))
    return {"seq": 0, "origin": [1.0, -2.0], "resolution": 0.1, "width": 6, "height": 4,
            "png": message.png}  # fmt: skip


def wire(**changes) -> bytes:
    fields = {"v": 1, **good_fields(), **changes}
    return msgpack.packb({k: v for k, v in fields.items() if v is not ...}, use_bin_type=True)


def test_a_map_image_round_trips() -> None:
    message = MapImage.decode(wire())
    assert message.extent == pytest.approx((1.0, 1.6, -2.0, -1.6))
    assert MapImage.decode(message.encode()) == message
    assert png_size(message.png) == (6, 4)


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"v": 2}, "version"),
        ({"extra": 1}, "schema"),
        ({"png": ...}, "schema"),
        ({"origin": ...}, "schema"),
        ({"png": b"GIF89a" + b"\0" * 40}, "value"),  # not a PNG
        ({"png": "text"}, "value"),
        ({"png": b"\x89PNG\r\n\x1a\n"}, "value"),  # cut short
        ({"width": 7}, "value"),  # not what the PNG's header says
        ({"height": 0}, "value"),
        ({"width": MAX_MAP_SIDE + 1}, "value"),
        ({"width": 6.0}, "value"),
        ({"resolution": 0.0}, "value"),
        ({"resolution": -0.1}, "value"),
        ({"resolution": float("nan")}, "nonfinite"),
        ({"origin": [1.0]}, "value"),
        ({"origin": [1.0, True]}, "value"),
        ({"origin": [9999.9, 0.0]}, "value"),  # the map reaches past MAX_COORD
        ({"seq": -1}, "value"),
        ({"png": b"\x89PNG" + b"\0" * MAX_MAP_PNG}, "oversize"),
    ],
)
def test_malformed_map_images_are_refused(changes: dict, reason: str) -> None:
    with pytest.raises(ProtocolError) as caught:
        MapImage.decode(wire(**changes))
    assert caught.value.reason == reason, caught.value


def test_a_payload_over_the_limit_is_refused_before_unpacking() -> None:
    with pytest.raises(ProtocolError) as caught:
        MapImage.decode(b"\0" * (MAX_MAP_PAYLOAD + 1))
    assert caught.value.reason == "oversize"


# -- the coordinator's answer ----------------------------------------------------------------


def core_of(name: str) -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=load_scenario(name), swarm="map-test", agents=3, duration=10.0, kappa=2.0,
        rate=20.0, sample_rate=10.0, feedforward=True, tile_size=0.5,
    )  # fmt: skip
    return CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)


def test_the_coordinator_answers_with_its_scenarios_map() -> None:
    core = core_of(str(SCENARIOS / "lab-route.toml"))
    message = MapImage.decode(core.map_payload)
    assert message == map_image(read_map(SCENARIOS / "lab.yaml"))
    assert message.seq == core.world_message().seq
    assert core_of("warehouse").map_payload is None  # boxes only: no picture
