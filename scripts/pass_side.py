"""Which side a robot held back passes on: always the left, or away from its blocker.

Usage: .venv/bin/python scripts/pass_side.py [--seeds 8] [--agents 1000]
       [--scenario scenarios/circle-1000.toml]

``covswarm sim --scenario SCENARIO --dt 0.1 --dynamics unicycle --projection-distance 0.05
--safety`` (covswarm.deploy.simulate, the robots as placed) per seed, twice: as main steers
(covswarm.tvd.drive.pass_sides: the side away from the robot that holds it back) and with
every robot passing on the left (pass_sides replaced by +1 everywhere, the rule before 30
Nov 2026). Prints a markdown row per seed and run: e_a's second-half mean (m), the
saturated wheels (robot-s) and the close approaches (pairs nearer than a body), then the
means. docs/scaling.md quotes it (~15 s a run at 1000 robots).
"""

from __future__ import annotations

import numpy as np
from pass_rule import arguments, figures  # this folder's: the same options and sim run

from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import drive


def always_left(positions: np.ndarray, *_: object) -> np.ndarray:
    """pass_sides' stand-in for the rule before: +1 (the left) for every robot."""
    return np.ones(len(positions))


def main() -> None:
    args = arguments(__doc__)
    scenario = load_scenario(args.scenario)
    away = drive.pass_sides
    print("| seed | passes | e_a 2nd half (m) | saturated (robot-s) | close approaches |")
    print("|---|---|---|---|---|")
    errors: dict[str, list[float]] = {"left": [], "away": []}
    try:
        for seed in range(args.seeds):
            for name, rule in (("left", always_left), ("away", away)):
                drive.pass_sides = rule
                error, saturated, close = figures(scenario, args.agents, seed)
                errors[name].append(error)
                print(f"| {seed} | {name} | {error:.4f} | {saturated:.1f} | {close} |", flush=True)
    finally:
        drive.pass_sides = away
    for name, values in errors.items():
        e = np.array(values)
        print(f"| mean | {name} | {e.mean():.4f} (median {np.median(e):.4f}) | | |")


if __name__ == "__main__":
    main()
