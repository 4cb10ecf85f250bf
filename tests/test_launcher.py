"""Pure logic of ``covswarm run``: the process plan, staggered start-up, helpers."""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path

import numpy as np

from coordinator.scenarios import load_scenario
from deploy.launcher import (
    ChildSpec,
    Startup,
    covswarm_argv,
    free_port,
    initial_poses,
    plan_children,
    rss_mb,
)


def _plan(feedforward: bool = True) -> list[ChildSpec]:
    return plan_children(
        load_scenario("passage"), scenario_arg="passage", agents=3, seed=7,
        endpoint="tcp/127.0.0.1:7000", swarm="s1", rate=10.0, kappa=2.0,
        feedforward=feedforward, duration=12.0, out_dir=Path("out"), base=["covswarm"],
    )  # fmt: skip


def _option(argv: tuple[str, ...], name: str) -> str:
    return argv[argv.index(name) + 1]


def test_plan_starts_coordinator_then_robot_agent_pairs() -> None:
    specs = _plan()
    assert [s.name for s in specs] == [
        "coordinator-0", "robot-0", "agent-0", "robot-1", "agent-1", "robot-2", "agent-2",
    ]  # fmt: skip
    for spec in specs:
        assert spec.argv[:2] == ("covswarm", spec.role)
        assert _option(spec.argv, "--connect") == "tcp/127.0.0.1:7000"
        assert _option(spec.argv, "--swarm") == "s1"
    coordinator = specs[0].argv
    assert _option(coordinator, "--agents") == "3"
    assert float(_option(coordinator, "--duration")) == 12.0
    assert _option(coordinator, "--out") == "out"
    assert "--feedforward" in coordinator
    assert _option(specs[2].argv, "--id") == "0" and float(_option(specs[2].argv, "--rate")) == 10


def test_plan_passes_no_feedforward_to_agents_and_coordinator() -> None:
    specs = _plan(feedforward=False)
    assert all("--no-feedforward" in s.argv for s in specs if s.role in ("agent", "coordinator"))
    assert not any("--no-feedforward" in s.argv for s in specs if s.role == "robot")


def test_robots_start_where_the_scenario_puts_them() -> None:
    scenario = load_scenario("passage")
    poses = initial_poses(scenario, 3, seed=7)
    np.testing.assert_array_equal(poses[:, :2], scenario.initial_positions(3, 7))
    assert np.all(np.abs(poses[:, 2]) <= np.pi)
    for spec, pose in zip([s for s in _plan() if s.role == "robot"], poses, strict=True):
        xyz = [float(_option(spec.argv, f"--{k}")) for k in ("x", "y", "theta")]
        np.testing.assert_array_equal(xyz, pose)  # repr round-trips floats exactly


def _specs(n: int) -> list[ChildSpec]:
    return [ChildSpec("robot", i, ("x",)) for i in range(n)]


def test_startup_keeps_at_most_max_starting_in_flight() -> None:
    startup = Startup(_specs(5), max_starting=2, stall=30.0)
    assert [s.ident for s in startup.next_batch(0.0)] == [0, 1]
    assert startup.next_batch(0.1) == []
    startup.ready.add("robot-0")
    assert [s.ident for s in startup.next_batch(0.2)] == [2]
    startup.exited.add("robot-1")  # died during start-up: frees its slot
    assert [s.ident for s in startup.next_batch(0.3)] == [3]
    assert not startup.done


def test_a_stalled_child_stops_holding_a_slot() -> None:
    startup = Startup(_specs(2), max_starting=1, stall=30.0)
    startup.next_batch(0.0)
    assert startup.next_batch(29.0) == []
    assert [s.ident for s in startup.next_batch(31.0)] == [1]


def test_startup_done_when_everyone_is_ready_or_gone() -> None:
    startup = Startup(_specs(2), max_starting=4, stall=30.0)
    startup.next_batch(0.0)
    startup.ready.add("robot-0")
    assert not startup.done
    startup.exited.add("robot-1")
    assert startup.done


def test_free_port_is_bindable() -> None:
    port = free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))


def test_covswarm_argv_runs_this_interpreter() -> None:
    argv = covswarm_argv()
    assert argv[0] == sys.executable


def test_rss_of_this_process_and_of_a_missing_one() -> None:
    assert rss_mb(os.getpid()) > 1.0
    assert rss_mb(2**22 + 12345) is None
