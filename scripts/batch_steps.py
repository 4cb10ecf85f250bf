"""``local_steps`` (one batch) against a loop of ``local_step``, in microseconds per view;
with ``--safety``, ``safe_unicycle_velocities`` against a loop of ``safe_velocity``.

Usage: .venv/bin/python scripts/batch_steps.py [--team 500] [--sizes 50,200,500]
[--repeats 7] [--law da] [--density] [--safety [--obstacles 100]]

A near-CVT team (deploy.bench.make_layout "cvt") in a translating square; each view is one
robot's two-hop neighbourhood (deploy.bench.two_hop), as an agent holds it. For each batch
size B the first B robots' views are stepped as one ``local_steps`` call and as a loop of
``local_step``, interleaved ``--repeats`` times (the machine's speed drifts: compare the
ratio, and read the load printed with it). Prints the median microseconds per view of each,
their ratio, and the fastest of the repeats (the cost without the other workers' noise).

The safety filter's inputs are an agent's (covswarm.agent.brain._safe): the robots within
SAFETY_RADIUS with velocities, a random heading, the nominal velocity of a coverage step, and
with ``--obstacles`` the boxes of deploy.bench.bench_world near the robot and its walls.
"""

from __future__ import annotations

import os
import time

import click
import numpy as np

from covswarm.deploy.bench import bench_density, bench_world, make_layout, translating, two_hop
from covswarm.tvd.control import LocalView, local_step, local_steps
from covswarm.tvd.coverage import neighbors
from covswarm.tvd.safety import (
    DEFAULT_GAMMA,
    SAFETY_RADIUS,
    safe_unicycle_velocities,
    safe_velocity,
    wall_distance,
)


def views_of(team: int, density: bool, seed: int = 0) -> list[LocalView]:
    layout = make_layout(team, "cvt", seed)
    adjacency = neighbors(layout.positions, layout.polygon)
    velocity = translating(layout)
    phi = bench_density(float(layout.polygon[:, 0].max())) if density else None
    return [
        LocalView(
            me, {j: layout.positions[j] for j in two_hop(adjacency, me)}, layout.polygon,
            velocity, 1.0, phi,
        )
        for me in range(team)
    ]  # fmt: skip


def filter_inputs(team: int, obstacles: int, seed: int = 0) -> dict:
    """Each robot's safety filter inputs as its agent has them (module notes)."""
    layout = make_layout(team, "cvt", seed)
    p = layout.positions
    rng = np.random.default_rng(seed)
    near = [np.flatnonzero(np.hypot(*(p - q).T) <= SAFETY_RADIUS) for q in p]
    near = [others[others != r] for r, others in enumerate(near)]
    velocities = rng.normal(0.0, 0.1, size=(team, 2))
    inputs = {
        "positions": p,
        "nominal": velocities + rng.normal(0.0, 0.2, size=(team, 2)),
        "headings": rng.uniform(-np.pi, np.pi, size=team),
        "neighbors": [p[others] for others in near],
        "velocities": velocities,
        "neighbor_velocities": [velocities[others] for others in near],
    }
    if obstacles:
        world = bench_world(layout, obstacles)
        inputs["obstacles"] = [
            [world.obstacles[j].vertices for j in world.candidates((x, x, y, y), SAFETY_RADIUS)]
            for x, y in p.tolist()
        ]
        inputs["workspace"] = world.workspace
    return inputs


def filter_loop(inputs: dict, count: int, safe: float) -> None:
    walls = "obstacles" in inputs
    for r in range(count):
        safe_velocity(
            inputs["positions"][r], inputs["nominal"][r], inputs["neighbors"][r], safe,
            DEFAULT_GAMMA, heading=float(inputs["headings"][r]),
            velocity=inputs["velocities"][r],
            neighbor_velocities=inputs["neighbor_velocities"][r],
            obstacles=inputs["obstacles"][r] if walls else (),
            workspace=inputs.get("workspace"),
            obstacle_distance=wall_distance(0.14) if walls else None,
            reach=SAFETY_RADIUS,
            obstacle_gamma=0.5 * DEFAULT_GAMMA if walls else None,
        )  # fmt: skip


def filter_batch(inputs: dict, count: int, safe: float) -> None:
    walls = "obstacles" in inputs
    safe_unicycle_velocities(
        inputs["positions"][:count], inputs["nominal"][:count], inputs["headings"][:count],
        inputs["neighbors"][:count], safe, DEFAULT_GAMMA,
        velocities=inputs["velocities"][:count],
        neighbor_velocities=inputs["neighbor_velocities"][:count],
        obstacles=inputs["obstacles"][:count] if walls else None,
        workspace=inputs.get("workspace"),
        obstacle_distance=wall_distance(0.14) if walls else None,
        reach=SAFETY_RADIUS,
        obstacle_gamma=0.5 * DEFAULT_GAMMA if walls else None,
    )  # fmt: skip


def compare(label: str, sizes: list[int], repeats: int, one_by_one, batched) -> None:
    """Interleaved timings of ``one_by_one(size)`` and ``batched(size)``, printed per item."""
    for size in sizes:
        one_by_one(size)
        batched(size)  # warm
        single, many = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            one_by_one(size)
            single.append((time.perf_counter() - start) / size * 1e6)
            start = time.perf_counter()
            batched(size)
            many.append((time.perf_counter() - start) / size * 1e6)
        one, batch = float(np.median(single)), float(np.median(many))
        print(
            f"{label} B={size:4d}: median loop {one:6.1f} us, batch {batch:6.1f} us, "
            f"ratio {one / batch:5.2f}; fastest loop {min(single):6.1f}, batch "
            f"{min(many):6.1f}; load {os.getloadavg()[0]:.2f}"
        )


def loop(views: list[LocalView], law: str) -> None:
    for v in views:
        local_step(v.me, v.positions, v.polygon, v.polygon_velocity, v.kappa, True, v.density,
                   law=law)  # fmt: skip


@click.command()
@click.option("--team", default=500, show_default=True)
@click.option("--sizes", default="50,200,500", show_default=True)
@click.option("--repeats", default=7, show_default=True)
@click.option("--law", default="da", type=click.Choice(["d1", "da"]), show_default=True)
@click.option("--density/--uniform", default=False, show_default=True)
@click.option("--safety", is_flag=True, help="Time the safety filter instead.")
@click.option("--obstacles", default=0, show_default=True, help="Boxes in the world (--safety).")
def main(
    team: int, sizes: str, repeats: int, law: str, density: bool, safety: bool, obstacles: int
) -> None:
    counts = [int(s) for s in sizes.split(",")]
    print(f"team {team}, load {os.getloadavg()[0]:.2f}")
    if safety:
        inputs = filter_inputs(team, obstacles)
        safe = 0.16  # m: a Khepera IV's diameter and the margin
        label = f"filter ({obstacles} obstacles)"
        compare(
            label, counts, repeats,
            lambda size: filter_loop(inputs, size, safe),
            lambda size: filter_batch(inputs, size, safe),
        )  # fmt: skip
        return
    views = views_of(team, density)
    compare(
        f"step {law} density={density}", counts, repeats,
        lambda size: loop(views[:size], law),
        lambda size: local_steps(views[:size], law=law),
    )  # fmt: skip


if __name__ == "__main__":
    main()
