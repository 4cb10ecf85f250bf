"""What facing S's first motion before the start does to e_a, seed by seed.

Usage: .venv/bin/python scripts/start_alignment.py [--scenario circle] [--agents 100]
       [--duration 20] [--seeds 0-8]

Runs the mission in the deterministic in-process network simulation
(covswarm.deploy.netsim: real brains, real Khepera IV models at random headings, no Zenoh)
twice per seed: with the waiting Domains carrying S's start velocities, so that each
brain turns its robot in place toward S's motion before the start (what covswarm run
does), and without (the robots start as placed). Prints a Markdown table of e_a at 5 s,
its second-half mean and its end, m, and the means over the seeds. docs/scaling.md quotes
it (about a minute of CPU per run at 100 robots).
"""

from __future__ import annotations

import statistics

import click
import numpy as np

from covswarm.deploy.netsim import run_netsim, steady_state
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol.keys import parse_ids


@click.command()
@click.option("--scenario", "name", default="circle", show_default=True)
@click.option("--agents", type=click.IntRange(min=2), default=100, show_default=True)
@click.option("--duration", type=click.FloatRange(min=1.0), default=20.0, show_default=True)
@click.option("--seeds", default="0-8", show_default=True, help="e.g. 0-8 or 0,3,5")
def main(name: str, agents: int, duration: float, seeds: str) -> None:
    scenario = load_scenario(name)
    rows: dict[bool, list[float]] = {True: [], False: []}
    print("| seed | facing S's start: e_a at 5 s, 2nd half, end | as placed: the same |")
    print("|---|---|---|")
    for seed in parse_ids(seeds):
        cells = []
        for announce in (True, False):
            result = run_netsim(
                scenario, agents=agents, duration=duration, seed=seed, announce_start=announce
            )
            at5 = float(result.error[np.searchsorted(result.t, 5.0)])
            half = steady_state(result)
            rows[announce].append(half)
            cells.append(f"{at5:.3f}, {half:.4f}, {result.error[-1]:.4f}")
        print(f"| {seed} | {cells[0]} | {cells[1]} |", flush=True)
    mean = {k: statistics.mean(v) for k, v in rows.items()}
    worst = {k: max(v) for k, v in rows.items()}
    print(
        f"| mean (worst) of the 2nd half | {mean[True]:.4f} ({worst[True]:.4f}) "
        f"| {mean[False]:.4f} ({worst[False]:.4f}) |"
    )


if __name__ == "__main__":
    main()
