"""The probes of issue 21 against real agents and robots over Zenoh, in open mode: a
hostile session forges Domains outside the workspace and numbered 2^62, and rings of
phantom beacons around every robot, while the test plays the real coordinator. The
team still covers the real S, no robot leaves the workspace, and every forgery is counted.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from live_runs import open_router, stop_children, watch_team
from wire_samples import domain_message

from covswarm import protocol
from covswarm.tvd.coverage import mass_centroid

pytestmark = pytest.mark.e2e

REPO = Path(__file__).resolve().parents[1]
COVSWARM = str(Path(sys.executable).with_name("covswarm"))
SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
WORKSPACE = (-0.5, 1.5, -0.5, 1.5)  # xmin, xmax, ymin, ymax
OUTSIDE = [[2.5, 0.0], [3.3, 0.0], [3.3, 1.0], [2.5, 1.0]]  # the probe's x = 3.30 m
STARTS = [(0.3, 0.3), (0.6, 0.4), (0.4, 0.7)]


def domain(vertices: list, seq: int, state: str = "running") -> bytes:
    return domain_message(vertices, seq=seq, stamp=time.time(), state=state).encode()


@pytest.mark.timeout(150)
def test_forged_domains_and_phantom_beacons_change_nothing_but_counts() -> None:
    zenoh = pytest.importorskip("zenoh")
    swarm = protocol.new_swarm_name()
    session, endpoint = open_router()
    hostile = zenoh.open(protocol.session_config([endpoint], None, "client"))
    children: list[subprocess.Popen] = []
    try:
        poses, states = watch_team(session, swarm)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        box = [str(v) for v in WORKSPACE]
        for rid, (x, y) in enumerate(STARTS):
            common = ["--id", str(rid), "--connect", endpoint, "--swarm", swarm]
            robot = [COVSWARM, "robot", *common, "--x", str(x), "--y", str(y)]
            children.append(subprocess.Popen(robot, cwd=REPO, env=env))
            agent = [COVSWARM, "agent", *common, "--workspace", *box]
            children.append(subprocess.Popen(agent, cwd=REPO, env=env))
        key = protocol.domain_key(swarm)
        seq, deadline = 0, time.monotonic() + 60.0
        while len(states.snapshot()) < len(STARTS):
            assert time.monotonic() < deadline, "agents did not come up"
            assert all(child.poll() is None for child in children), "a child exited"
            seq += 1
            session.put(key, domain(SQUARE, seq, "waiting"))
            time.sleep(0.1)

        def error() -> float:
            positions = np.array([[p.x, p.y] for _, p in sorted(poses.snapshot().items())])
            _, centroids = mass_centroid(positions, np.array(SQUARE))
            return float(np.linalg.norm(positions - centroids))

        def phantom_rings() -> None:
            """36 beacons in a 0.12 m ring around each robot (ids 100 + 36 k + j)."""
            for k, (_, pose) in enumerate(sorted(poses.snapshot().items())):
                for j in range(36):
                    a = 2.0 * np.pi * j / 36
                    x, y = pose.x + 0.12 * np.cos(a), pose.y + 0.12 * np.sin(a)
                    rid = 100 + 36 * k + j
                    tx, ty = protocol.tile_of(x, y, protocol.DEFAULT_TILE_SIZE)
                    beacon = protocol.Beacon(id=rid, x=x, y=y, stamp=time.time())
                    hostile.put(protocol.beacon_key(swarm, tx, ty, rid), beacon.encode())

        initial = error()
        end, next_ring = time.monotonic() + 8.0, 0.0
        farthest = 0.0
        while time.monotonic() < end:
            seq += 1
            session.put(key, domain(SQUARE, seq))
            hostile.put(key, domain(OUTSIDE, seq + 1))  # numbered above the real one
            hostile.put(key, domain(OUTSIDE, 2**62))
            if time.monotonic() >= next_ring:  # every 2 s, under the 25 s beacon timeout
                phantom_rings()
                next_ring = time.monotonic() + 2.0
            farthest = max([farthest, *(p.x for p in poses.snapshot().values())])
            time.sleep(0.05)
        final = error()
        assert final < 0.5 * initial, (initial, final)
        assert farthest < WORKSPACE[1]
        stats = [s.stats for s in states.snapshot().values()]
        assert all(s["drop_domain_outside_workspace"] > 0 for s in stats), stats
        assert all(s["beacon_unconfirmed"] > 0 for s in stats), stats
        # The 2^62 ones are refused either way: as a jump (held stream alive) or, right
        # behind a refused one, still as a jump; never taken.
        assert all(s["drop_domain_seq_jump"] > 0 for s in stats), stats
    finally:
        codes = stop_children(children)
        hostile.close()
        session.close()
    assert codes == [0] * len(children), "children must exit cleanly on SIGTERM"
