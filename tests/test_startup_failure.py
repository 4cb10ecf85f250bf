"""A run whose own child cannot start is no run: ``covswarm run`` stops at once, saying
which child and why, and exits 1, rather than fly the mission with what is there. The case
that matters in a lab: the launcher asked for simulated robots 0-1 while robot 0 already
runs in that swarm (a bridge's real robot); the simulated one is refused ("already
running") and, were the run to go on, the mission's brains would drive the other one."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest
import zenoh
from live_runs import new_swarm, swarm_pids, wait_until

from covswarm import protocol
from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port
from covswarm.protocol.session import session_config

pytestmark = pytest.mark.e2e


def test_a_child_refused_at_start_up_stops_the_run(tmp_path: Path) -> None:
    swarm, endpoint = new_swarm(), f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen(
        [*covswarm_argv(), "router", "--listen", endpoint], stdout=subprocess.PIPE, text=True
    )
    other = None
    try:
        assert router.stdout.readline().startswith("router listening on")
        robot = [*covswarm_argv(), "robot", "--id", "0", "--swarm", swarm, "--connect", endpoint]
        other = subprocess.Popen(robot, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # robot 0 is up (and holds its claim) once its liveliness token is there
        with zenoh.open(session_config([endpoint])) as session:
            key = protocol.alive_key(swarm, "robot", 0)
            assert wait_until(
                lambda: any(True for _ in session.liveliness().get(key, timeout=1.0)),
                timeout=60,
            )
        began = time.monotonic()
        run = subprocess.run(
            [*covswarm_argv(), "run", "--agents", "2", "--duration", "20", "--swarm", swarm,
             "--connect", endpoint, "--out", str(tmp_path / "run")],
            capture_output=True, text=True, timeout=120,
            env={**os.environ, "COLUMNS": "400"},  # one line per message
        )  # fmt: skip
        took = time.monotonic() - began
    finally:
        for process in (other, router):
            if process is not None:
                process.kill()
                process.wait()
    said = " ".join(run.stdout.split())
    assert run.returncode == 1, said
    assert "robot-0 (pid" in said
    assert "before the mission started: Error: robot 0 is already running" in said
    assert "stopping the run" in said
    assert took < 60  # not the 20 s mission, nor the start-up timeout
    assert not (tmp_path / "run" / "summary.json").exists()
    assert not swarm_pids(swarm, "run") and not swarm_pids(swarm, "agent")


def test_a_start_up_that_times_out_says_whom_the_coordinator_waited_for(tmp_path: Path) -> None:
    """No robot ever comes (``--robots none``, and no bridge on that swarm: a wrong
    ``--swarm``): at the start-up timeout the launcher quotes the coordinator's last word
    on who is missing, which was in its log alone, and exits 1."""
    swarm = new_swarm()
    run = subprocess.run(
        [*covswarm_argv(), "run", "--agents", "2", "--duration", "5", "--swarm", swarm,
         "--robots", "none", "--startup-timeout", "25", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "400"},
    )  # fmt: skip
    said = " ".join(run.stdout.split())
    assert run.returncode == 1, said
    assert "start-up took more than 25 s" in said
    waiting = "the coordinator: still waiting for the team: agents 0-1 missing; robots 0-1 missing"
    assert waiting in said, said
    assert f"joins with --swarm {swarm}" in said
    assert not swarm_pids(swarm, "agent") and not swarm_pids(swarm, "coordinator")
