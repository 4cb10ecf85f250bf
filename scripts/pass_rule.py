"""How the pass rule's constants do: e_a, saturated wheels and close approaches per setting.

Usage: .venv/bin/python scripts/pass_rule.py [--seeds 8] [--agents 1000]
       [--scenario scenarios/circle-1000.toml]

``covswarm sim --scenario SCENARIO --dt 0.1 --dynamics unicycle --projection-distance 0.05
--safety`` (covswarm.deploy.simulate, the robots as placed) per seed, with
covswarm.tvd.drive's PASS_ANGLE (rad: how far left of its aim a robot held back veers; 0:
it faces its aim) and PASS_BELOW (the forward speed, as a share of what it asks for, from
which it no longer veers) set to each pair of a grid around main's (1.0, 0.5). Prints a
markdown table: e_a's second-half mean over the seeds, its median and [range] (m), the
saturated wheels (robot-s) and the close approaches (pairs nearer than a body) summed over
the seeds. docs/scaling.md quotes it (~10 s a run at 1000 robots).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from covswarm.deploy.simulate import simulate
from covswarm.mission.physical import proximity, wheel_figures
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import drive

SETTINGS = [(0.0, 0.5)] + [(a, b) for a in (0.5, 1.0, 1.5) for b in (0.3, 0.5, 0.8)]


def figures(scenario: Any, agents: int, seed: int) -> tuple[float, float, int]:
    """One run of the module docstring's ``covswarm sim`` with the constants as set: e_a's
    second-half mean (m), the saturated wheels (robot-s) and the close approaches."""
    result = simulate(
        scenario,
        agents=agents,
        dt=0.1,
        dynamics="unicycle",
        projection_distance=0.05,
        safety=True,
        seed=seed,
    )
    error = float(result.error[result.t >= 0.5 * result.t[-1]].mean())
    assert result.wheels is not None
    wheels = wheel_figures(result.t, result.wheels, drive.KHEPERA_IV.max_wheel_speed)
    close = len(proximity(result.t, result.trajectories, scenario.robot_diameter)[2])
    return error, wheels["saturated_time"], close


def arguments(doc: str) -> argparse.Namespace:
    """--seeds, --agents and --scenario, as a script's documentation ``doc`` gives them."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--agents", type=int, default=1000)
    parser.add_argument("--scenario", default="scenarios/circle-1000.toml")
    return parser.parse_args()


def main() -> None:
    args = arguments(__doc__)
    scenario = load_scenario(args.scenario)
    main_setting = (drive.PASS_ANGLE, drive.PASS_BELOW)
    print(
        "| PASS_ANGLE (rad) | PASS_BELOW | e_a 2nd half, mean | median [range] (m) "
        "| saturated (robot-s) | close approaches |"
    )
    print("|---|---|---|---|---|---|")
    try:
        for angle, below in SETTINGS:
            drive.PASS_ANGLE, drive.PASS_BELOW = angle, below
            errors, saturated, close = [], 0.0, 0
            for seed in range(args.seeds):
                error, wheels, approaches = figures(scenario, args.agents, seed)
                errors.append(error)
                saturated += wheels
                close += approaches
            e = np.array(errors)
            name = " (main)" if (angle, below) == main_setting else ""
            cells = [
                f"{angle}{name}",
                "-" if angle == 0.0 else f"{below}",
                f"{e.mean():.4f}",
                f"{np.median(e):.4f} [{e.min():.4f}-{e.max():.4f}]",
                f"{saturated / args.seeds:.1f}",
                f"{close}",
            ]
            print("| " + " | ".join(cells) + " |", flush=True)
    finally:
        drive.PASS_ANGLE, drive.PASS_BELOW = main_setting


if __name__ == "__main__":
    main()
