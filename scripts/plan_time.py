"""How long the route planner takes on 20 m x 20 m occupancy maps at 5 cm.

Two families of maps, drawn from a seed, each an occupancy grid at 5 cm per pixel turned
into obstacles as a map file would be (covswarm.world.maps: merged rectangles):

- ``random``: outer walls and 40 random blocks (0.3 m to 2 m a side); S a 1.6 m x 1.2 m
  rectangle, sent from a random free spot in the left quarter to one in the right quarter;
- ``doors``: three walls across the map, each with a 1.1 m door at a random height; S a
  2.4 m x 1.6 m rectangle that must shrink through every door;
- ``turns``: the same walls with 0.9 m doors; S a 0.6 m x 2.4 m rectangle standing
  upright, which the team cannot shrink below 1.9 m high: it must turn to pass each door.

The team is 20 Khepera IV (its least S from covswarm.mission.crowding.least_domain); the
fastest vertex 0.25 m/s. Prints one JSON object: per family the plan times' p50, p95 and
max (ms, wall clock, the world built beforehand), the CPU time's p50 and p95 (ms: what the
plan costs on a machine shared with other work) and how many plans found a route.

    python scripts/plan_time.py [--maps 20] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from covswarm.mission.crowding import least_domain
from covswarm.world.maps import OccupancyMap
from covswarm.world.model import World
from covswarm.world.planner import NoPath, plan_route

RESOLUTION = 0.05  # m per pixel
SIDE = 20.0  # m
PIXELS = round(SIDE / RESOLUTION)
SPEED = 0.25  # m/s
DOORS = {"doors": 1.1, "turns": 0.9}  # m
SHAPES = {"random": (1.6, 1.2), "doors": (2.4, 1.6), "turns": (0.6, 2.4)}  # S, m x m


def _rectangle(width: float, height: float) -> np.ndarray:
    return np.array([[0, 0], [width, 0], [width, height], [0, height]]) - [width / 2, height / 2]


def _grid(rng: np.random.Generator, family: str) -> np.ndarray:
    """(rows, cols) bool occupancy, row 0 at the bottom."""
    occupied = np.zeros((PIXELS, PIXELS), dtype=bool)
    border = round(0.2 / RESOLUTION)
    occupied[:border], occupied[-border:], occupied[:, :border], occupied[:, -border:] = (
        True, True, True, True,
    )  # fmt: skip
    if family == "random":
        for _ in range(40):
            w, h = rng.integers(round(0.3 / RESOLUTION), round(2.0 / RESOLUTION), 2)
            i, j = rng.integers(0, PIXELS - h), rng.integers(0, PIXELS - w)
            occupied[i : i + h, j : j + w] = True
    else:
        thick, door = round(0.2 / RESOLUTION), round(DOORS[family] / RESOLUTION)
        for x in (5.0, 10.0, 15.0):
            j = round(x / RESOLUTION)
            start = rng.integers(border + 10, PIXELS - border - door - 10)
            occupied[:, j : j + thick] = True
            occupied[start : start + door, j : j + thick] = False
    return occupied


def _free_spot(
    rng: np.random.Generator, world: World, shape: np.ndarray, xs: tuple[float, float]
) -> np.ndarray:
    for _ in range(10_000):
        centre = rng.uniform([xs[0], 1.5], [xs[1], SIDE - 1.5])
        if world.contact(centre + shape) is None:
            return centre
    raise RuntimeError("no free spot for S")


def measure(family: str, maps: int, seed: int) -> dict:
    min_area, min_width = least_domain(20, 0.14)
    shape = _rectangle(*SHAPES[family])
    times, cpu, pieces, found, refused = [], [], [], 0, {}
    for k in range(maps):
        rng = np.random.default_rng([seed, k, list(SHAPES).index(family)])
        grid = OccupancyMap(Path(f"<{family} {k}>"), _grid(rng, family), RESOLUTION, (0.0, 0.0))
        world = World(grid.extent, grid.obstacles())
        pieces.append(len(world.obstacles))
        start = _free_spot(rng, world, shape, (1.5, 4.5))
        goal = _free_spot(rng, world, shape, (15.5, 18.5))
        began, began_cpu = time.perf_counter(), time.process_time()
        try:
            plan_route(
                world, start + shape, goal, min_area=min_area, min_width=min_width,
                max_speed=SPEED,
            )  # fmt: skip
            found += 1
        except NoPath as exc:
            refused[exc.code] = refused.get(exc.code, 0) + 1
        times.append(1e3 * (time.perf_counter() - began))
        cpu.append(1e3 * (time.process_time() - began_cpu))
    ms, cpu_ms = np.array(times), np.array(cpu)
    return {
        "maps": maps,
        "routes": found,
        "refused": refused,
        "obstacles_mean": round(float(np.mean(pieces)), 1),
        "p50_ms": round(float(np.percentile(ms, 50)), 1),
        "p95_ms": round(float(np.percentile(ms, 95)), 1),
        "max_ms": round(float(ms.max()), 1),
        "cpu_p50_ms": round(float(np.percentile(cpu_ms, 50)), 1),
        "cpu_p95_ms": round(float(np.percentile(cpu_ms, 95)), 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--maps", type=int, default=20, help="maps per family")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    result = {
        "map": f"{SIDE:g} m x {SIDE:g} m at {RESOLUTION:g} m",
        **{family: measure(family, args.maps, args.seed) for family in SHAPES},
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
