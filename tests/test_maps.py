"""world.maps: map_server YAML + image, the rectangle cover, and each refusal."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hang_checks import value_errors_within
from PIL import Image
from shapely.geometry import Point, Polygon

from covswarm.world.maps import cover_rectangles, read_map, world_from_map

FREE, OCC, UNKNOWN = 254, 0, 205


def write_map(folder: Path, grey: np.ndarray, *, image: str = "lab.pgm", **meta) -> Path:
    """Save grey as ``image`` and a YAML naming it (``meta`` overrides or, as None, drops keys)."""
    Image.fromarray(grey.astype(np.uint8), mode="L").save(folder / image)
    fields = {
        "image": image,
        "resolution": 0.05,
        "origin": "[-1.0, -2.0, 0.0]",
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        **meta,
    }
    text = "".join(f"{k}: {v}\n" for k, v in fields.items() if v is not None)
    (folder / "lab.yaml").write_text(text)
    return folder / "lab.yaml"


def rasterise(rectangles, shape) -> np.ndarray:
    grid = np.zeros(shape, dtype=int)
    for r0, r1, c0, c1 in rectangles:
        grid[r0:r1, c0:c1] += 1
    return grid


def test_rectangle_cover_is_exact_and_disjoint_on_random_grids() -> None:
    rng = np.random.default_rng(0)
    for density in (0.05, 0.3, 0.7, 0.95):
        grid = rng.random((60, 80)) < density
        counts = rasterise(cover_rectangles(grid), grid.shape)
        np.testing.assert_array_equal(counts, grid.astype(int))  # once each, nothing else
    assert cover_rectangles(np.zeros((5, 5), bool)) == []
    assert cover_rectangles(np.ones((5, 5), bool)) == [(0, 5, 0, 5)]


def test_a_pixel_lands_at_the_right_place(tmp_path: Path) -> None:
    grey = np.full((40, 60), FREE)
    grey[0, 0] = OCC  # top-left pixel of the image
    grey[39, 59] = OCC  # bottom-right
    grid = read_map(write_map(tmp_path, grey))
    assert grid.extent == pytest.approx((-1.0, 2.0, -2.0, 0.0))
    world = world_from_map(tmp_path / "lab.yaml")
    assert world.workspace == pytest.approx((-1.0, 2.0, -2.0, 0.0))
    boxes = sorted(o.box for o in world.obstacles)
    # top-left: x in [-1, -0.95], y in [-0.05, 0]; bottom-right: x in [1.95, 2], y in [-2, -1.95]
    assert boxes[0] == pytest.approx((-1.0, -0.95, -0.05, 0.0))
    assert boxes[1] == pytest.approx((1.95, 2.0, -2.0, -1.95))
    assert world.clearance(np.array([[-0.975, -0.025]]))[0] < 0.0
    assert world.clearance(np.array([[-0.975, -1.975]]))[0] > 0.0


def test_wall_map_has_few_pieces_covering_the_occupied_cells(tmp_path: Path) -> None:
    grey = np.full((200, 300), FREE)
    grey[:, :3] = grey[:, -3:] = grey[:3, :] = grey[-3:, :] = OCC  # outer walls
    grey[50:200, 140:146] = OCC  # a wall with a door at the top
    grey[80:120, 40:70] = UNKNOWN  # never seen: not free
    world = world_from_map(write_map(tmp_path, grey))
    assert len(world.obstacles) <= 8
    names = {o.name for o in world.obstacles}
    assert "map piece 1" in names
    # rasterise the pieces back at cell centres and compare with the image
    rows, cols = grey.shape
    jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
    centres = np.stack([-1.0 + (jj + 0.5) * 0.05, -2.0 + (rows - 1 - ii + 0.5) * 0.05], -1)
    inside = world.clearance(centres.reshape(-1, 2)).reshape(rows, cols) < 0.0
    # the workspace is the map's extent, so only obstacles make clearance negative
    np.testing.assert_array_equal(inside, grey != FREE)


def test_pgm_written_by_hand_png_negate_and_colour(tmp_path: Path) -> None:
    pixels = bytes([0, 254, 254, 254, 254, 254])  # 3 x 2, top-left occupied
    (tmp_path / "hand.pgm").write_bytes(b"P5\n# made by hand\n3 2\n255\n" + pixels)
    (tmp_path / "lab.yaml").write_text(
        "image: hand.pgm\nresolution: 1.0\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    grid = read_map(tmp_path / "lab.yaml")
    np.testing.assert_array_equal(grid.occupied, [[False, False, False], [True, False, False]])
    # negate: white is occupied
    grey = np.full((4, 4), 0)
    grey[1, 2] = 255
    grid = read_map(write_map(tmp_path, grey, image="neg.png", negate=1))
    expect = np.zeros((4, 4), bool)
    expect[2, 2] = True  # image row 1 from the top is row 2 from the bottom
    np.testing.assert_array_equal(grid.occupied, expect)
    # colour averaged to grey: (255, 255, 240) is free, (200, 0, 0) occupied
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[...] = (255, 255, 240)
    rgb[0, 1] = (200, 0, 0)
    Image.fromarray(rgb, mode="RGB").save(tmp_path / "colour.png")
    (tmp_path / "c.yaml").write_text(
        "image: colour.png\nresolution: 0.1\norigin: [0, 0, 0]\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.25\n"
    )
    np.testing.assert_array_equal(read_map(tmp_path / "c.yaml").occupied, [[0, 0], [0, 1]])


def test_unknown_and_thresholds(tmp_path: Path) -> None:
    grey = np.array([[0, 100, 150, 205, 230, 254]])
    # p = (255 - x) / 255: 1.0, 0.61, 0.41, 0.196, 0.098, 0.004
    grid = read_map(write_map(tmp_path, grey, free_thresh=0.3))
    np.testing.assert_array_equal(grid.occupied, [[1, 1, 1, 0, 0, 0]])
    grid = read_map(write_map(tmp_path, np.array([[0, 50, 101, 255]]), mode="raw"))
    np.testing.assert_array_equal(grid.occupied, [[0, 1, 1, 1]])  # > 100: unknown


def test_map_world_against_shapely_points(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    grey = np.where(rng.random((30, 40)) < 0.2, OCC, FREE)
    world = world_from_map(write_map(tmp_path, grey))
    union = [Polygon(o.vertices) for o in world.obstacles]
    for p in rng.uniform([-1, -2], [1, -0.5], size=(200, 2)):
        row = 29 - int((p[1] + 2.0) / 0.05)
        col = int((p[0] + 1.0) / 0.05)
        assert any(u.contains(Point(p)) for u in union) == (grey[row, col] == OCC)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"resolution": 0}, "resolution must be > 0"),
        ({"resolution": "fine"}, "resolution must be a number"),
        ({"resolution": ".nan"}, "resolution must be finite"),
        ({"origin": "[0, 0]"}, r"origin must be \[x, y, yaw\]"),
        ({"origin": "[0, 0, 0.5]"}, "yaw"),
        ({"occupied_thresh": 1.5}, r"occupied_thresh must be in \[0, 1\]"),
        ({"free_thresh": 0.7}, "must be below occupied_thresh"),
        ({"negate": 2}, "negate must be 0 or 1"),
        ({"mode": "fancy"}, "mode must be"),
        ({"resolution": None}, "missing keys"),
        ({"colour": "red"}, "unknown keys"),
    ],
)
def test_malformed_yaml_is_refused_with_file_and_reason(tmp_path: Path, change, reason) -> None:
    path = write_map(tmp_path, np.full((4, 4), FREE), **change)
    with pytest.raises(ValueError, match=reason) as info:
        read_map(path)
    assert str(path.parent) in str(info.value)


def test_bad_files_are_refused(tmp_path: Path) -> None:
    path = write_map(tmp_path, np.full((4, 4), FREE))
    (tmp_path / "lab.pgm").write_bytes(b"not an image at all")
    with pytest.raises(ValueError, match="lab.pgm: not a readable image"):
        read_map(path)
    Image.new("I;16", (4, 4), 300).save(tmp_path / "deep.png")
    path = write_map(tmp_path, np.full((4, 4), FREE))
    (tmp_path / "lab.yaml").write_text(
        path.read_text().replace("image: lab.pgm", "image: deep.png")
    )
    with pytest.raises(ValueError, match="not an 8-bit image"):
        read_map(path)
    (tmp_path / "lab.yaml").write_text(
        path.read_text().replace("image: deep.png", "image: nothere.pgm")
    )
    with pytest.raises(ValueError, match="nothere.pgm: cannot read"):
        read_map(path)
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match="list.yaml: the YAML must be a mapping"):
        read_map(tmp_path / "list.yaml")
    (tmp_path / "broken.yaml").write_text("image: [unclosed\n")
    with pytest.raises(ValueError, match="broken.yaml: not YAML: line 2, column 1: ") as info:
        read_map(tmp_path / "broken.yaml")
    assert "\n" not in str(info.value) and "unicode string" not in str(info.value)
    (tmp_path / "big.yaml").write_bytes(b"#" * (2 << 20))
    with pytest.raises(ValueError, match="more than the"):
        read_map(tmp_path / "big.yaml")
    with pytest.raises(ValueError, match="not a regular file"):
        read_map(Path("/dev/zero"))
    with pytest.raises(ValueError, match="not a regular file"):
        read_map(tmp_path)


def test_fifo_does_not_hang(tmp_path: Path) -> None:
    fifo = tmp_path / "lab.yaml"
    os.mkfifo(fifo)
    done = value_errors_within(read_map, fifo)
    assert done and "not a regular file" in str(done[0])
    # the image may be a FIFO too
    path = write_map(tmp_path / "..", np.full((2, 2), FREE), image="pipe.pgm")
    (tmp_path / ".." / "pipe.pgm").unlink()
    os.mkfifo(tmp_path / ".." / "pipe.pgm")
    with pytest.raises(ValueError, match="not a regular file"):
        read_map(path)
