"""A team that passes robots whose brains are dead: ``covswarm sim --still`` on a crowded
mission, under three rules: as it is (the dead robots still generators of the diagram,
covswarm.tvd.control's ``still``, and a robot stopped dead at a forward speed of at most
covswarm.tvd.drive.STOPPED_SPEED); "out of cells", the dead robots left out of the
diagram before 2 Dec 2026 (every law and e_a over the moving robots alone);
"before", out of cells and stopped dead at a forward speed <= 0, as before 1 Dec 2026.

Usage: .venv/bin/python scripts/dead_robots.py [--scenario scenarios/circle-400.toml]
       [--still 10] [--seeds 0,1,2,3] [--out docs/img/dead-robots.png]

Robots 0 to still - 1 stand where they start (dead brains, the agents' stranded robots); the
rest run with the agents' settings (unicycles, the safety filter, 10 Hz, a projection
distance of 0.05 m, facing S's motion at the start). Prints, per seed and rule, the robots
left more than 5 cm outside S at the end, those inside it held more than 5 cm from their
centroids (in the rule's diagram), e_a's second-half mean and final value, the
robot-steps slid and the closest two robots came; draws seed 0's end and e_a.
"""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from unittest import mock

import click
import numpy as np
from scipy.spatial import cKDTree
from shapely.geometry import Point, Polygon

from covswarm.deploy.simulate import SimResult, simulate
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd import control, coverage, drive

RULES = ("before", "out of cells", "now")
team_step, aggregate_error = control.team_step, coverage.aggregate_error


def step_out_of_cells(law, positions, *args, still=None, **options) -> control.TeamStep:
    """``control.team_step`` with the still robots out of the diagram (velocity 0)."""
    if still is None:
        return team_step(law, positions, *args, **options)
    step = team_step(law, positions[~still], *args, **options)
    velocity, guarded = np.zeros_like(positions), np.zeros(len(positions), dtype=bool)
    velocity[~still], guarded[~still] = step.velocity, step.guarded
    return replace(step, velocity=velocity, guarded=guarded)


def error_out_of_cells(positions, polygon, density=None, still=None) -> float:
    """``coverage.aggregate_error`` of the moving robots alone."""
    return aggregate_error(positions if still is None else positions[~still], polygon, density)


def run(scenario_path: str, still: int, seed: int, rule: str) -> SimResult:
    """One run with robots 0..still-1 dead under ``rule`` (module docstring)."""
    with ExitStack() as stack:
        if rule != "now":
            stack.enter_context(mock.patch.object(control, "team_step", step_out_of_cells))
            stack.enter_context(mock.patch.object(coverage, "aggregate_error", error_out_of_cells))
        if rule == "before":
            stack.enter_context(mock.patch.object(drive, "STOPPED_SPEED", 0.0))
        return simulate(
            load_scenario(scenario_path), safety=True, dt=0.1, projection_distance=0.05,
            seed=seed, still=list(range(still)), dynamics="unicycle", face_start=True,
        )  # fmt: skip


def left_behind(result: SimResult, still: int) -> int:
    """Moving robots more than 5 cm outside S at the end."""
    final = Polygon(result.final_polygon).buffer(0.05)
    return sum(not final.contains(Point(*p)) for p in result.positions[still:])


def held_inside(result: SimResult, still: int, rule: str) -> int:
    """Moving robots inside S at the end more than 5 cm from the centroid of their cell in
    the rule's diagram (the dead robots generators of it only under "now")."""
    final = Polygon(result.final_polygon).buffer(0.05)
    points = result.positions if rule == "now" else result.positions[still:]
    _, _, batch = coverage.tessellate(points, result.final_polygon)
    offsets = points - coverage.as_vectors(batch.centroid)
    moving = range(still, len(points)) if rule == "now" else range(len(points))
    return sum(
        final.contains(Point(*points[i])) and float(np.hypot(*offsets[i])) > 0.05 for i in moving
    )


def closest(result: SimResult) -> float:
    """m: the closest any two robots came, over every step."""
    return float(min(cKDTree(f).query(f, k=2)[0][:, 1].min() for f in result.trajectories))


@click.command()
@click.option("--scenario", "scenario_path", default="scenarios/circle-400.toml", show_default=True)
@click.option("--still", type=click.IntRange(min=1), default=10, show_default=True)
@click.option("--seeds", default="0,1,2,3", show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("docs/img/dead-robots.png"))
def main(scenario_path: str, still: int, seeds: str, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown: dict[str, SimResult] = {}
    print(
        "| seed | rule | left behind | held inside S | e_a 2nd half, m | e_a final, m | slid "
        "| closest, m |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for seed in [int(s) for s in seeds.split(",")]:
        for rule in RULES:
            result = run(scenario_path, still, seed, rule)
            half = float(result.error[len(result.error) // 2 :].mean())
            print(
                f"| {seed} | {rule} | {left_behind(result, still)} | "
                f"{held_inside(result, still, rule)} | {half:.3f} | "
                f"{result.error[-1]:.3f} | {result.slid} | {closest(result):.4f} |",
                flush=True,
            )
            if not shown.get(rule):
                shown[rule] = result
    figure, axes = plt.subplots(1, 3, figsize=(16, 5.2))
    titles = {
        "before": "out of cells, stopped dead at <= 0 m/s",
        "out of cells": f"out of cells, stopped dead at <= {drive.STOPPED_SPEED:g} m/s",
        "now": "still cells (now)",
    }
    for ax, rule in zip(axes[:2], ("out of cells", "now"), strict=True):
        result = shown[rule]
        polygon = np.vstack([result.final_polygon, result.final_polygon[:1]])
        ax.fill(*polygon.T, color="C0", alpha=0.12, label="S at the end")
        ax.scatter(*result.positions[still:].T, s=9, color="C0", label="robots")
        ax.scatter(*result.positions[:still].T, s=30, color="k", marker="s", label="dead robots")
        ax.set_title(f"{titles[rule]}: {left_behind(result, still)} left behind", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(loc="lower left", fontsize=8)
    for rule, style in zip(RULES, ("C3:", "C1--", "C0-"), strict=True):
        axes[2].plot(shown[rule].t, shown[rule].error, style, label=titles[rule])
    axes[2].set_yscale("log")
    axes[2].set_xlabel("t [s]")
    axes[2].set_ylabel("e_a [m]")
    axes[2].legend(fontsize=8)
    axes[2].set_title("e_a over the mission", fontsize=10)
    figure.suptitle(
        f"{Path(scenario_path).stem}, {still} robots dead where they start (covswarm sim --still), "
        "seed 0, at the end",
        fontsize=11,
    )
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
