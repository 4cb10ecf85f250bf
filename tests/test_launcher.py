"""Pure logic of ``covswarm run``: the process plan, staggered start-up, helpers."""

from __future__ import annotations

import io
import os
import socket
import sys
from pathlib import Path

import numpy as np
import pytest

from covswarm.deploy.display import Progress, render
from covswarm.deploy.plan import (
    ChildSpec,
    RunConfig,
    covswarm_argv,
    initial_poses,
    plan_children,
)
from covswarm.deploy.processes import CHILD_NICE, cpu_seconds, rss_mb, spawn
from covswarm.deploy.router import free_port
from covswarm.deploy.supervisor import Startup
from covswarm.mission.scenario_files import load_scenario


def _plan(feedforward: bool = True) -> list[ChildSpec]:
    run = RunConfig(
        scenario="passage", agents=3, seed=7, swarm="s1", rate=10.0, kappa=2.0,
        feedforward=feedforward, duration=12.0, out=Path("out"),
    )  # fmt: skip
    return plan_children(
        run, load_scenario("passage"), endpoint="tcp/127.0.0.1:7000", base=["covswarm"]
    )


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


def test_rss_and_cpu_of_this_process_and_of_a_missing_one() -> None:
    before = cpu_seconds(os.getpid())
    sum(i * i for i in range(1_000_000))  # burn a little CPU
    assert cpu_seconds(os.getpid()) > before >= 0.0
    assert rss_mb(os.getpid()) > 1.0
    missing = 2**22 + 12345  # above the default pid_max
    assert rss_mb(missing) is None and cpu_seconds(missing) is None


def _text(renderable) -> str:
    from rich.console import Console

    console = Console(file=io.StringIO(), width=100, color_system=None)
    console.print(renderable)
    return console.file.getvalue()


def test_display_shows_start_up_then_the_mission() -> None:
    from covswarm.protocol import Status

    progress = Progress(agents=3, duration=20.0)
    progress.ready |= {("coordinator", 0), ("robot", 0), ("robot", 1), ("agent", 2)}
    text = _text(render(progress))
    assert "start-up" in text and "2/3" in text and "1/3" in text and "1/1" in text
    progress.status = Status(
        stamp=1.0, t=5.0, state="running", error=0.0123, alive_agents=3, alive_robots=2
    )
    text = _text(render(progress))
    assert "running" in text and "5.0 / 20.0 s" in text and "0.0123 m" in text
    assert "robots alive  2/3" in text


def test_the_start_up_table_shows_the_planned_route() -> None:
    """A route scenario's lines (mission.scenarios.route_lines, from its plan) are rows of
    the start-up table, one per goal, and leave it once the mission runs."""
    from covswarm.mission.scenarios import route_lines
    from covswarm.protocol import Status

    path = Path(__file__).resolve().parent / "data" / "through_the_wall_route.toml"
    lines = route_lines(load_scenario(path).motion)
    assert len(lines) == 1 and lines[0].startswith("route to goal (1.8, 0.0): ")
    progress = Progress(agents=10, duration=59.0, routes=tuple(lines))
    text = " ".join(_text(render(progress)).split())
    assert "start-up" in text and f"route {lines[0].removeprefix('route ')}" in text
    progress.status = Status(stamp=1.0, t=5.0, state="running", error=0.01, alive_agents=10,
                             alive_robots=10)  # fmt: skip
    assert "route to goal" not in " ".join(_text(render(progress)).split())
    assert "route" not in _text(render(Progress(agents=3, duration=20.0)))  # no plan, no row


def test_display_says_when_the_mission_runs_slower_than_its_script(tmp_path: Path) -> None:
    from covswarm.deploy.display import summary_table
    from covswarm.deploy.processes import RunResult
    from covswarm.protocol import Status

    progress = Progress(agents=3, duration=20.0)
    progress.status = Status(
        stamp=1.0, t=9.0, state="running", error=0.01, alive_agents=3, alive_robots=3,
        pace=0.45, script_t=4.0,
    )  # fmt: skip
    text = " ".join(_text(render(progress)).split())
    assert "4.0 / 20.0 s at 0.45x" in text and "do not hold their rate" in text
    pace = {
        "enabled": True, "asked_rate_hz": 10.0, "held_rate_hz": 4.1, "periods_missed": 0.59,
        "late_held": 0.3, "pace_min": 0.3, "pace_mean": 0.45, "script_time": 20.0,
        "mission_time": 44.4,
    }  # fmt: skip
    table = summary_table({"scenario": "circle", "pace": pace}, RunResult(0, {}, {}), tmp_path)
    text = " ".join(_text(table).split())
    assert "the machine held 4.1 Hz of 10 asked" in text and "ran at 0.45x" in text


