"""An occupancy map as the picture a console draws under the obstacles (protocol.MapImage).

The picture is 1-bit grey: black where the map is occupied (unknown cells included, as
covswarm.world.maps counts them), white where it is free; row 0 is the top (largest y), as
map_server's images and the browser's canvas have it. A map wider or taller than
MAX_MAP_SIDE pixels is downsampled by a whole factor f: a pixel is black when any of its
f x f cells is occupied, so no wall disappears, only thickens by less than a pixel; the
image is padded with occupied cells at the top and right to a multiple of f (the origin,
the lower-left corner, stays). 1 bit per pixel keeps the PNG under MAX_MAP_PNG whatever
the map: 1024 x 1024 pixels are 128 KiB before compression.
"""

from __future__ import annotations

import io
import math

import numpy as np

from covswarm.protocol.messages import MAX_MAP_PNG, MAX_MAP_SIDE, MapImage, ProtocolError
from covswarm.world.maps import OccupancyMap


def downsample(occupied: np.ndarray, factor: int) -> np.ndarray:
    """(rows, cols) bool -> (ceil(rows / f), ceil(cols / f)) bool, each cell occupied when
    any of its f x f source cells is (cells past the grid's top and right count occupied).
    Rows stay bottom-up, as in OccupancyMap."""
    grid = np.asarray(occupied, dtype=bool)
    if grid.ndim != 2:
        raise ValueError(f"occupancy grid must be 2-D, got shape {grid.shape}")
    if factor < 1:
        raise ValueError(f"downsampling factor must be >= 1, not {factor!r}")
    rows, cols = grid.shape
    out_rows, out_cols = -(-rows // factor), -(-cols // factor)
    padded = np.ones((out_rows * factor, out_cols * factor), dtype=bool)
    padded[:rows, :cols] = grid
    return padded.reshape(out_rows, factor, out_cols, factor).any(axis=(1, 3))


def map_image(grid: OccupancyMap, seq: int = 0, max_side: int = MAX_MAP_SIDE) -> MapImage:
    """The MapImage of ``grid`` (seq: the World's), downsampled to at most ``max_side``
    pixels a side. ValueError if the PNG still exceeds MAX_MAP_PNG (it cannot at 1 bit a
    pixel and the default side) or the map does not fit the message's bounds."""
    from PIL import Image

    rows, cols = grid.occupied.shape
    factor = max(1, math.ceil(max(rows, cols) / max_side))
    small = downsample(grid.occupied, factor)
    # Image rows run top-down: flip the bottom-up grid. White (1) is free.
    pixels = np.where(small[::-1], 0, 255).astype(np.uint8)
    buffer = io.BytesIO()
    bilevel = Image.fromarray(pixels, mode="L").convert("1", dither=Image.Dither.NONE)
    bilevel.save(buffer, format="PNG", optimize=True)
    png = buffer.getvalue()
    if len(png) > MAX_MAP_PNG:
        raise ValueError(f"{grid.path}: map picture of {len(png)} bytes, over {MAX_MAP_PNG}")
    height, width = pixels.shape
    try:
        return MapImage(
            seq=seq,
            origin=grid.origin,
            resolution=grid.resolution * factor,
            width=width,
            height=height,
            png=png,
        )
    except ProtocolError as exc:
        raise ValueError(f"{grid.path}: {exc}") from None
