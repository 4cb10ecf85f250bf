"""The agents' projection distance against latency the prediction does not know about.

Usage: .venv/bin/python scripts/projection_distance.py [--distances 0.03,0.05,0.08]
       [--latencies 0,0.1,0.2,0.3] [--safety/--no-safety]

Runs the passage (10 robots, 45 s) in deploy.netsim, the in-process replica of
``covswarm run`` (real brains and robot sims on a simulated clock, deterministic), with the
robots acting on each command this many seconds after it was stamped while the agents
assume at once (an actuator or command link slower than modelled), and prints e_a's
second-half mean per (distance, latency) as a Markdown table. The heading loop of the
near-identity mapping has gain |u| / l, and with a residual latency tau it is stable only
while tau |u| / l < pi / 2: a longer l tolerates more, and costs tracking.
"""

from __future__ import annotations

import click

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import run_netsim, steady_state
from covswarm.mission.scenario_files import load_scenario


@click.command()
@click.option("--distances", default="0.03,0.05,0.08", show_default=True, help="m")
@click.option("--latencies", default="0,0.1,0.2,0.3", show_default=True, help="s")
@click.option("--safety/--no-safety", default=True, show_default=True)
@click.option("--agents", type=int, default=10, show_default=True)
def main(distances: str, latencies: str, safety: bool, agents: int) -> None:
    """Print e_a per projection distance and unmodelled command latency."""
    scenario = load_scenario("passage")
    lats = [float(v) for v in latencies.split(",")]
    click.echo("| projection distance | " + " | ".join(f"{v:g} s" for v in lats) + " |")
    click.echo("|---" * (len(lats) + 1) + "|")
    for distance in (float(v) for v in distances.split(",")):
        config = AgentConfig(projection_distance=distance, safety=safety)
        cells = [
            steady_state(run_netsim(scenario, agents=agents, config=config, command_delay=lat))
            for lat in lats
        ]
        click.echo(f"| {distance:g} m | " + " | ".join(f"{e:.4f}" for e in cells) + " |")


if __name__ == "__main__":
    main()
