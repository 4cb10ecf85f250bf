"""Robots stopped dead side by side: sliding at once, or waiting SLIDE_AFTER as before.

Usage: .venv/bin/python scripts/beside_slide.py [--scenario tests/data/square-200.toml]
[--seeds 0,1,2,3,4,5] [--duration 4] [--gaps 0.08,0.14] [--layout-seed 0]

deploy.netsim (the agents' own code over a simulated network) of a scenario from one start
layout (``--layout-seed``: covswarm.deploy.plan.initial_poses), each brain stepped every
``--gaps`` s (drawn per step; ``--gaps 0``: at a steady 10 Hz), its robot stopped 0.3 s
after its last step, per seed of those draws, twice: as main steers a robot stopped dead by
its safety filter (covswarm.agent.brain.AgentBrain.drive: its slide at once when no robot
that stops it is ahead of it, covswarm.tvd.drive.stopped_beside) and as before 3 Dec 2026
(its slide only after SLIDE_AFTER s stopped). Prints a Markdown row per seed and rule:
e_a's second-half mean and the worst robot's distance from its centroid at 1.6 s (m), the
closest two robots came (m) and the steps slid. ~25 s of CPU a run of 200 robots;
covswarm.tvd.drive's BESIDE_ANGLE comment and docs/scaling.md quote it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

import click
import numpy as np

from covswarm.agent import brain
from covswarm.deploy.netsim import NetsimResult, run_netsim, steady_state
from covswarm.deploy.plan import initial_poses
from covswarm.mission.physical import proximity
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import Scenario
from covswarm.tvd import drive
from covswarm.tvd.coverage import mass_centroid
from covswarm.tvd.drive import KHEPERA_IV

RULES = ("after SLIDE_AFTER (before)", "main")
HOLD_AFTER = 0.3  # s: a packed process's stop (covswarm agent's three periods at 10 Hz)


@contextmanager
def slides_only_after_waiting() -> Iterator[None]:
    """Within: a robot stopped dead slides only after SLIDE_AFTER s, as before 3 Dec 2026,
    in the agents (covswarm.agent.brain) and in ``covswarm sim`` (which imports the test
    from covswarm.tvd.drive when it runs)."""
    beside = drive.stopped_beside

    def never(*args: object, **kwargs: object) -> bool:
        return False

    brain.stopped_beside = drive.stopped_beside = never  # type: ignore[assignment]
    try:
        yield
    finally:
        brain.stopped_beside = drive.stopped_beside = beside


def worst_at(result: NetsimResult, scenario: Scenario, t: float) -> float:
    """The largest distance (m) of a robot from its centroid at the sample nearest ``t``."""
    k = int(np.argmin(np.abs(result.t - t)))
    _, centroids = mass_centroid(result.trajectories[k], scenario.domain(result.t[k])[0])
    return float(np.max(np.linalg.norm(result.trajectories[k] - centroids, axis=1)))


def compare(
    scenario: Scenario, seed: int, duration: float, gaps: tuple[float, float] | None, layout: int
) -> dict[str, NetsimResult]:
    """The netsim run under each rule of RULES (module docstring)."""
    poses = initial_poses(scenario, scenario.agents, layout)
    late = {} if gaps is None else {"turn_gaps": gaps, "hold_after": HOLD_AFTER}
    results = {}
    for rule in RULES:
        with slides_only_after_waiting() if rule != "main" else nullcontext():
            results[rule] = run_netsim(scenario, seed=seed, duration=duration, poses=poses, **late)
    return results


@click.command()
@click.option("--scenario", default="tests/data/square-200.toml", show_default=True)
@click.option("--seeds", default="0,1,2,3,4,5", show_default=True)
@click.option("--duration", type=float, default=4.0, show_default=True)
@click.option("--gaps", default="0.08,0.14", show_default=True, help="s between steps; 0: 10 Hz")
@click.option("--layout-seed", type=int, default=0, show_default=True)
def main(scenario: str, seeds: str, duration: float, gaps: str, layout_seed: int) -> None:
    drawn = None if gaps.strip() == "0" else tuple(float(g) for g in gaps.split(","))
    loaded = load_scenario(scenario)
    print("| seed | rule | e_a 2nd half, m | worst at 1.6 s, m | closest, m | steps slid |")
    print("|---|---|---|---|---|---|")
    for seed in (int(s) for s in seeds.split(",")):
        for rule, result in compare(loaded, seed, duration, drawn, layout_seed).items():
            closest = proximity(result.t, result.trajectories, KHEPERA_IV.body_diameter)[0]
            slid = sum(stats.get("slid", 0) for stats in result.stats.values())
            print(
                f"| {seed} | {rule} | {steady_state(result):.4f} | "
                f"{worst_at(result, loaded, 1.6):.3f} | {closest:.4f} | {slid} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
