"""Robots known only from old beacons in the local diagrams: as main has it, or as before.

Usage: .venv/bin/python scripts/phantom_diagrams.py [--scenario warehouse] [--agents 20]
[--seeds 3] [--duration SECONDS]

deploy.netsim (the agents' own code over a simulated network, the agents' defaults) of a
scenario (a built-in name or a file), per seed, twice: as main builds each agent's local
diagram (covswarm.agent.neighborhood.Neighborhood.relevant: a robot known only from a
beacon older than covswarm.agent.brain.BEACON_TRUST is no robot in it while its AgentState
is awaited) and with every beacon-only robot in it however old its beacon (the rule before
3 Dec 2026; the safety filter drops them either way, scripts/phantom_beacons.py). Prints a
Markdown row per seed and rule: e_a's second-half mean and final value (m), and the
closest two robots came (m). docs/scaling.md quotes it (warehouse 20: ~15 s of CPU a run).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import click
import numpy as np
from scipy.spatial.distance import pdist

from covswarm.agent.neighborhood import Neighborhood
from covswarm.deploy.netsim import NetsimResult, run_netsim, steady_state
from covswarm.mission.scenario_files import load_scenario

RULES = ("any age (before)", "main")


@contextmanager
def old_beacons_in_diagrams() -> Iterator[None]:
    """Within: every agent's local diagram holds its beacon-only robots however old their
    beacons (the trust horizon ignored), as before 3 Dec 2026."""
    relevant = Neighborhood.relevant

    def trusting(self: Neighborhood, *args: object, **kwargs: object) -> dict:
        kwargs["trust"] = math.inf
        return relevant(self, *args[:4], **kwargs)  # type: ignore[arg-type]

    Neighborhood.relevant = trusting  # type: ignore[method-assign]
    try:
        yield
    finally:
        Neighborhood.relevant = relevant  # type: ignore[method-assign]


def closest(result: NetsimResult) -> float:
    """The least distance between two robots over the run (m)."""
    return float(min(pdist(positions).min() for positions in result.trajectories))


def compare(
    scenario: str, agents: int | None, seed: int, duration: float | None
) -> dict[str, NetsimResult]:
    """The netsim run of ``scenario`` under each rule of RULES (module docstring)."""
    loaded = load_scenario(scenario)
    results = {}
    for rule in RULES:
        if rule == "main":
            results[rule] = run_netsim(loaded, agents=agents, seed=seed, duration=duration)
        else:
            with old_beacons_in_diagrams():
                results[rule] = run_netsim(loaded, agents=agents, seed=seed, duration=duration)
    return results


@click.command()
@click.option("--scenario", default="warehouse", show_default=True)
@click.option("--agents", type=click.IntRange(min=2), default=None, help="Default: the file's.")
@click.option("--seeds", type=click.IntRange(min=1), default=3, show_default=True)
@click.option("--duration", type=click.FloatRange(min=1.0), default=None)
def main(scenario: str, agents: int | None, seeds: int, duration: float | None) -> None:
    """Old beacons in the local diagrams, with and without the trust horizon."""
    print("| seed | old beacons in the diagram | e_a 2nd half (m) | e_a end (m) | closest (m) |")
    print("|---|---|---|---|---|")
    for seed in range(seeds):
        for rule, result in compare(scenario, agents, seed, duration).items():
            error = np.asarray(result.error)
            print(
                f"| {seed} | {rule} | {steady_state(result):.4f} | {error[-1]:.4f} "
                f"| {closest(result):.4f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
