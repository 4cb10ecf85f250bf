"""The router's cost of per-id access control: start-up and put -> subscriber latency.

Usage: .venv/bin/python scripts/secure_acl_cost.py [--ids 1000] [--repeats 4]
       [--samples 1000] [--dir runs/acl-cost]

Issues credentials for ``--ids`` agents and robots (protocol.security: one subject, one
policy and two rules per identity), then alternately starts a secured router process with
the access-control list and the same router with it disabled, ``--repeats`` times each.
For each it prints the time of ``zenoh.open`` in the router process, a client's connection
time, and the one-way latency of ``--samples`` 64-byte puts from the last agent to its
robot (both clients of the router, one put in flight at a time). docs/security.md quotes it.
"""

from __future__ import annotations

import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import click
import zenoh

from covswarm.protocol.security import issue_credentials
from covswarm.protocol.session import session_config

ROUTER = """
import signal, sys, time, zenoh
from pathlib import Path
from covswarm.protocol import session_config
config = session_config(None, [sys.argv[1]], mode="router", secure=Path(sys.argv[2]))
if sys.argv[3] == "off":
    config.insert_json5("access_control/enabled", "false")
start = time.perf_counter()
with zenoh.open(config):
    print(f"{time.perf_counter() - start:.3f}", flush=True)
    signal.pause()  # until SIGTERM
"""


def free_endpoint() -> str:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tls/127.0.0.1:{probe.getsockname()[1]}"


def measure(folder: Path, last: int, acl: str, samples: int) -> str:
    """One router process (access control ``acl`` "on"/"off"): a line of results."""
    endpoint = free_endpoint()
    router = subprocess.Popen(
        [sys.executable, "-c", ROUTER, endpoint, str(folder), acl],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        opened = float(router.stdout.readline())
        start = time.perf_counter()
        robot = zenoh.open(session_config([endpoint], secure=folder, role="robot", id=last))
        connect_ms = (time.perf_counter() - start) * 1e3
        agent = zenoh.open(session_config([endpoint], secure=folder, role="agent", id=last))
        arrived, sent, latencies = threading.Event(), [0.0], []

        def on_sample(_sample: zenoh.Sample) -> None:
            latencies.append(time.perf_counter() - sent[0])
            arrived.set()

        key = f"covswarm/acl-cost/robot/{last}/cmd"
        robot.declare_subscriber(key, on_sample)
        publisher = agent.declare_publisher(key)
        time.sleep(1.0)  # the subscription reaches the router and the publisher
        for _ in range(samples):
            arrived.clear()
            sent[0] = time.perf_counter()
            publisher.put(b"x" * 64)
            arrived.wait(1.0)
            time.sleep(0.005)
        agent.close()
        robot.close()
    finally:
        router.terminate()
        router.wait(timeout=30)
    latencies.sort()
    median, p90 = statistics.median(latencies), latencies[int(0.9 * len(latencies))]
    return (
        f"acl {acl:3}: router open {opened:.3f} s, client connect {connect_ms:.0f} ms, "
        f"latency n={len(latencies)} median {median * 1e6:.0f} us p90 {p90 * 1e6:.0f} us"
    )


@click.command()
@click.option("--ids", type=click.IntRange(1), default=1000, show_default=True)
@click.option("--repeats", type=click.IntRange(1), default=4, show_default=True)
@click.option("--samples", type=click.IntRange(10), default=1000, show_default=True)
@click.option("--dir", "folder", type=click.Path(path_type=Path), default=Path("runs/acl-cost"))
def main(ids: int, repeats: int, samples: int, folder: Path) -> None:
    start = time.perf_counter()
    issue_credentials(folder, agents=range(ids), robots=range(ids))
    click.echo(f"credentials for {ids} agents + {ids} robots: {time.perf_counter() - start:.1f} s")
    for _ in range(repeats):
        for acl in ("on", "off"):
            click.echo(measure(folder, ids - 1, acl, samples))


if __name__ == "__main__":
    main()
