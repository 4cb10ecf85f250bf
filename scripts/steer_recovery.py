"""How fast the team recovers from a steering request: e_a after 1 m translations.

Usage: .venv/bin/python scripts/steer_recovery.py [--agents 10] [--speeds default,0.25,0.1]
       [--repeats 2] [--out runs/steer-recovery]

Runs ``covswarm run --scenario live`` (real processes), lets the team settle for SETTLE s in
the still S, then sends 1 m translations (alternately +x and -x), GAP s apart, with the
Python SteeringClient: ``--repeats`` at each speed of ``--speeds`` (m/s of S's fastest
vertex; "default": the coordinator's --max-domain-speed). From the run's error.csv it
prints, per request: how long S moved, e_a's level before it (the mean over the WINDOW s
before the request), the peak, and the time from the request until e_a is back under
SLACK x that level, and under ABSOLUTE, for good (up to the next request).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import time
from pathlib import Path

import click
import numpy as np

from covswarm.deploy.plan import covswarm_argv

SETTLE = 30.0  # s of mission time before the first request
GAP = 30.0  # s between requests
WINDOW = 5.0  # s before a request over which its steady-state level is taken
SLACK = 2.0  # "back under its level": e_a's floor depends on the robots' headings (the
# control point is 3 cm ahead of the axle), which a translation changes
ABSOLUTE = 0.01  # m


def wait_for(predicate, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise click.ClickException("timed out waiting for the run")
        time.sleep(0.1)


def mission_time(subscriber) -> float:
    """Mission time of the coordinator's newest Domain broadcast (a RingChannel(1) one)."""
    from covswarm.protocol import Domain

    return Domain.decode(subscriber.recv().payload.to_bytes()).t


def settled_after(t: np.ndarray, e: np.ndarray, bound: float) -> float:
    """Time from t[0] to the first sample from which e stays <= bound (nan: never)."""
    above = np.flatnonzero(e > bound)
    if not above.size:
        return 0.0
    return float(t[above[-1] + 1] - t[0]) if above[-1] + 1 < t.size else float("nan")


def recovery(t: np.ndarray, e: np.ndarray, t_req: float, t_next: float) -> dict[str, float]:
    """Figures of one request at ``t_req`` from e_a samples (t, e) up to ``t_next``."""
    level = float(e[(t >= t_req - WINDOW) & (t < t_req)].mean())
    after = (t >= t_req) & (t < t_next)
    ta = np.concatenate([[t_req], t[after]])
    ea = np.concatenate([[level], e[after]])
    return {
        "level": level,
        "peak": float(ea.max()),
        "relative": settled_after(ta, ea, SLACK * level),
        "absolute": settled_after(ta, ea, ABSOLUTE),
    }


@click.command()
@click.option("--scenario", default="live", show_default=True, help="Any scenario: S is steered.")
@click.option("--agents", type=int, default=10, show_default=True)
@click.option("--speeds", default="default,0.25,0.1", show_default=True)
@click.option("--repeats", type=int, default=2, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/steer-recovery"))
def main(scenario: str, agents: int, speeds: str, repeats: int, out: Path) -> None:
    """Steer a live team by 1 m at each speed and print the recovery table."""
    import zenoh

    from covswarm.coordinator.steer_client import SteeringClient
    from covswarm.protocol import domain_key, session_config
    from covswarm.protocol.steering import SteerRequest

    swarm = f"steer-{secrets.token_hex(4)}"
    plan = [None if v == "default" else float(v) for v in speeds.split(",") for _ in range(repeats)]
    duration = SETTLE + len(plan) * GAP
    shutil.rmtree(out, ignore_errors=True)  # this script's own folder: a run needs a new one
    launcher = subprocess.Popen(
        [*covswarm_argv(), "run", "--scenario", scenario, "--agents", str(agents),
         "--duration", repr(duration), "--swarm", swarm, "--out", str(out)],
        stdout=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        log = out / "logs" / "coordinator-0.log"
        wait_for(lambda: log.exists() and "mission started" in log.read_text(), 300)
        endpoint = json.loads((out / "launch.json").read_text())["endpoint"]
        replies = []
        with zenoh.open(session_config([endpoint])) as session:
            domains = session.declare_subscriber(domain_key(swarm), zenoh.handlers.RingChannel(1))
            steer = SteeringClient(session, swarm, timeout=5.0)
            for k, speed in enumerate(plan):
                wait_for(lambda k=k: mission_time(domains) >= SETTLE + k * GAP, 600)
                request = SteerRequest("translate", dx=1.0 - 2.0 * (k % 2), speed=speed)
                replies.append(steer.request(request))
                click.echo(f"request {k + 1}: {replies[-1]}", err=True)
        if launcher.wait(timeout=duration + 120) != 0:
            raise click.ClickException(f"covswarm run failed: see {out}/logs")
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGTERM)
            launcher.wait(timeout=60)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    t, e = np.loadtxt(out / "error.csv", delimiter=",", skiprows=1, unpack=True)
    # e_a is sampled less often when the coordinator is starved: say how well it was sampled.
    click.echo(
        f"load average {os.getloadavg()[0]:.1f} at the end; e_a samples {t.size}, longest gap "
        f"{np.diff(t).max():.2f} s"
    )
    times = [r["t"] for r in summary["steering"] if r["accepted"]]
    click.echo(
        f"| request | S moves (s) | e_a before (m) | e_a peak (m) | back under {SLACK:g}x "
        f"before (s) | back under {ABSOLUTE:g} m (s) |"
    )
    click.echo("|---|---|---|---|---|---|")
    for k, (t_req, reply) in enumerate(zip(times, replies, strict=True)):
        t_next = times[k + 1] if k + 1 < len(times) else float(t[-1]) + 1.0
        fig = recovery(t, e, t_req, t_next)
        speed = "default speed" if plan[k] is None else f"{plan[k]:g} m/s"
        click.echo(
            f"| {k + 1}: 1 m, {speed} | {reply.duration:.2f} | {fig['level']:.4f} "
            f"| {fig['peak']:.4f} | {fig['relative']:.2f} | {fig['absolute']:.2f} |"
        )


if __name__ == "__main__":
    main()
