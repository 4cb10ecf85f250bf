"""Robots known only from old beacons in the safety filter: as main has it, or as before.

Usage: .venv/bin/python scripts/phantom_beacons.py [--agents 400] [--duration 30] [--seeds 1]

deploy.netsim (the agents' own code over a simulated network) of scenarios/circle-N.toml
(N = --agents) at 10 Hz, the agents' safety filter and prediction on, robots' command
timeout 0.5 s, per seed, twice: as main filters (covswarm.agent.brain.BEACON_TRUST: a robot
known only from a beacon older than that is no row while its AgentState is awaited) and
with every beacon-only robot a row however old its beacon (BEACON_TRUST infinite, the rule
before 30 Nov 2026). Since 3 Dec 2026 the same horizon also keeps such robots out of the
local diagrams (scripts/phantom_diagrams.py): the first row has them in the filter and the
diagrams, as before 30 Nov, the second in neither; figures from before 3 Dec had them in
the diagrams in both rows. Prints a Markdown row per seed and rule: e_a's second-half mean
and final value (m), and the team's safety_relaxed steps. docs/scaling.md quotes it (~5 min of
CPU a run at 400 robots).
"""

from __future__ import annotations

import math

import click

from covswarm.agent import brain
from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import run_netsim, steady_state
from covswarm.mission.scenario_files import load_scenario


@click.command()
@click.option("--agents", type=click.IntRange(min=2), default=400, show_default=True)
@click.option("--duration", type=click.FloatRange(min=1.0), default=30.0, show_default=True)
@click.option("--seeds", type=click.IntRange(min=1), default=1, show_default=True)
def main(agents: int, duration: float, seeds: int) -> None:
    """Old beacons in the safety filter, with and without BEACON_TRUST (module docstring)."""
    scenario = load_scenario(f"scenarios/circle-{agents}.toml")
    config = AgentConfig(kappa=3.0, safety=True, prediction=True, feedforward=True)
    trust = brain.BEACON_TRUST
    print("| seed | beacon-only rows | e_a 2nd half (m) | e_a end (m) | safety_relaxed |")
    print("|---|---|---|---|---|")
    try:
        for seed in range(seeds):
            for name, horizon in (("any age (before)", math.inf), (f"<= {trust:g} s", trust)):
                brain.BEACON_TRUST = horizon
                result = run_netsim(
                    scenario, seed=seed, duration=duration, config=config, cmd_timeout=0.5
                )
                relaxed = sum(int(s.get("safety_relaxed", 0)) for s in result.stats.values())
                print(
                    f"| {seed} | {name} | {steady_state(result):.4f} | {result.error[-1]:.4f} "
                    f"| {relaxed} |",
                    flush=True,
                )
    finally:
        brain.BEACON_TRUST = trust


if __name__ == "__main__":
    main()
