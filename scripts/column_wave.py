"""The start wave down a column of robots: what the safety filter's headway does to a column
that S sets moving, and how latency meets a column at the safe distance.

Usage: .venv/bin/python scripts/column_wave.py [--seeds 5] [--part headway|oracle|latency]

Seven robots in a column one robot wide, ``spacing`` m apart, each at the centre of its cell
of S facing +y; S's speed ramps from 0 to ``speed`` over ``ramp`` s; the agents' closed loop
of covswarm.deploy.netsim (real brains and robot models, every message ``transit`` s late).
Prints markdown tables (mean over seeds, the range in brackets) of, 6 s after S reached
its speed, the gaps between consecutive robots against the filter's headway
d*(v) (tests/columns.py: the split's clip and the receding credit) and the lags behind S
(m), front to tail; the closest two robots ever came (m) and for how long two were within
the safe distance (pair-seconds); the body diameter is 0.14 m. docs/scaling.md and
docs/real-robots.md quote it.

Parts: ``headway`` (spacings, speeds and ramps); ``oracle`` (each brain's safety filter
given the true current velocities of the robots near it instead of the ones their
AgentStates reported: whether the age of those velocities matters); ``latency`` (every
message 0.001-0.1 s late, the commands up to 0.1 s later still, the agents told a command
latency of 0-0.2 s).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from columns import SAFE, headway, pair_distances, run_column  # noqa: E402

from covswarm.agent import brain as brain_module  # noqa: E402
from covswarm.sim_robot import process as robot_process  # noqa: E402
from covswarm.tvd.drive import KHEPERA_IV, twist_from_wheels  # noqa: E402
from covswarm.tvd.safety import SAFETY_RADIUS  # noqa: E402

ROBOTS: list = []  # the simulated robots of the run going on (oracle)


class _Registered(robot_process.RobotSim):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        ROBOTS.append(self)


_safety_inputs = brain_module.AgentBrain._safety_inputs


def _true_velocities(self, begun, velocity, x, y):
    """AgentBrain._safety_inputs, the near robots' velocities replaced by their wheels'."""
    filtering = _safety_inputs(self, begun, velocity, x, y)
    ids = self.neighborhood.table_ids[self.neighborhood.within(x, y, SAFETY_RADIUS)].tolist()
    near = filtering.near.copy()
    for row, rid in enumerate(ids):
        robot = ROBOTS[rid]
        left, right = np.clip(robot.wheels, -KHEPERA_IV.max_wheel_speed, KHEPERA_IV.max_wheel_speed)
        forward, _ = twist_from_wheels(float(left), float(right), KHEPERA_IV.wheel_separation)
        near[row, 2:] = forward * math.cos(robot.pose[2]), forward * math.sin(robot.pose[2])
    filtering.near = near
    return filtering


def run(
    spacing, speed, ramp, seed, transit=0.001, latency=0.0, oracle=False, command_delay=0.0
) -> dict:
    ROBOTS.clear()
    robot_process.RobotSim, real = _Registered, robot_process.RobotSim
    if oracle:
        brain_module.AgentBrain._safety_inputs = _true_velocities
    try:
        result, poses, shift = run_column(
            spacing, speed, seed, ramp, transit, command_delay, latency
        )
    finally:
        robot_process.RobotSim = real
        brain_module.AgentBrain._safety_inputs = _safety_inputs
    y = result.trajectories[-1][:, 1]
    lags = shift(float(result.t[-1])) - (y - poses[:, 1])
    pairs = pair_distances(result.trajectories)
    sample = float(np.diff(result.t).mean())
    return {
        "gaps": np.diff(y)[::-1],  # front to tail
        "lags": lags[::-1],
        "closest": float(pairs.min()),
        "within": float((pairs < SAFE - 1e-9).sum() * sample),
    }


def summary(runs: list[dict]) -> list[str]:
    def spread(values) -> str:
        values = np.asarray(values)
        return f"{values.mean():.4f} [{values.min():.4f}-{values.max():.4f}]"

    gaps = np.array([r["gaps"] for r in runs])
    lags = np.array([r["lags"] for r in runs])
    return [
        f"{gaps.min():.4f}-{gaps.max():.4f}",
        " ".join(f"{v:.3f}" for v in lags.mean(axis=0)),
        spread([r["closest"] for r in runs]),
        spread([r["within"] for r in runs]),
    ]


def table(header: list[str], rows: list[list[str]]) -> None:
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print(flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--part", choices=("headway", "oracle", "latency"), action="append")
    args = parser.parse_args()
    parts = args.part or ["headway", "oracle", "latency"]
    seeds = range(args.seeds)
    measured = ["gaps (m)", "lags, front to tail (m)", "closest (m)", "pair-s within D"]
    if "headway" in parts:
        rows = []
        for spacing, speed, ramp in (
            (0.165, 0.19, 2.0),
            (0.165, 0.19, 0.5),
            (0.165, 0.19, 4.0),
            (0.17, 0.19, 2.0),
            (0.18, 0.19, 2.0),
            (0.19, 0.19, 2.0),
            (0.165, 0.10, 2.0),
            (0.165, 0.30, 2.0),
        ):
            runs = [run(spacing, speed, ramp, seed) for seed in seeds]
            rows.append(
                [f"{spacing}", f"{speed}", f"{ramp}", f"{headway(speed):.4f}", *summary(runs)]
            )
        table(["spacing (m)", "speed (m/s)", "ramp (s)", "d*(v) (m)", *measured], rows)
    if "oracle" in parts:
        rows = []
        for oracle in (False, True):
            runs = [run(0.165, 0.19, 2.0, seed, oracle=oracle) for seed in seeds]
            rows.append(["true velocities" if oracle else "AgentStates'", *summary(runs)])
        table(["near robots' velocities in the filter", *measured], rows)
    if "latency" in parts:
        rows = []
        for transit, delay, latency in (
            (0.001, 0.0, 0.0),
            (0.001, 0.1, 0.0),
            (0.001, 0.1, 0.1),
            (0.001, 0.0, 0.15),
            (0.05, 0.05, 0.0),
            (0.05, 0.05, 0.1),
            (0.1, 0.0, 0.0),
            (0.1, 0.0, 0.1),
            (0.1, 0.0, 0.2),
        ):
            runs = [
                run(0.165, 0.19, 2.0, seed, transit, latency, command_delay=delay) for seed in seeds
            ]
            rows.append([f"{transit}", f"{delay}", f"{latency}", *summary(runs)])
        header = ["every message late (s)", "commands later still (s)", "--command-latency (s)"]
        table([*header, *measured], rows)


if __name__ == "__main__":
    main()
