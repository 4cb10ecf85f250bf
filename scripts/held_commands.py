"""How long a slow team's commands must stay in force: e_a against when robots stop.

Usage: .venv/bin/python scripts/held_commands.py [--agents 100] [--rate 1.67] [--slow 6]
       [--stops 0.3,0.5,0.9] [--duration 60] [--seed 0] [--max-duty 4]

Runs the ``circle`` scenario (its S circling at 1/``--slow`` of its speed, as the
coordinator paces it for a team holding 1/``--slow`` of 10 Hz) in the deterministic
in-process network simulation (covswarm.deploy.netsim: real brains, real robot models, no
Zenoh) with every agent stepping at ``--rate`` Hz, once per robot stop time in
``--stops``: the robot stops that many s after each command (its command timeout, or a
packed process's hold of a late brain, covswarm.agent.pack), and the brains know it (their
``cmd_timeout``, as ``covswarm run`` passes it): a command that stops before the next step
is driven up to ``--max-duty`` times faster (covswarm.agent.brain.MAX_DUTY; 1: as computed,
for the robot to cover only its share of each move). Prints a Markdown table of
e_a at the start, its second-half mean and its end, m. docs/scaling.md quotes it (a
minute of CPU per row at 100 robots).
"""

from __future__ import annotations

import dataclasses

import click
import numpy as np

from covswarm.agent.brain import MAX_DUTY, AgentConfig
from covswarm.deploy.netsim import run_netsim, steady_state
from covswarm.mission.motion import Rigid
from covswarm.mission.scenarios import Scenario, circle


def slowed_circle(slow: float, duration: float) -> Scenario:
    """The circle scenario with its centre circling ``slow`` times slower."""
    base = circle()
    assert isinstance(base.motion, Rigid)
    motion = dataclasses.replace(base.motion, period=base.motion.period * slow)
    return dataclasses.replace(base, name=f"circle-slow-{slow:g}", motion=motion, duration=duration)


@click.command()
@click.option("--agents", type=click.IntRange(2), default=100, show_default=True)
@click.option("--rate", type=click.FloatRange(0.5), default=1.67, show_default=True)
@click.option("--slow", type=click.FloatRange(1.0), default=6.0, show_default=True)
@click.option("--stops", default="0.3,0.5,0.9", show_default=True)
@click.option("--duration", type=click.FloatRange(5.0), default=60.0, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option(
    "--max-duty", type=click.FloatRange(1.0), default=MAX_DUTY, show_default=True,
    help="How much faster a brain drives a command that stops early (1: not at all).",
)  # fmt: skip
def main(
    agents: int, rate: float, slow: float, stops: str, duration: float, seed: int, max_duty: float
) -> None:
    scenario = slowed_circle(slow, duration)
    print(
        f"circle, S at 1/{slow:g} of its speed, {agents} agents at {rate:g} Hz, {duration:g} s, "
        f"max duty {max_duty:g}"
    )
    print("| robot stops after a command, s | e_a start, m | second half | end |")
    print("|---|---|---|---|")
    for stop in (float(s) for s in stops.split(",")):
        # The brains know the stop, as in covswarm run (the robots' command timeout).
        config = AgentConfig(cmd_timeout=stop, max_duty=max_duty)
        result = run_netsim(
            scenario, agents=agents, seed=seed, rate=rate, cmd_timeout=stop, config=config
        )
        error = np.asarray(result.error)
        print(f"| {stop:g} | {error[0]:.3f} | {steady_state(result):.3f} | {error[-1]:.3f} |")


if __name__ == "__main__":
    main()
