"""End to end: ``covswarm run`` as a real subprocess over loopback Zenoh, no mocks.

Each run gets its own swarm name; its processes are found by that name in /proc (every
child has ``--swarm NAME`` on its command line), which is how these tests check that no
child outlives the launcher. Small teams and short missions keep the whole file to about a
minute and a half on two cores.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from live_runs import launch, new_swarm, swarm_pids, wait_until

from covswarm.agent.brain import AGENT_PROJECTION_DISTANCE
from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port
from covswarm.deploy.simulate import simulate
from covswarm.mission.report import steady_state_mean
from covswarm.mission.scenario_files import load_scenario

pytestmark = pytest.mark.e2e


def test_run_covers_the_moving_domain_and_leaves_no_process(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "run"
    began = time.time()
    # TVD-D1: the law docs/results.md's "within 20 %" of the simulation was measured with.
    with launch(out, "--agents", "4", "--scenario", "passage", "--duration", "15", "--law", "d1",
                "--no-safety", "--no-prediction", swarm=swarm) as launcher:  # fmt: skip
        assert wait_until(lambda: len(swarm_pids(swarm)) >= 1 + 1 + 4 + 4, timeout=60)
        assert launcher.wait(timeout=150) == 0, (out.parent / "run.launcher.log").read_text()
    # its output is a file: plain progress lines stand in for the live display
    assert "start-up: coordinator" in (out.parent / "run.launcher.log").read_text()
    for name in ("summary.json", "error.csv", "error.png", "trajectories.png"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agents"] == 4 and summary["law"] == "d1" and summary["feedforward"] is True
    assert summary["lost_processes"] == []
    assert summary["robot_drops"] == {}  # gathered from the robots' logs: nothing dropped
    assert summary["alive_at_end"] == {"agents": 4, "robots": 4}
    # Robots left still (a broken controller) stay near the random start's ~0.3-0.4 m and
    # fall behind once the domain moves (t > 5 s); the controller gets to ~0.01 m.
    assert summary["final_error"] < 0.05
    assert summary["final_error"] < 0.25 * summary["initial_error"]
    assert summary["steady_state_error_mean"] < 0.05
    assert summary["agent_stats"]["team"]["rate_hz"]["min"] > 8.0
    # A healthy run: no control step failed (the step's catch-all counts, never hides).
    assert summary["agent_stats"]["team"]["step_errors"]["max"] == 0
    # e_a at its poses' time: hardly ever placed at a bound (poses too old, out of order).
    assert summary["error_samples_clipped"] < 0.05 * summary["samples"]
    rows = (out / "error.csv").read_text().splitlines()
    assert rows[0] == "t,e_a" and len(rows) > 100
    # The README's resume files (docs/faults.md): when the mission started and where the
    # script's clock stood last; no steering.jsonl, as nobody steered.
    mission = json.loads((out / "mission.json").read_text())
    assert mission["swarm"] == swarm and began < mission["started_wall"] < time.time()
    clock = json.loads((out / "script.json").read_text())
    assert clock["swarm"] == swarm and 7.5 < clock["script_t"] <= 15.0 and clock["pace"] > 0
    assert not (out / "steering.jsonl").exists()
    assert swarm_pids(swarm) == set()
    # docs/results.md: the distributed run's steady-state e_a is within 30 % below and 20 %
    # above the in-process simulation of the same robots (same seed, law, unicycle model,
    # projection distance and safety filter; the simulator needs no pose prediction: it
    # holds each velocity for 20 ms from the exact pose, where a pose predicted to the
    # command's time then held for 100 ms lags more, measured +36 %). The monitor evaluates
    # e_a at the poses' time: against S(now) it measured +16 % to +29 %. Measured -11 % to 0 %
    # on 2026-11-24, -23 % to -14 % on 2026-11-27 (0.0094-0.0105 m in nine runs against the
    # simulation's 0.0122 m: the agents have since come closer to S).
    scenario = load_scenario("passage")  # seed 0: covswarm run's default --seed
    law = summary["law"]
    sim = simulate(
        scenario, agents=4, duration=15.0, law=law, dynamics="unicycle", seed=0,
        projection_distance=AGENT_PROJECTION_DISTANCE, safety=True,
    )  # fmt: skip
    expected = steady_state_mean(sim.t, sim.error)
    assert 0.70 * expected < summary["steady_state_error_mean"] < 1.20 * expected


def test_two_runs_at_once_do_not_collide(tmp_path: Path) -> None:
    outs = [tmp_path / "a", tmp_path / "b"]
    with (
        launch(outs[0], "--agents", "2", "--duration", "5") as first,
        # the robots' command timeout given (a bridge's): the children are told it
        launch(outs[1], "--agents", "2", "--duration", "5", "--cmd-timeout", "0.7") as second,
    ):
        assert first.wait(timeout=120) == 0
        assert second.wait(timeout=120) == 0
    launches = [json.loads((out / "launch.json").read_text()) for out in outs]
    assert launches[0]["swarm"] != launches[1]["swarm"]
    assert launches[0]["endpoint"] != launches[1]["endpoint"]
    for launched in launches:  # an embedded router listens on loopback unless told otherwise
        assert launched["endpoint"].startswith("tcp/127.0.0.1:"), launched["endpoint"]
    assert launches[1]["cmd_timeout_s"] == 0.7
    children = [argv for argv in launches[1]["argv"] if "agent" in argv or "robot" in argv]
    assert children and all(argv[argv.index("--cmd-timeout") + 1] == "0.7" for argv in children), (
        children
    )
    for out in outs:
        summary = json.loads((out / "summary.json").read_text())
        # Each coordinator saw exactly its own team, none of the other run's processes.
        assert summary["alive_at_end"] == {"agents": 2, "robots": 2}
        assert sorted(summary["agent_stats"]["per_agent"]) == ["0", "1"]


def test_a_dead_agent_is_reported_and_the_run_goes_on(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "death"
    # The agent is killed as the mission starts; its token goes at once (liveliness).
    with launch(out, "--agents", "3", "--duration", "5", swarm=swarm) as launcher:
        log = out / "logs" / "coordinator-0.log"
        assert wait_until(lambda: log.exists() and "mission started" in log.read_text(), 60)
        (victim,) = swarm_pids(swarm, "agent", "--id", "1")
        os.kill(victim, signal.SIGKILL)
        assert launcher.wait(timeout=60) == 0
    lost = json.loads((out / "summary.json").read_text())["lost_processes"]
    assert [(e["role"], e["id"]) for e in lost] == [("agent", 1)]
    assert 0.0 <= lost[0]["t"] < 5.0
    assert "agent-1" in (tmp_path / "death.launcher.log").read_text()
    assert swarm_pids(swarm) == set()


def test_run_joins_an_existing_router(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen(
        [*covswarm_argv(), "router", "--listen", endpoint], stdout=subprocess.PIPE, text=True
    )
    try:
        assert router.stdout.readline().startswith("router listening on")
        # Two runs share the router: each swarm name keeps them apart (docs/protocol.md, "<swarm>").
        # Teams of 2 and 3: a run that saw the other's robot 2 or its states would say so.
        outs = {2: tmp_path / "joined-2", 3: tmp_path / "joined-3"}
        common = ("--duration", "4", "--connect", endpoint)
        with (
            launch(outs[2], "--agents", "2", *common) as first,
            launch(outs[3], "--agents", "3", *common) as second,
        ):
            assert first.wait(timeout=120) == 0 and second.wait(timeout=120) == 0
        for n, out in outs.items():
            assert json.loads((out / "launch.json").read_text())["endpoint"] == endpoint
            summary = json.loads((out / "summary.json").read_text())
            assert summary["alive_at_end"] == {"agents": n, "robots": n}
            assert sorted(summary["agent_stats"]["per_agent"]) == [str(i) for i in range(n)]
    finally:
        router.terminate()
        router.wait(timeout=10)


def test_children_die_when_the_launcher_is_sigkilled(tmp_path: Path) -> None:
    swarm = new_swarm()
    with launch(tmp_path / "killed", "--agents", "2", "--duration", "60",
                swarm=swarm) as launcher:  # fmt: skip
        # Launcher + coordinator + 2 robots + 2 agents, all started.
        assert wait_until(lambda: len(swarm_pids(swarm)) == 6, timeout=60)
        children = swarm_pids(swarm) - {launcher.pid}
        launcher.kill()
        launcher.wait()
        assert wait_until(lambda: not (swarm_pids(swarm) & children), timeout=10)


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_run_cleanly_with_outputs(tmp_path: Path, stop: int) -> None:
    # SIGINT is Ctrl-C, how the live scenario is ended; resources.json measured then too.
    swarm, out = new_swarm(), tmp_path / "stopped"
    with launch(out, "--agents", "2", "--duration", "60", swarm=swarm) as launcher:
        log = out / "logs" / "coordinator-0.log"
        assert wait_until(lambda: log.exists() and "mission started" in log.read_text(), 60)
        time.sleep(3.0)  # some mission time, so there is something to write
        launcher.send_signal(stop)
        assert launcher.wait(timeout=60) == 128 + stop
    summary = json.loads((out / "summary.json").read_text())
    assert 2.0 < summary["mission_time"] < 30.0
    resources = json.loads((out / "resources.json").read_text())
    assert {"coordinator", "agent", "robot"} <= resources["rss_mb"].keys()
    assert all(mb > 0 for mbs in resources["rss_mb"].values() for mb in mbs)
    assert {"coordinator", "agent", "robot"} <= resources["cpu_percent_of_core"].keys()
    assert swarm_pids(swarm) == set()


TIGHT = """name = "tight"
agents = 4
kappa = 2.0
duration = 3.0
dt = 0.02
dynamics = "unicycle"
workspace = [-1.0, 1.0, -1.0, 1.0]

[domain]
kind = "rigid"
polygon = [[-0.125, -0.125], [0.125, -0.125], [0.125, 0.125], [-0.125, 0.125]]
"""


def test_a_team_too_big_for_its_domain_is_told_so(tmp_path: Path) -> None:
    """Four Khepera IV in a 25 cm square: 0.0156 m^2 each where a robot needs 0.022."""
    scenario, swarm, out = tmp_path / "tight.toml", new_swarm(), tmp_path / "tight"
    scenario.write_text(TIGHT, encoding="utf-8")
    with launch(out, "--scenario", str(scenario), swarm=swarm) as launcher:
        assert launcher.wait(timeout=120) == 0
    log = (tmp_path / "tight.launcher.log").read_text()
    assert "4 robots do not fit" in " ".join(log.split())
    crowd = json.loads((out / "summary.json").read_text())["crowding"]
    assert crowd["crowded"] and crowd["smallest_cell_m2"] == pytest.approx(0.25**2 / 4, rel=0.02)
    assert swarm_pids(swarm) == set()
