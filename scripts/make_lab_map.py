"""Write scenarios/lab.pgm and scenarios/lab.yaml: an example ROS map_server / Nav2 map.

A 10 m x 6 m lab at 5 cm per pixel: outer walls, a wall at x = 0 with a 1.2 m door between
the two rooms, benches along the walls and a pillar. Grey 0 is occupied, 254 free; a band
of unknown grey (205) outside the walls, as a SLAM map has. Run from the repository root:

    python scripts/make_lab_map.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RESOLUTION = 0.05  # m per pixel
ORIGIN = (-5.0, -3.0)  # m, the lower-left corner of the lower-left pixel
SIZE = (10.0, 6.0)  # m
FREE, OCCUPIED, UNKNOWN = 254, 0, 205
# Occupied boxes (xmin, xmax, ymin, ymax), m.
WALL = 0.15
DOOR = (-0.4, 0.8)  # y extent of the door in the middle wall, m
BOXES = [
    (-4.85, 4.85, -2.85, -2.85 + WALL),  # outer walls
    (-4.85, 4.85, 2.85 - WALL, 2.85),
    (-4.85, -4.85 + WALL, -2.85, 2.85),
    (4.85 - WALL, 4.85, -2.85, 2.85),
    (-0.1, 0.1, -2.85, DOOR[0]),  # middle wall and its door
    (-0.1, 0.1, DOOR[1], 2.85),
    (-4.6, -2.2, 2.0, 2.6),  # benches
    (-4.6, -3.8, -2.6, -0.8),
    (1.6, 4.6, -2.6, -2.0),
    (3.9, 4.6, 0.6, 2.6),
    (1.8, 2.2, 0.9, 1.3),  # a pillar
]


def render() -> np.ndarray:
    """(rows, cols) uint8 image, row 0 at the top (as map_server reads it)."""
    cols, rows = (round(s / RESOLUTION) for s in SIZE)
    x = ORIGIN[0] + RESOLUTION * (np.arange(cols) + 0.5)
    y = ORIGIN[1] + RESOLUTION * (np.arange(rows) + 0.5)
    image = np.full((rows, cols), FREE, dtype=np.uint8)
    outside = (np.abs(x)[None, :] > 4.85) | (np.abs(y)[:, None] > 2.85)
    image[outside] = UNKNOWN
    for xmin, xmax, ymin, ymax in BOXES:
        inside = ((x >= xmin) & (x <= xmax))[None, :] & ((y >= ymin) & (y <= ymax))[:, None]
        image[inside] = OCCUPIED
    return image[::-1]  # row 0 is the top (largest y)


def main() -> None:
    folder = Path(__file__).resolve().parents[1] / "scenarios"
    image = render()
    header = f"P5\n# covswarm example lab map\n{image.shape[1]} {image.shape[0]}\n255\n"
    (folder / "lab.pgm").write_bytes(header.encode("ascii") + image.tobytes())
    (folder / "lab.yaml").write_text(
        "# Written by scripts/make_lab_map.py: a 10 m x 6 m lab, two rooms and a 1.2 m door.\n"
        "image: lab.pgm\n"
        f"resolution: {RESOLUTION}\n"
        f"origin: [{ORIGIN[0]}, {ORIGIN[1]}, 0.0]\n"
        "negate: 0\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n",
        encoding="utf-8",
    )
    print(f"wrote {folder / 'lab.pgm'} ({image.shape[1]} x {image.shape[0]}) and lab.yaml")


if __name__ == "__main__":
    main()
