"""One swarm over two "hosts": two Linux network namespaces joined by a veth pair.

Each namespace runs ``covswarm run`` for half of the team with its own embedded router on
its veth address; namespace B's router connects to A's (Zenoh routes between them), and
only A runs the coordinator. A router reachable from another host listens in secured mode
only (covswarm.protocol.session.check_open_listen), so the run is secured: one secure folder
whose router certificate names both addresses, mutual TLS on every link, and each router
enforcing the access list on its own clients. A probe process in each namespace measures
the round trip between them through both routers (as the ``bridge`` and a ``ros2`` node, on
a ROS 2 key: the access list lets no one else put outside the swarm's own keys) and records
the agents' neighbour lists, which must cross the hosts. Needs root (``ip netns``): as
another user it is skipped with that reason (failed under CI=true, tests/conftest.py); as
root it runs, and fails if it cannot set up the namespaces (no iproute2, no netns support).

Namespaces, veth names and the 10.199.X.0/24 subnet are random per run (addresses live
only inside the test's own namespaces, so even equal X would not collide); everything is
removed in ``finally`` blocks, processes by pid.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from covswarm.deploy.plan import covswarm_argv
from covswarm.protocol.security import issue_credentials

pytestmark = pytest.mark.e2e

TEAM = 6  # robots 0-2 on host A, 3-5 on host B
PORT = 7447  # free by construction: nothing else listens inside a fresh namespace

# mode "pong": echo probe pings. Mode "ping": measure round trips, then record the agents'
# neighbour lists until the coordinator says "done"; prints one JSON line.
PROBE = """
import json, signal, sys, threading, time, zenoh
from covswarm.protocol import AgentState, Status, session_config
from pathlib import Path
mode, endpoint, swarm, secure = sys.argv[1:5]
base = f"0/covswarm_probe/{swarm}"  # ROS 2 domain 0's keys: the bridge and ros2 may put them
role = "ros2" if mode == "pong" else "bridge"
for attempt in range(300):  # until this namespace's launcher has its router up
    try:
        session = zenoh.open(session_config([endpoint], secure=Path(secure), role=role))
        break
    except zenoh.ZError:
        time.sleep(0.2)
with session:
    if mode == "pong":
        pub = session.declare_publisher(f"{base}/pong")
        session.declare_subscriber(f"{base}/ping", lambda s: pub.put(s.payload.to_bytes()))
        print("ready", flush=True)
        signal.pause()  # until SIGTERM
    neighbors, done, got = {}, threading.Event(), threading.Event()
    def on_state(sample):
        state = AgentState.decode(sample.payload.to_bytes())
        neighbors.setdefault(state.id, set()).update(state.neighbors)
    def on_status(sample):
        if Status.decode(sample.payload.to_bytes()).state == "done":
            done.set()
    session.declare_subscriber(f"covswarm/{swarm}/agent/*/state", on_state)
    session.declare_subscriber(f"covswarm/{swarm}/status", on_status)
    session.declare_subscriber(f"{base}/pong", lambda s: got.set())
    ping = session.declare_publisher(f"{base}/ping")
    deadline = time.monotonic() + 60.0
    while not got.is_set() and time.monotonic() < deadline:  # until the pong side is routed
        ping.put(b"hello")
        got.wait(0.2)
    rtt = []
    for _ in range(200):
        got.clear()
        began = time.perf_counter()
        ping.put(b"x" * 64)
        if got.wait(1.0):
            rtt.append((time.perf_counter() - began) * 1e6)
        time.sleep(0.01)
    done.wait(120.0)
    print(json.dumps({"rtt_us": rtt, "neighbors": {i: sorted(n) for i, n in neighbors.items()}}))
