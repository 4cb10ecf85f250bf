"""What recording costs the coordinator: the same mission with and without run.mcap.

Usage: .venv/bin/python scripts/recording_cost.py [--agents 100] [--duration 30]
       [--repeats 2] [--out runs/recording-cost]

Each run starts the team with ``covswarm run --no-coordinator`` (robots and agents, 50 per
process, an embedded router) and the coordinator separately, so the coordinator's CPU time
is read exactly from its own rusage (os.wait4). Runs alternate: with recording, with
recording but not the AgentStates (``--no-record-states``), without (``--no-record``),
with, ... Prints a Markdown table (docs/records.md) and writes
OUT/recording_cost.json: per run the coordinator's CPU seconds, its mission time, the wall
CPU time it logged for recording, and the size of run.mcap per robot-minute.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import socket
import subprocess
import time
from pathlib import Path

import click

from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port

LISTEN_TIMEOUT = 60.0  # s: the launcher times the host before it starts its router


def wait_listening(port: int, timeout: float = LISTEN_TIMEOUT) -> None:
    """Until 127.0.0.1:``port`` accepts a connection (the team's router is up)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise click.ClickException(f"no router on port {port} after {timeout} s") from None
            time.sleep(0.2)


RECORDING_LINE = re.compile(r"recording took ([0-9.]+) s of CPU over ([0-9.]+) s of mission")


def run_once(
    out: Path, scenario: str, agents: int, duration: float, record: bool, states: bool = True
) -> dict:
    """One mission; the coordinator's CPU seconds (user + system) and what it recorded
    (``states``: the agents' AgentStates too, /agents/states)."""
    swarm = f"cost-{secrets.token_hex(4)}"
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    out.mkdir(parents=True, exist_ok=True)
    team_log = (out / "team.log").open("wb")
    team = subprocess.Popen(
        [*covswarm_argv(), "run", "--no-coordinator", "--swarm", swarm, "--scenario", scenario,
         "--agents", str(agents), "--agents-per-process", "50", "--router-listen", endpoint,
         "--out", str(out / "team")],
        stdout=team_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    wait_listening(port)
    coordinator_log = (out / "coordinator.log").open("wb")
    coordinator = subprocess.Popen(
        [*covswarm_argv(), "coordinator", "--connect", endpoint, "--swarm", swarm,
         "--scenario", scenario, "--agents", str(agents), "--duration", repr(duration),
         "--out", str(out), *(() if record else ("--no-record",)),
         *(() if states else ("--no-record-states",))],
        stdout=coordinator_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    _, status, usage = os.wait4(coordinator.pid, 0)
    coordinator.returncode = os.waitstatus_to_exitcode(status)
    coordinator_log.close()
    if coordinator.returncode != 0:
        team.terminate()  # the team would wait for a mission that never comes
        team.wait(timeout=30)
        team_log.close()
        raise click.ClickException(f"coordinator failed: see {out / 'coordinator.log'}")
    team.wait(timeout=120)
    team_log.close()
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    result = {
        "record": record,
        "states": record and states,
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
    # (record, record the AgentStates) per variant, interleaved in each repeat
    variants = {
        "record": (True, True),
        "record-no-states": (True, False),
        "no-record": (False, False),
    }
    labels = {
        "record": "with recording",
        "record-no-states": "with recording, no AgentStates",
        "no-record": "without recording",
    }
    runs = []
    for k in range(repeats):
        for variant, (record, states) in variants.items():
            name = f"{k}-{variant}"
            click.echo(f"run {name}: {agents} robots, {duration:g} s ...", err=True)
            run = run_once(out / name, scenario, agents, duration, record, states)
            runs.append({"variant": variant, **run})
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
            f"| {labels[r['variant']]} | {r['cpu_s']:.2f} | "
            f"{'-' if logged is None else f'{logged:.2f}'} | "
            f"{'-' if size is None else f'{size:.0f}'} |"
        )
    mean = {
        variant: sum(r["cpu_s"] for r in runs if r["variant"] == variant) / repeats
        for variant in variants
    }
    for variant in ("record", "record-no-states"):
        extra = (mean[variant] - mean["no-record"]) / duration
        click.echo(f"{labels[variant]}: {100 * extra:+.2f} % of a core (mean - mean without)")


if __name__ == "__main__":
    main()
