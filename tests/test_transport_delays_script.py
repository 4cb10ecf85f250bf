"""scripts/transport_delays.py against a router of its own: the ages it prints are those of
the messages put through it, each of its kind."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from live_runs import open_router

from covswarm import protocol

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "transport_delays.py"


def p50(table: str, kind: str) -> list[float]:
    """The p50 column of every row of ``kind``."""
    return [
        float(row.split("|")[5])
        for row in table.splitlines()
        if row.split("|")[2:3] == [f" {kind} "]
    ]


@pytest.mark.e2e
def test_ages_are_told_by_kind_and_stops_apart_from_steering() -> None:
    import zenoh

    router, endpoint = open_router()
    swarm = f"delays{int(time.time() * 1000) % 10**9}"
    probe = subprocess.Popen(
        [sys.executable, str(SCRIPT), endpoint, swarm, "--ids", "3-3",
         "--every", "1", "--duration", "4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        with router, zenoh.open(protocol.session_config([endpoint])) as session:
            seq = 0
            while probe.poll() is None:
                now = time.time()
                seq += 1
                pose = protocol.Pose(id=3, x=0.0, y=0.0, theta=0.0, stamp=now - 0.3, seq=seq)
                session.put(protocol.pose_key(swarm, 3), pose.encode())
                for left, age in ((0.1, 0.05), (0.0, 0.8)):  # steered from a fresh pose; a stop
                    command = protocol.WheelCommand(
                        id=3, left=left, right=left, stamp=now, seq=seq, pose_stamp=now - age
                    )
                    session.put(protocol.cmd_key(swarm, 3), command.encode())
                time.sleep(0.05)
        out, err = probe.communicate(timeout=30)
    finally:
        probe.kill()
    assert probe.returncode == 0, err
    # Loopback delivers in well under 100 ms: the ages are the stamps' (300, 50, 800 ms).
    for kind, age in (("pose", 300.0), ("steered pose age", 50.0), ("stop pose age", 800.0)):
        seen = p50(out, kind)
        assert seen and all(age - 1.0 <= value < age + 100.0 for value in seen), (kind, out)
    assert all(value < 100.0 for value in p50(out, "command")), out