def test_the_live_brain_tick_is_the_agents_cpu_per_brain_step(tmp_path: Path) -> None:
    """Two agent processes of 50 brains at 39.2 % and 39.6 % of a core, holding 13.05 Hz:
    0.788 core-s per s over 1305 brain steps per s; at half speed (x0.5) the same CPU
    buys half the steps per wall second, so each costs twice as much."""
    from covswarm.deploy.display import live_brain_tick, summary_table
    from covswarm.deploy.processes import LAUNCHER, RunResult

    cpu = {"agent": [39.2, 39.6], "robot": [4.0, 5.0], "coordinator": [12.0], LAUNCHER: [8.0]}
    result = RunResult(0, {}, cpu, {"agent": [50, 50], "robot": [50, 50], "coordinator": [1]})
    assert live_brain_tick(result, 13.05, 1.0) == pytest.approx(0.788 / 1305)
    assert live_brain_tick(result, 13.05, 0.5) == pytest.approx(2 * 0.788 / 1305)
    assert live_brain_tick(result, None, 1.0) is None  # no agent reported a rate
    unmeasured = RunResult(0, {}, {"agent": [39.2]}, {"agent": [50, 50]})  # one died early
    assert live_brain_tick(unmeasured, 13.05, 1.0) is None
    pace = {"enabled": True, "asked_rate_hz": 30.0, "held_rate_hz": 13.05,
            "periods_missed": 0.56, "pace_min": 1.0, "pace_mean": 1.0, "script_time": 20.0,
            "mission_time": 20.0}  # fmt: skip
    summary = {"scenario": "circle", "pace": pace}
    text = " ".join(_text(summary_table(summary, result, tmp_path)).split())
    assert "CPU per brain-tick (live) │ 0.60 ms" in text
    assert "CPU outside the agents │ 29% of a core" in text  # robots, coordinator, launcher
    assert "CPU per launcher process │ mean 8.0%" in text


def test_the_run_table_shows_the_arena_as_sim_prints_it(tmp_path: Path) -> None:
    from covswarm.deploy.display import summary_table, world_line
    from covswarm.deploy.processes import RunResult

    arena = {"obstacle_contacts": 0, "min_obstacle_clearance": 0.0864,
             "domain_obstacle_overlap": 0.0, "goals": 1, "goals_reached": 1}  # fmt: skip
    line = "0 obstacle contacts; closest to a wall 0.086 m; S over obstacles up to 0.0000 m^2"
    assert world_line(arena) == line + "; goals reached 1 of 1"
    text = " ".join(_text(summary_table(arena, RunResult(0, {}, {}), tmp_path)).split())
    assert "arena │ 0 obstacle contacts; closest to a wall 0.086 m" in text
    open_floor = {"obstacle_contacts": 0, "min_obstacle_clearance": None,
                  "domain_obstacle_overlap": 0.0, "goals": 0, "goals_reached": 0}  # fmt: skip
    assert "arena" not in _text(summary_table(open_floor, RunResult(0, {}, {}), tmp_path))


def test_an_output_that_is_not_a_terminal_gets_plain_progress_lines() -> None:
    from covswarm.deploy.display import Progress, progress_line
    from covswarm.protocol import Status

    progress = Progress(agents=4, duration=30.0, ready={("coordinator", 0), ("robot", 1)})
    assert progress_line(progress) == "start-up: coordinator 1/1, robots 1/4, agents 0/4 ready"
    progress.status = Status(1.7e9, 12.3, "running", 0.0312, 4, 3, pace=0.5, script_t=6.1)
    assert progress_line(progress) == (
        "running: 6.1 / 30.0 s at 0.50x, e_a 0.0312 m, alive 3/4 robots, 4/4 agents"
    )


def test_a_session_close_that_times_out_does_not_lose_the_run(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The embedded router of a 2000-process run timed out closing; the launcher must still
    go on to write its outputs."""
    import zenoh

    from covswarm.deploy.router import _closing

    class SlowSession:
        def close(self) -> None:
            raise zenoh.ZError("close operation timed out!")

    with caplog.at_level("WARNING"), _closing(SlowSession()):
        pass
    assert "close operation timed out" in caplog.text


def test_robot_and_agent_children_run_nicer_than_the_launcher(tmp_path: Path) -> None:
    """The router (in the launcher) and the coordinator serve every child: robots and agents
    take CHILD_NICE more niceness, in their own entry point (deploy.lifeline)."""
    probe = "from covswarm.deploy import lifeline; lifeline.hold(); import os; print(os.nice(0))"
    mine = os.nice(0)
    for role in ("robot", "agent", "coordinator"):
        child = spawn(ChildSpec(role, 0, (sys.executable, "-c", probe)), tmp_path)
        assert child.process.wait(timeout=30) == 0
        niceness = int(child.log_path.read_text().split()[-1])
        assert niceness == min(19, mine + CHILD_NICE.get(role, 0)), role


def test_a_lost_process_is_listed_with_when() -> None:
    from covswarm.deploy.display import describe_loss

    assert describe_loss({"role": "robot", "id": 5, "t": None}) == "robot 5 before the start"
    assert describe_loss({"role": "robot", "id": 5, "t": 10.84}) == "robot 5 at t = 10.8 s"
