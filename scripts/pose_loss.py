"""e_a against pose loss: ``covswarm run`` on the passage with 10 robots per loss rate.

Usage: .venv/bin/python scripts/pose_loss.py [--loss 0,0.1,0.3,0.5] [--out runs/pose-loss]
Prints a Markdown table (docs/faults.md) of the steady-state (second half), final and peak
(after the first 10 s of convergence) e_a of each run. Each run takes about a minute.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import click
import numpy as np

from covswarm.deploy.plan import covswarm_argv

SETTLED = 10.0  # s: the random start has converged by then in a healthy run


def run_once(loss: float, out: Path, agents: int, delay: float) -> dict:
    """One run at ``loss``; its summary plus the peak e_a after SETTLED."""
    shutil.rmtree(out, ignore_errors=True)  # this script's own folder: a run needs a new one
    subprocess.run(
        [*covswarm_argv(), "run", "--scenario", "passage", "--agents", str(agents),
         "--pose-loss", repr(loss), "--pose-delay", repr(delay), "--out", str(out)],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    t, e = np.loadtxt(out / "error.csv", delimiter=",", skiprows=1, unpack=True)
    summary["peak_after_settling"] = float(e[t >= SETTLED].max())
    return summary


@click.command()
@click.option("--loss", "losses", default="0,0.1,0.3,0.5", show_default=True)
@click.option("--delay", type=float, default=0.0, show_default=True, help="Pose delay, s.")
@click.option("--agents", type=int, default=10, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/pose-loss"))
def main(losses: str, delay: float, agents: int, out: Path) -> None:
    """Run the passage once per loss rate and print the table."""
    rows = []
    for loss in (float(v) for v in losses.split(",")):
        s = run_once(loss, out / f"loss-{loss:g}", agents, delay)
        rows.append(
            f"| {loss:.0%} | {s['steady_state_error_mean']:.4f} | {s['final_error']:.4f} "
            f"| {s['peak_after_settling']:.4f} |"
        )
        click.echo(rows[-1], err=True)
    click.echo("| pose loss | e_a steady state (m) | e_a final (m) | e_a peak after 10 s (m) |")
    click.echo("|---|---|---|---|")
    click.echo("\n".join(rows))


if __name__ == "__main__":
    main()
