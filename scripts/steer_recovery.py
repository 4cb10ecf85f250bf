"""How fast the team recovers from a steering request: e_a after 1 m translations.

Usage: .venv/bin/python scripts/steer_recovery.py [--agents 10] [--moves 3] [--out runs/steer]

Runs ``covswarm run --scenario live`` (real processes), lets the team settle for SETTLE s in
the still S, then sends ``--moves`` translations of 1 m (alternately +x and -x, each at the
coordinator's default speed, i.e. its --max-domain-speed), GAP s apart, with the Python
SteeringClient. From the run's error.csv it prints, per request: how long S moved, the
steady-state level (the largest e_a over the WINDOW s before the request: the top of its
steady band), the peak e_a, and the recovery time: from the request until the first sample
from which e_a stays within SLACK of that level up to the next request.
"""

from __future__ import annotations

import json
import secrets
import signal
import subprocess
import time
from pathlib import Path

import click
import numpy as np

from covswarm.deploy.plan import covswarm_argv

SETTLE = 20.0  # s of mission time before the first request
GAP = 20.0  # s between requests
WINDOW = 5.0  # s before a request over which its steady-state level is taken
SLACK = 1.05  # "back under the level": within 5% of the steady band's top


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


def recovery(t: np.ndarray, e: np.ndarray, t_req: float, t_next: float) -> dict[str, float]:
    """Figures of one request at ``t_req`` from e_a samples (t, e) up to ``t_next``."""
    before = e[(t >= t_req - WINDOW) & (t < t_req)]
    level = float(before.max())
    after = (t >= t_req) & (t < t_next)
    ta, ea = t[after], e[after]
    above = np.flatnonzero(ea > SLACK * level)
    if not above.size:
        back = 0.0  # never left its steady band
    elif above[-1] + 1 < ta.size:
        back = float(ta[above[-1] + 1] - t_req)
    else:
        back = float("nan")  # not back before the next request
    return {"level": level, "peak": float(ea.max()), "recovery": back}


@click.command()
@click.option("--agents", type=int, default=10, show_default=True)
@click.option("--moves", type=int, default=3, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/steer-recovery"))
def main(agents: int, moves: int, out: Path) -> None:
    """Steer a live team by 1 m ``--moves`` times and print the recovery table."""
    import zenoh

    from covswarm.coordinator.steer_client import SteeringClient
    from covswarm.protocol import domain_key, session_config

    swarm = f"steer-{secrets.token_hex(4)}"
    duration = SETTLE + moves * GAP
    launcher = subprocess.Popen(
        [*covswarm_argv(), "run", "--scenario", "live", "--agents", str(agents),
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
            for k in range(moves):
                wait_for(lambda k=k: mission_time(domains) >= SETTLE + k * GAP, 600)
                replies.append(steer.translate(1.0 if k % 2 == 0 else -1.0, 0.0))
                click.echo(f"request {k + 1}: {replies[-1]}", err=True)
        if launcher.wait(timeout=duration + 120) != 0:
            raise click.ClickException(f"covswarm run failed: see {out}/logs")
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGTERM)
            launcher.wait(timeout=60)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    t, e = np.loadtxt(out / "error.csv", delimiter=",", skiprows=1, unpack=True)
    times = [r["t"] for r in summary["steering"] if r["accepted"]]
    click.echo(
        "| request | S moves (s) | e_a before: top of steady band (m) | e_a peak (m) "
        "| back under it after (s) |"
    )
    click.echo("|---|---|---|---|---|")
    for k, (t_req, reply) in enumerate(zip(times, replies, strict=True)):
        t_next = times[k + 1] if k + 1 < len(times) else float(t[-1]) + 1.0
        fig = recovery(t, e, t_req, t_next)
        click.echo(
            f"| {k + 1}: 1 m at t = {t_req:.1f} s | {reply.duration:.2f} | {fig['level']:.4f} "
            f"| {fig['peak']:.4f} | {fig['recovery']:.2f} |"
        )


if __name__ == "__main__":
    main()
