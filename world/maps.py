"""Occupancy-grid maps as labs store them (ROS map_server / Nav2): a YAML file and an image.

YAML keys: ``image`` (path, absolute or relative to the YAML file), ``resolution`` (m per
pixel, > 0), ``origin`` ([x, y, yaw]: the world position of the lower-left corner of the
lower-left pixel; yaw must be 0: a rotated map is refused, rotate the image instead),
``occupied_thresh`` and ``free_thresh`` (in [0, 1], free < occupied), optional ``negate``
(0 or 1, default 0) and ``mode`` (``trinary`` default, ``scale``, ``raw``). Other keys are
refused (a typo must not pass silently).

The image: 8-bit grey, bilevel, palette or colour (colour channels averaged to grey; an alpha
channel is ignored), PGM or PNG or anything Pillow reads; 16-bit images are refused (save
the map with 8 bits a channel). Row 0 is the top of the map. A pixel of grey x has
occupancy p = (255 - x) / 255, or x / 255 when negated. trinary and
scale: p > occupied_thresh is occupied, p < free_thresh free, anything between unknown; raw:
x is the occupancy in percent (p = x / 100, 255 unknown). Unknown counts as occupied: S must
not be planned into space nobody has seen.

Occupied cells become few convex pieces: runs of occupied cells along each row, merged with
the identical runs of the rows above them into rectangles, so a straight wall is one
rectangle; the rectangles cover exactly the occupied cells, without overlapping. A map whose
cover has more rectangles than a World message carries (protocol MAX_OBSTACLES) is refused
when its obstacles are asked for, counted before any is built (count_rectangles), so a
noisy map is refused in a second rather than after minutes of building millions of pieces.
"""

from __future__ import annotations

import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from covswarm.protocol.messages import MAX_OBSTACLES
from covswarm.world.model import Box, Obstacle, World

MAX_YAML_BYTES = 1 << 20  # a map's YAML is a few lines
MAX_IMAGE_BYTES = 64 << 20
MAX_PIXELS = 64_000_000  # 8000 x 8000: 400 m a side at 5 cm
_KEYS = {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"}
_REQUIRED = {"image", "resolution", "origin", "occupied_thresh", "free_thresh"}
EDGE_TOLERANCE = 1e-6  # m: a workspace this close to the map's edge is inside it (rounding)
_BLOCK_CELLS = 1 << 22  # cells count_rectangles looks at at once (bounds its memory)


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A map read from disk. occupied: (rows, cols) bool, row 0 at the BOTTOM (y up), so cell
    (i, j) spans x in origin[0] + [j, j + 1] resolution, y in origin[1] + [i, i + 1]
    resolution (m). Unknown cells are occupied."""

    path: Path
    occupied: np.ndarray
    resolution: float
    origin: tuple[float, float]

    @property
    def extent(self) -> Box:
        """(xmin, xmax, ymin, ymax) of the whole map, m."""
        rows, cols = self.occupied.shape
        x0, y0 = self.origin
        return (x0, x0 + cols * self.resolution, y0, y0 + rows * self.resolution)

    def check_workspace(self, workspace: Box) -> None:
        """ValueError naming both rectangles unless ``workspace`` lies within the map's extent
        (to EDGE_TOLERANCE): space beyond the map's edge was never seen, yet has no pieces,
        so S would be planned through it as if it were free."""
        xmin, xmax, ymin, ymax = self.extent
        wx0, wx1, wy0, wy1 = workspace
        e = EDGE_TOLERANCE
        if wx0 < xmin - e or wx1 > xmax + e or wy0 < ymin - e or wy1 > ymax + e:
            raise ValueError(
                f"workspace [{wx0:g}, {wx1:g}] x [{wy0:g}, {wy1:g}] m reaches beyond the map "
                f"{self.path} ([{xmin:g}, {xmax:g}] x [{ymin:g}, {ymax:g}] m), space nobody "
                "has seen: give a workspace within the map, or none to use the map's extent"
            )

    def obstacles(
        self,
        prefix: str = "map piece",
        first: int = 1,
        limit: int = MAX_OBSTACLES,
        others: int = 0,
    ) -> tuple[Obstacle, ...]:
        """The occupied cells as rectangles (cover_rectangles), named "<prefix> <first + i>";
        ValueError naming the map and what to do if there are more than ``limit`` (counted
        first, in a fraction of a second, so none is built). others: obstacles the world
        holds besides the map's pieces (a scenario file's own ``obstacles``), which count
        against ``limit`` with them (the message names both counts)."""
        count = count_rectangles(self.occupied)
        if others and count + others > limit:
            raise ValueError(
                f"{self.path}: {count} occupied rectangles and the scenario's {others} other "
                f"obstacles make {count + others}, at most {limit} fit a World message: give "
                "fewer obstacles, or use a coarser resolution, clean speckle (isolated "
                "occupied pixels) or crop the map to the lab"
            )
        if count > limit:
            raise ValueError(
                f"{self.path}: {count} occupied rectangles, at most {limit} fit a World "
                "message: clean speckle (isolated occupied pixels), crop the map to the lab, "
                "or use a coarser resolution"
            )
        x0, y0 = self.origin
        h = self.resolution
        return tuple(
            Obstacle(
                f"{prefix} {first + n}",
                np.array(
                    [
                        [x0 + c0 * h, y0 + r0 * h],
                        [x0 + c1 * h, y0 + r0 * h],
                        [x0 + c1 * h, y0 + r1 * h],
                        [x0 + c0 * h, y0 + r1 * h],
                    ]
                ),
            )
            for n, (r0, r1, c0, c1) in enumerate(cover_rectangles(self.occupied))
        )


def cover_rectangles(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Disjoint rectangles (r0, r1, c0, c1), cells r0 <= i < r1, c0 <= j < c1, whose union is
    exactly the True cells of ``occupied`` (rows, cols): each row's runs of True cells, a run
    extended upward while the next row has the identical run."""
    grid = np.asarray(occupied, dtype=bool)
    if grid.ndim != 2:
        raise ValueError(f"occupancy grid must be 2-D, got shape {grid.shape}")
    rows, cols = grid.shape
    padded = np.zeros((rows, cols + 2), dtype=np.int8)
    padded[:, 1:-1] = grid
    changes = np.diff(padded, axis=1)  # +1 where a run starts, -1 one past where it ends
    open_runs: dict[tuple[int, int], int] = {}  # (c0, c1) -> first row
    rectangles: list[tuple[int, int, int, int]] = []
    for r in range(rows + 1):
        if r < rows:
            starts = np.flatnonzero(changes[r] == 1)
            ends = np.flatnonzero(changes[r] == -1)
            runs = set(zip(starts.tolist(), ends.tolist(), strict=True))
        else:
            runs = set()
        for run in [run for run in open_runs if run not in runs]:
            rectangles.append((open_runs.pop(run), r, run[0], run[1]))
        for run in runs:
            open_runs.setdefault(run, r)
    return rectangles


