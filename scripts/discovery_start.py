"""When the mission starts, with beacons heard between two idle steps in the diagram or not.

Usage: .venv/bin/python scripts/discovery_start.py [--seeds 3]

deploy.netsim (the agents' own code over a simulated network; its start is the coordinator's:
the settle, then no gap in the neighbour discovery, coordinator.monitor.discovery_gaps, at
most DISCOVERY_WAIT longer) of a few small teams, per seed, under two rules for the local
diagram's beacons: main's (covswarm.agent.brain.diagram_trust: a beacon heard since the
brain's previous view enters it, up to IDLE_STEP_PERIOD old) and the rule before 3 Dec 2026
evening (only those younger than BEACON_TRUST, 0.5 s). Prints a Markdown row per case, seed
and rule: when the mission started (s of the simulated clock; the warmup ends at 2 s), the
gaps left when it started, the agents whose last state before it named no neighbour, e_a's
second half (m) and the closest two robots came (m).
docs/scaling.md quotes it (~1 minute of CPU for three seeds).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

import click
from scipy.spatial.distance import pdist

from covswarm.agent import brain as brain_module
from covswarm.deploy.netsim import NetsimResult, run_netsim, steady_state
from covswarm.mission.scenario_files import load_scenario

RULES = ("younger than BEACON_TRUST (before)", "main")
# (label, scenario, agents, rate Hz, dead brains)
CASES = (
    ("circle, 12 robots, 10 Hz", "circle", 12, 10.0, ()),
    ("circle, 12 robots, 1.25 Hz", "circle", 12, 1.25, ()),
    ("passage, 6 robots, brains 0 and 3 dead", "passage", 6, 10.0, (0, 3)),
    ("passage, 10 robots", "passage", 10, 10.0, ()),
)
DURATION = 4.0  # s of mission after the start


@contextmanager
def young_beacons_only() -> Iterator[None]:
    """Within: every brain's local diagram takes a beacon-only robot only while its beacon is
    younger than BEACON_TRUST, however long ago the brain's last view was."""
    trust = brain_module.diagram_trust
    brain_module.diagram_trust = lambda now, last_view: brain_module.BEACON_TRUST
    try:
        yield
    finally:
        brain_module.diagram_trust = trust


def closest(result: NetsimResult) -> float:
    """The least distance between two robots over the run (m)."""
    return float(min(pdist(positions).min() for positions in result.trajectories))


def run_case(
    scenario: str,
    agents: int,
    rate: float,
    dead: tuple[int, ...],
    seed: int,
    duration: float = DURATION,
) -> dict[str, NetsimResult]:
    """The netsim run of one case under each rule of RULES."""
    loaded = load_scenario(scenario)
    results = {}
    for rule in RULES:
        with young_beacons_only() if rule != "main" else nullcontext():
            results[rule] = run_netsim(
                loaded, agents=agents, seed=seed, duration=duration, rate=rate, dead=dead
            )
    return results


@click.command()
@click.option("--seeds", type=click.IntRange(min=1), default=3, show_default=True)
def main(seeds: int) -> None:
    """Start times and gaps under both rules (module docstring)."""
    print(
        "| case | seed | diagram's beacons | started (s) | gaps left | naming none "
        "| e_a 2nd half (m) | closest (m) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, scenario, agents, rate, dead in CASES:
        for seed in range(seeds):
            for rule, result in run_case(scenario, agents, rate, dead, seed).items():
                silent = sorted(rid for rid, names in result.listed.items() if not names)
                print(
                    f"| {label} | {seed} | {rule} | {result.started:.2f} "
                    f"| {len(result.undiscovered)} | {', '.join(map(str, silent)) or '-'} "
                    f"| {steady_state(result):.4f} | {closest(result):.4f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
