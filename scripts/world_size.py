"""Bytes of the World message (covswarm.protocol.World) for the example lab map and for a
20 m x 20 m warehouse map at 5 cm (outer walls, a dividing wall with a door, 24 shelves and
pillars, a band of unknown around it, as a SLAM map has). Run from the repository root:

    python scripts/world_size.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from covswarm.world.maps import world_from_map
from covswarm.world.wire import to_message

ROOT = Path(__file__).resolve().parents[1]
RESOLUTION = 0.05  # m per pixel
SIDE = 20.0  # m


def warehouse_map(folder: Path) -> Path:
    """Write a 20 m x 20 m map at 5 cm (PGM + YAML) into ``folder``; its YAML's path."""
    n = round(SIDE / RESOLUTION)
    centres = RESOLUTION * (np.arange(n) + 0.5)  # m from the lower-left corner
    x, y = centres[None, :], centres[:, None]
    occupied = np.zeros((n, n), dtype=bool)

    def box(xmin: float, xmax: float, ymin: float, ymax: float) -> None:
        occupied[(x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)] = True

    for xmin, xmax, ymin, ymax in [(0.3, 19.7, 0.3, 0.5), (0.3, 19.7, 19.5, 19.7)]:
        box(xmin, xmax, ymin, ymax)
    box(0.3, 0.5, 0.3, 19.7)
    box(19.5, 19.7, 0.3, 19.7)
    box(9.9, 10.1, 0.3, 8.0)  # dividing wall, a 2 m door at y in (8, 10)
    box(9.9, 10.1, 10.0, 19.7)
    for col in range(4):  # shelves: 4 columns x 3 rows in each half
        for row in range(3):
            for half in (0.0, 10.0):
                x0 = half + 1.5 + 2.0 * col
                y0 = 2.0 + 6.0 * row
                box(x0, x0 + 0.6, y0, y0 + 4.0)
    for px, py in [(5.0, 9.0), (15.0, 9.0), (5.0, 15.5), (15.0, 15.5)]:  # pillars
        box(px - 0.15, px + 0.15, py - 0.15, py + 0.15)
    unknown = (x < 0.3) | (x > 19.7) | (y < 0.3) | (y > 19.7)
    image = np.where(occupied, 0, np.where(unknown, 205, 254)).astype(np.uint8)[::-1]
    header = f"P5\n{n} {n}\n255\n".encode("ascii")
    (folder / "warehouse20.pgm").write_bytes(header + image.tobytes())
    path = folder / "warehouse20.yaml"
    path.write_text(
        "image: warehouse20.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return path


def sizes(folder: Path) -> dict[str, tuple[int, int]]:
    """name -> (obstacles, encoded bytes) of the World messages measured."""
    out = {}
    for name, path in [
        ("scenarios/lab.yaml", ROOT / "scenarios" / "lab.yaml"),
        ("20 m x 20 m at 5 cm", warehouse_map(folder)),
    ]:
        world = world_from_map(path)
        out[name] = (len(world.obstacles), len(to_message(world, 1, time.time()).encode()))
    return out


def main() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        for name, (count, size) in sizes(Path(folder)).items():
            print(f"{name}: {count} obstacles, World message {size} bytes")


if __name__ == "__main__":
    main()
