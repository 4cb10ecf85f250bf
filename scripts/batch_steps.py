"""``local_steps`` (one batch) against a loop of ``local_step``, in microseconds per view.

Usage: .venv/bin/python scripts/batch_steps.py [--team 500] [--sizes 50,200,500]
[--repeats 7] [--law da] [--density]

A near-CVT team (deploy.bench.make_layout "cvt") in a translating square; each view is one
robot's two-hop neighbourhood (deploy.bench.two_hop), as an agent holds it. For each batch
size B the first B robots' views are stepped as one ``local_steps`` call and as a loop of
``local_step``, interleaved ``--repeats`` times (the machine's speed drifts: compare the
ratio, and read the load printed with it). Prints the median microseconds per view of each
and their ratio.
"""

from __future__ import annotations

import os
import time

import click
import numpy as np

from covswarm.deploy.bench import bench_density, make_layout, translating, two_hop
from covswarm.tvd.control import LocalView, local_step, local_steps
from covswarm.tvd.coverage import neighbors


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
def main(team: int, sizes: str, repeats: int, law: str, density: bool) -> None:
    views = views_of(team, density)
    print(f"team {team}, law {law}, density {density}, load {os.getloadavg()[0]:.2f}")
    for size in (int(s) for s in sizes.split(",")):
        batch = views[:size]
        loop(batch, law)
        local_steps(batch, law=law)  # warm
        single, batched = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            loop(batch, law)
            single.append((time.perf_counter() - start) / size * 1e6)
            start = time.perf_counter()
            local_steps(batch, law=law)
            batched.append((time.perf_counter() - start) / size * 1e6)
        one, many = float(np.median(single)), float(np.median(batched))
        print(
            f"B={size:4d}: loop {one:7.1f} us/view, batch {many:7.1f} us/view, "
            f"ratio {one / many:5.2f}, load {os.getloadavg()[0]:.2f}"
        )


if __name__ == "__main__":
    main()