"""


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=30)


@contextmanager
def two_hosts() -> Iterator[tuple[tuple[str, str], tuple[str, str]]]:
    """((namespace A, address A), (namespace B, address B)), veth-linked, removed after."""
    if shutil.which("ip") is None:
        pytest.fail("the multi-host test needs iproute2 (`ip netns`) to create namespaces")
    tag = secrets.token_hex(4)
    subnet = f"10.199.{secrets.randbelow(254) + 1}"
    hosts = ((f"cs-{tag}-a", f"{subnet}.1"), (f"cs-{tag}-b", f"{subnet}.2"))
    veths = (f"cs{tag}a", f"cs{tag}b")
    created: list[str] = []
    try:
        for ns, _ in hosts:
            ip("netns", "add", ns)
            created.append(ns)
        ip("link", "add", veths[0], "type", "veth", "peer", "name", veths[1])
        for (ns, address), veth in zip(hosts, veths, strict=True):
            ip("link", "set", veth, "netns", ns)
            ip("-n", ns, "addr", "add", f"{address}/24", "dev", veth)
            ip("-n", ns, "link", "set", veth, "up")
            ip("-n", ns, "link", "set", "lo", "up")
        yield hosts
    except subprocess.CalledProcessError as exc:
        pytest.fail(f"could not set up network namespaces: {exc.stderr.decode().strip()}")
    finally:
        for ns in created:  # deleting a namespace deletes its end of the veth pair too
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


@contextmanager
def started(argv: list[str], log: Path, **kwargs) -> Iterator[subprocess.Popen]:
    """A background process, SIGKILLed by pid if it is still running at the end."""
    with log.open("wb") as out:
        process = subprocess.Popen(argv, stdout=kwargs.pop("stdout", out), stderr=out, **kwargs)
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(timeout=30)


def test_one_swarm_over_two_hosts(tmp_path: Path, require) -> None:
    require(os.geteuid() == 0, "the multi-host test needs root to create network namespaces")
    swarm = f"mh-{secrets.token_hex(4)}"
    with two_hosts() as ((ns_a, addr_a), (ns_b, addr_b)):
        secure = issue_credentials(
            tmp_path / "secure", agents=range(TEAM), robots=range(TEAM), hosts=[addr_a, addr_b]
        )
        in_a, in_b = ["ip", "netns", "exec", ns_a], ["ip", "netns", "exec", ns_b]
        router_a, router_b = f"tls/{addr_a}:{PORT}", f"tls/{addr_b}:{PORT}"
        common = ["--agents", str(TEAM), "--scenario", "passage", "--duration", "15",
                  "--seed", "3", "--swarm", swarm, "--secure", str(secure)]  # fmt: skip
        run = [*covswarm_argv(), "run", *common]
        host_a = [*in_a, *run, "--ids", "0-2", "--router-listen", router_a,
                  "--out", str(tmp_path / "a")]  # fmt: skip
        host_b = [*in_b, *run, "--ids", "3-5", "--no-coordinator", "--router-listen", router_b,
                  "--router-connect", router_a, "--out", str(tmp_path / "b")]  # fmt: skip
        probe = [sys.executable, "-c", PROBE]
        with (
            # B first: its router keeps retrying A's until A is up.
            started(host_b, tmp_path / "b.log") as launcher_b,
            started(host_a, tmp_path / "a.log") as launcher_a,
            started(
                [*in_b, *probe, "pong", router_b, swarm, str(secure)],
                tmp_path / "pong.log",
                stdout=subprocess.PIPE,
                text=True,
            ) as pong,  # fmt: skip
        ):
            assert pong.stdout.readline().strip() == "ready", (tmp_path / "pong.log").read_text()
            measured = subprocess.run(
                [*in_a, *probe, "ping", router_a, swarm, str(secure)], capture_output=True,
                text=True,
                timeout=150,
            )  # fmt: skip
            assert measured.returncode == 0, measured.stderr
            assert launcher_a.wait(timeout=60) == 0, (tmp_path / "a.log").read_text()
            assert launcher_b.wait(timeout=60) == 0, (tmp_path / "b.log").read_text()
            pong.send_signal(signal.SIGTERM)

    probe_out = json.loads(measured.stdout.strip().splitlines()[-1])
    rtt = sorted(probe_out["rtt_us"])
    assert len(rtt) >= 150, "pings lost between the namespaces"
    print(
        f"\ncross-host round trip (probe A -> router A -> veth -> router B -> probe B and back,"
        f" 64 B, during the mission): p50 {rtt[len(rtt) // 2]:.0f} us, "
        f"p99 {rtt[int(0.99 * len(rtt))]:.0f} us"
    )
    neighbors = {int(i): set(n) for i, n in probe_out["neighbors"].items()}
    assert set(neighbors) == set(range(TEAM)), "the probe on A must hear every agent"
    across = {(i, j) for i, ns in neighbors.items() for j in ns if (i < 3) != (j < 3)}
    assert across, f"no Voronoi neighbours across the hosts: {neighbors}"

    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["alive_at_end"] == {"agents": TEAM, "robots": TEAM}
    assert summary["lost_processes"] == []
    # At 15 s the passage domain is moving: a healthy team tracks it within ~0.05 m
    # (0.056 m seen once), a broken one stays near its 0.5 m start.
    assert summary["final_error"] < 0.1
    assert summary["final_error"] < 0.25 * summary["initial_error"]
    assert not (tmp_path / "b" / "summary.json").exists()  # B has no coordinator
    resources = json.loads((tmp_path / "b" / "resources.json").read_text())
    assert len(resources["rss_mb"]["agent"]) == 3  # B ran its three agents to the end
