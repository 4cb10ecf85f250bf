"""What recording costs the coordinator: the same mission with and without run.mcap.

Usage: .venv/bin/python scripts/recording_cost.py [--agents 100] [--duration 30]
       [--repeats 2] [--out runs/recording-cost]

Each run starts the team with ``covswarm run --no-coordinator`` (robots and agents, 50 per
process, an embedded router) and the coordinator separately, so the coordinator's CPU time
is read exactly from its own rusage (os.wait4). Runs alternate: with recording, without
(``--no-record``), with, ... Prints a Markdown table (README) and writes
OUT/recording_cost.json: per run the coordinator's CPU seconds, its mission time, the wall
CPU time it logged for recording, and the size of run.mcap per robot-minute.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import subprocess
import time
from pathlib import Path

import click

from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port

RECORDING_LINE = re.compile(r"recording took ([0-9.]+) s of CPU over ([0-9.]+) s of mission")


def run_once(out: Path, scenario: str, agents: int, duration: float, record: bool) -> dict:
    """One mission; the coordinator's CPU seconds (user + system) and what it recorded."""
    swarm = f"cost-{secrets.token_hex(4)}"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out.mkdir(parents=True, exist_ok=True)
    team_log = (out / "team.log").open("wb")
    team = subprocess.Popen(
        [*covswarm_argv(), "run", "--no-coordinator", "--swarm", swarm, "--scenario", scenario,
         "--agents", str(agents), "--agents-per-process", "50", "--router-listen", endpoint,
         "--out", str(out / "team")],
        stdout=team_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    time.sleep(2.0)  # the embedded router listens before the coordinator connects
    coordinator_log = (out / "coordinator.log").open("wb")
    coordinator = subprocess.Popen(
        [*covswarm_argv(), "coordinator", "--connect", endpoint, "--swarm", swarm,
         "--scenario", scenario, "--agents", str(agents), "--duration", repr(duration),
         "--out", str(out), *(() if record else ("--no-record",))],
        stdout=coordinator_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    _, status, usage = os.wait4(coordinator.pid, 0)
    coordinator.returncode = os.waitstatus_to_exitcode(status)
    team.wait(timeout=120)
    team_log.close()
    coordinator_log.close()
    if coordinator.returncode != 0:
        raise click.ClickException(f"coordinator failed: see {out / 'coordinator.log'}")
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    result = {
        "record": record,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "mission_s": summary["mission_time"],
        "steady_state_error_mean": summary["steady_state_error_mean"],
    }
    if record:
        found = RECORDING_LINE.search((out / "coordinator.log").read_text(encoding="utf-8"))
        result["recording_cpu_s"] = float(found.group(1)) if found else None
        size = (out / "run.mcap").stat().st_size
        result["mcap_bytes"] = size
        result["mcap_kb_per_robot_minute"] = size / 1e3 / (agents * summary["mission_time"] / 60)
    return result


@click.command()
@click.option("--scenario", default="circle", show_default=True)
@click.option("--agents", type=int, default=100, show_default=True)
@click.option("--duration", type=float, default=30.0, show_default=True)
@click.option("--repeats", type=int, default=2, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/recording-cost"))
def main(scenario: str, agents: int, duration: float, repeats: int, out: Path) -> None:
    runs = []
    for k in range(repeats):
        for record in (True, False):
            name = f"{k}-{'record' if record else 'no-record'}"
            click.echo(f"run {name}: {agents} robots, {duration:g} s ...", err=True)
            runs.append(run_once(out / name, scenario, agents, duration, record))
    (out / "recording_cost.json").write_text(json.dumps(runs, indent=2) + "\n", encoding="utf-8")
    click.echo(
        "| run | coordinator CPU, start to exit (s) | recording CPU, logged (s) "
        "| run.mcap (KB per robot-minute) |"
    )
    click.echo("|---|---|---|---|")
    for r in runs:
        logged = r.get("recording_cpu_s")
        size = r.get("mcap_kb_per_robot_minute")
        click.echo(
            f"| {'with' if r['record'] else 'without'} recording | {r['cpu_s']:.2f} | "
            f"{'-' if logged is None else f'{logged:.2f}'} | "
            f"{'-' if size is None else f'{size:.0f}'} |"
        )
    with_cpu = [r["cpu_s"] for r in runs if r["record"]]
    without = [r["cpu_s"] for r in runs if not r["record"]]
    extra = (sum(with_cpu) / len(with_cpu) - sum(without) / len(without)) / duration
    click.echo(f"\nrecording: {100 * extra:+.2f} % of a core (mean with - mean without)")


if __name__ == "__main__":
    main()