def count_rectangles(occupied: np.ndarray, block_cells: int = _BLOCK_CELLS) -> int:
    """len(cover_rectangles(occupied)) without building them, vectorised: every run of True
    cells along a row starts a rectangle unless the row below has the identical run. Rows
    are taken a block of about ``block_cells`` cells at a time (with the row before it)."""
    grid = np.asarray(occupied, dtype=bool)
    if grid.ndim != 2:
        raise ValueError(f"occupancy grid must be 2-D, got shape {grid.shape}")
    rows, cols = grid.shape
    width = cols + 1  # flat index of a change: row * width + column
    block = max(1, block_cells // (cols + 2))
    total = 0
    for a in range(0, rows, block):
        low = max(a - 1, 0)
        padded = np.zeros((min(a + block, rows) - low, cols + 2), dtype=np.int8)
        padded[:, 1:-1] = grid[low : a + block]
        changes = np.flatnonzero(np.diff(padded, axis=1))  # a row's runs start, end, ...
        starts, lengths = changes[0::2], changes[1::2] - changes[0::2]
        if len(starts) == 0:
            continue
        keys = starts * (cols + 2) + lengths  # increasing: runs in order, lengths <= cols
        own = starts >= (a - low) * width  # the block's rows (not the row before it)
        below = (starts[own] - width) * (cols + 2) + lengths[own]  # the same run a row down
        at = np.minimum(np.searchsorted(keys, below), len(keys) - 1)
        total += int(own.sum()) - int(np.count_nonzero(keys[at] == below))
    return total


def read_map(yaml_path: str | Path) -> OccupancyMap:
    """The map described by a map_server YAML file; ValueError naming the file and the reason
    for anything malformed (module docstring)."""
    path = Path(yaml_path)
    text = read_regular_file(path, MAX_YAML_BYTES).decode("utf-8", errors="replace")
    import yaml

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML: {_yaml_error(exc)}") from None
    try:
        meta = _metadata(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    image_path = Path(meta["image"])
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    grey = _read_grey(image_path)
    if meta["mode"] == "raw":
        p = grey.astype(float) / 100.0
        unknown = grey > 100
    else:
        p = grey.astype(float) / 255.0 if meta["negate"] else (255.0 - grey) / 255.0
        unknown = np.zeros(grey.shape, dtype=bool)
    free = (p < meta["free_thresh"]) & ~unknown
    return OccupancyMap(
        path=path,
        occupied=np.ascontiguousarray(~free[::-1]),  # image row 0 is the top: flip to y up
        resolution=meta["resolution"],
        origin=meta["origin"],
    )


def world_from_map(yaml_path: str | Path, workspace: Box | None = None) -> World:
    """A World of the map's occupied cells (few rectangles, "map piece N"), in ``workspace``
    (default: the map's extent; one reaching beyond it is refused: OccupancyMap.check_workspace)."""
    grid = read_map(yaml_path)
    if workspace is not None:
        grid.check_workspace(workspace)
    return World(grid.extent if workspace is None else workspace, grid.obstacles())


def _yaml_error(exc: Exception) -> str:
    """PyYAML's error in one line: where (line, column, from 1) and what, without its
    multi-line excerpt of the text."""
    mark, problem = getattr(exc, "problem_mark", None), getattr(exc, "problem", None)
    if mark is None or problem is None:
        return " ".join(str(exc).replace('in "<unicode string>", ', "").split())
    where = f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    context, begun = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if context and begun is not None:  # "while parsing a flow sequence" begun elsewhere
        context += f" begun at line {begun.line + 1}, column {begun.column + 1}"
    return " ".join((where + (f" ({context})" if context else "")).split())


def _metadata(data: Any) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError("the YAML must be a mapping of image, resolution, origin, ...")
    unknown = set(map(str, data)) - _KEYS
    if unknown:
        raise ValueError(f"unknown keys {sorted(unknown)}")
    missing = _REQUIRED - set(data)
    if missing:
        raise ValueError(f"missing keys {sorted(missing)}")
    image = data["image"]
    if not isinstance(image, str) or not image:
        raise ValueError(f"image must be a file name, not {image!r}")
    resolution = finite_number(data["resolution"], "resolution")
    if resolution <= 0.0:
        raise ValueError(f"resolution must be > 0 m per pixel, not {resolution!r}")
    origin = data["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise ValueError(f"origin must be [x, y, yaw], not {origin!r}")
    x, y, yaw = (finite_number(v, "origin") for v in origin)
    if yaw != 0.0:
        raise ValueError(f"origin yaw {yaw!r} is not supported: rotate the image instead")
    occupied, free = (finite_number(data[k], k) for k in ("occupied_thresh", "free_thresh"))
    for key, value in (("occupied_thresh", occupied), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"{key} must be in [0, 1], not {value!r}")
    if free >= occupied:
        raise ValueError(f"free_thresh {free!r} must be below occupied_thresh {occupied!r}")
    negate = data.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise ValueError(f"negate must be 0 or 1, not {negate!r}")
    mode = data.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise ValueError(f"mode must be trinary, scale or raw, not {mode!r}")
    return {
        "image": image,
        "resolution": resolution,
        "origin": (x, y),
        "occupied_thresh": occupied,
        "free_thresh": free,
        "negate": bool(negate),
        "mode": mode,
    }


def finite_number(value: Any, key: str) -> float:
    """``value`` as a float when it is a finite int or float (not a bool), else ValueError
    naming ``key`` (a file's field)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{key} must be a number, not {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{key} must be finite, not {value!r}")
    return float(value)


def read_regular_file(path: Path, limit: int) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes, or ValueError naming the file:
    stat first, so a FIFO or a device (/dev/zero) is refused without being opened."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"{path}: not a regular file")
    if info.st_size > limit:
        raise ValueError(f"{path}: {info.st_size} bytes, more than the {limit} allowed")
    try:
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    if len(data) > limit:
        raise ValueError(f"{path}: more than the {limit} bytes allowed")
    return data


def _read_grey(path: Path) -> np.ndarray:
    """(rows, cols) uint8 grey of an image file, row 0 the top; ValueError if unreadable."""
    import io

    from PIL import Image, UnidentifiedImageError

    data = read_regular_file(path, MAX_IMAGE_BYTES)
    try:
        with Image.open(io.BytesIO(data)) as image:
            width, height = image.size
            if width * height > MAX_PIXELS:
                raise ValueError(f"{path}: {width} x {height} pixels, more than {MAX_PIXELS}")
            if width == 0 or height == 0:
                raise ValueError(f"{path}: empty image")
            if image.mode not in ("1", "L", "LA", "P", "PA", "RGB", "RGBA"):
                raise ValueError(
                    f"{path}: not an 8-bit image (mode {image.mode}): save the map with "
                    "8 bits a channel (8-bit grey, as map_saver writes)"
                )
            if image.mode in ("P", "PA"):
                image = image.convert("RGBA")
            pixels = np.asarray(image)
    except UnidentifiedImageError:
        raise ValueError(
            f"{path}: not a readable image (not PGM, PNG or another format Pillow reads)"
        ) from None
    except (OSError, Image.DecompressionBombError) as exc:
        raise ValueError(f"{path}: not a readable image ({exc})") from None
    if pixels.dtype == bool:
        return np.where(pixels, 255, 0).astype(np.uint8)
    if pixels.ndim == 3:  # colour (and alpha): average the colour channels
        channels = pixels[..., :3] if pixels.shape[2] >= 3 else pixels[..., :1]
        return np.round(channels.astype(float).mean(axis=2)).astype(np.uint8)
    return pixels.astype(np.uint8)
