"""What the deploy hold's facing second does to e_a after the release, by which way the
robots turn.

Usage: .venv/bin/python scripts/facing_cost.py [--seeds 10] [--agents 300]

``covswarm sim --scenario scenarios/circle-400.toml --dt 0.1 --dynamics unicycle
--projection-distance 0.05 --safety --deploy-error 0.05`` (covswarm.deploy.simulate), per
seed, with the hold's last second (covswarm.coordinator.pace.DEPLOY_ALIGN) spent turning
in place toward S's start motion (as main does), a quarter turn to its left of it, half a
turn from it, or not at all (DEPLOY_ALIGN = 0). Prints a markdown table of e_a (m), the
mean over the seeds of each 5 s window after the release, and in how many seeds each way
of turning ends above no turn, window by window. docs/scaling.md quotes it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from covswarm.coordinator import pace
from covswarm.deploy.simulate import simulate
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import drive

WINDOWS = range(0, 30, 5)  # s after the release, each 5 s long
TURNS = {"toward S's start": 0.0, "a quarter turn left of it": 0.5 * math.pi, "away": math.pi}


def after_release(seed: int, agents: int, turn: float | None) -> np.ndarray:
    """e_a's mean in each window after the release; ``turn``: rad added to the direction
    the robots face during the hold's last second (None: no such second)."""
    facing, align = drive.turn_in_place, pace.DEPLOY_ALIGN
    if turn is None:
        pace.DEPLOY_ALIGN = 0.0
    elif turn:
        drive.turn_in_place = lambda heading, direction, hold, *rest: facing(
            heading, direction + turn, hold, *rest
        )
    try:
        result = simulate(
            load_scenario("scenarios/circle-400.toml"),
            agents=agents,
            dt=0.1,
            dynamics="unicycle",
            projection_distance=0.05,
            safety=True,
            deploy_error=0.05,
            seed=seed,
        )
    finally:
        drive.turn_in_place, pace.DEPLOY_ALIGN = facing, align
    assert result.released is not None
    t = result.t - result.released[0]
    return np.array([result.error[(t >= a) & (t < a + 5.0)].mean() for a in WINDOWS])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--agents", type=int, default=300)
    args = parser.parse_args()
    seeds = range(args.seeds)
    still = np.array([after_release(s, args.agents, None) for s in seeds])
    rows = {"no facing second": (still, None)}
    for name, turn in TURNS.items():
        errors = np.array([after_release(s, args.agents, turn) for s in seeds])
        rows[name] = (errors, (errors > still).sum(axis=0))
    windows = [f"{a}-{a + 5} s" for a in WINDOWS]
    print("| the hold's last second | " + " | ".join(windows) + " |")
    print("|" + "---|" * (len(windows) + 1))
    for name, (errors, above) in rows.items():
        means = errors.mean(axis=0)
        cells = [
            f"{m:.4f}" + ("" if above is None else f" ({a}/{len(seeds)})")
            for m, a in zip(means, above if above is not None else means, strict=True)
        ]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
