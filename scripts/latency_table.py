"""e_a against pose delay and loss: ``covswarm run`` on the passage, 10 robots, one run each.

Usage: .venv/bin/python scripts/latency_table.py [--delays 0,0.1,0.2,0.3] [--losses 0,0.3]
       [--agents 10] [--out runs/latency] [--extra "--no-safety"] [--replica]

Prints the Markdown table of README.md / docs/faults.md: per (delay, loss), the steady-state
(second half) and final e_a, the closest two robots came and the close approaches (pairs
nearer than a diameter; robots start a diameter apart), and the agents' measured
pose-to-command latency (team mean of their p50) and the worst agent's share of missed
control deadlines (a loaded machine shows there first). ``--extra`` options go to every run
(e.g. ``--no-safety`` or ``--no-prediction``, to compare). Each run takes about a minute.

``--replica`` runs each case in covswarm.deploy.netsim instead (the same brains and robot
simulations on a simulated clock, in one process, deterministic, seconds per run): what the
agents do with the given delay and loss, free of what a loaded machine adds (missed
deadlines are then 0 by construction); ``--extra`` then understands ``--no-safety`` and
``--no-prediction``.
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
from pathlib import Path

import click

from covswarm.deploy.plan import covswarm_argv


def run_once(out: Path, agents: int, delay: float, loss: float, extra: list[str]) -> dict:
    """One run; its summary.json."""
    shutil.rmtree(out, ignore_errors=True)  # this script's own folder: a run needs a new one
    subprocess.run(
        [*covswarm_argv(), "run", "--scenario", "passage", "--agents", str(agents),
         "--pose-delay", repr(delay), "--pose-loss", repr(loss), "--out", str(out), *extra],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def replica_once(agents: int, delay: float, loss: float, extra: list[str]) -> dict:
    """One case in deploy.netsim; the summary.json keys the table reads."""
    from covswarm.agent.brain import AgentConfig
    from covswarm.coordinator.monitor import agent_figures
    from covswarm.deploy.netsim import run_netsim, steady_state
    from covswarm.mission.physical import physical_summary
    from covswarm.mission.scenario_files import load_scenario

    unknown = set(extra) - {"--no-safety", "--no-prediction"}
    if unknown:
        raise click.UsageError(f"--replica does not understand {sorted(unknown)}")
    config = AgentConfig(
        pose_delay=delay,
        pose_loss=loss,
        safety="--no-safety" not in extra,
        prediction="--no-prediction" not in extra,
    )
    scenario = load_scenario("passage")
    result = run_netsim(scenario, agents=agents, config=config)
    return {
        "steady_state_error_mean": steady_state(result),
        "final_error": float(result.error[-1]),
        **physical_summary(result.t, result.trajectories, scenario.robot_diameter)[0],
        "agent_stats": agent_figures(result.stats),
    }


def row(delay: float, loss: float, summary: dict) -> str:
    """One Markdown row of the table."""
    closest = summary["min_pairwise_distance"]
    team = summary["agent_stats"]["team"]
    age = team.get("pose_age_ms_p50", {}).get("mean", float("nan"))
    missed = team.get("missed_deadline", {}).get("max", float("nan"))
    return (
        f"| {delay:g} s | {loss:.0%} | {summary['steady_state_error_mean']:.4f} "
        f"| {summary['final_error']:.4f} | {closest:.3f} | {summary['close_approaches']} "
        f"| {age:.0f} | {missed:.1%} |"
    )


@click.command()
@click.option("--delays", default="0,0.1,0.2,0.3", show_default=True, help="Pose delays, s.")
@click.option("--losses", default="0,0.3", show_default=True, help="Pose loss fractions.")
@click.option("--agents", type=int, default=10, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/latency"))
@click.option("--extra", default="", help="More `covswarm run` options for every run.")
@click.option("--replica", is_flag=True, help="In covswarm.deploy.netsim, not real processes.")
def main(delays: str, losses: str, agents: int, out: Path, extra: str, replica: bool) -> None:
    """Run the passage once per (delay, loss) and print the table."""
    rows = []
    options = shlex.split(extra)
    for delay in (float(v) for v in delays.split(",")):
        for loss in (float(v) for v in losses.split(",")):
            if replica:
                summary = replica_once(agents, delay, loss, options)
            else:
                folder = out / f"delay-{delay:g}-loss-{loss:g}"
                summary = run_once(folder, agents, delay, loss, options)
            rows.append(row(delay, loss, summary))
            click.echo(rows[-1], err=True)
    click.echo(
        "| pose delay | pose loss | e_a steady state (m) | e_a final (m) | closest (m) "
        "| close approaches | pose-to-command latency p50 (ms) "
        "| missed deadlines (worst agent) |"
    )
    click.echo("|---|---|---|---|---|---|---|---|")
    click.echo("\n".join(rows))


if __name__ == "__main__":
    main()
