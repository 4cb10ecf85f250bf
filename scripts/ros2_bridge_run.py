"""ROS 2 robots against simulated ones: the same mission through ``covswarm bridge ros2``.

Usage: .venv/bin/python scripts/ros2_bridge_run.py [--agents 6] [--duration 45] [--out runs/ros2]

Runs, one after the other, on this machine:

1. ``ros2``: a Zenoh router (standing in for ``rmw_zenohd``), ``scripts/ros2_robot_sim.py``
   with one ROS 2 robot per agent at the poses ``covswarm run`` would give its simulated
   robots, ``covswarm bridge ros2 --publish-state`` and ``covswarm run --robots none
   --connect`` (coordinator and agents only);
2. ``sim``: plain ``covswarm run`` (simulated Khepera IV robots), same scenario and seed.

Prints a Markdown table of both runs' e_a (steady state = mean over the second half,
final) and their ratio; each run's outputs are in ``<out>/ros2`` and ``<out>/sim``, the
bridge's log (``bridge.log``) and the Twists the emulated robots received
(``twists.jsonl``) in ``<out>``.
"""

from __future__ import annotations

import json
import secrets
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import click

from covswarm.deploy.plan import covswarm_argv, initial_poses
from covswarm.deploy.router import free_port
from covswarm.mission.scenario_files import load_scenario

HERE = Path(__file__).resolve().parent
ROUTER = """
import signal, sys, zenoh
from covswarm.protocol import session_config
with zenoh.open(session_config(None, [sys.argv[1]], mode="router")):
    print("ready", flush=True)
    signal.pause()
"""


def ros2_run(scenario: str, agents: int, duration: float, seed: int, out: Path) -> dict:
    """The mission with ROS 2 robots behind the bridge; returns its summary."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    swarm = f"ros2-{secrets.token_hex(4)}"
    poses = initial_poses(load_scenario(scenario), agents, seed)
    robots = [f"--robot={i}:{x},{y},{theta}" for i, (x, y, theta) in enumerate(poses.tolist())]
    out.mkdir(parents=True, exist_ok=True)
    children = []
    try:
        router = subprocess.Popen(
            [sys.executable, "-c", ROUTER, endpoint], stdout=subprocess.PIPE, text=True
        )
        children.append(router)
        assert router.stdout.readline().strip() == "ready"
        sim = subprocess.Popen(
            [sys.executable, str(HERE / "ros2_robot_sim.py"), "--connect", endpoint, *robots,
             "--record", str(out / "twists.jsonl")],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        children.append(sim)
        assert sim.stdout.readline().strip() == "ready"
        with (out / "bridge.log").open("wb") as log:
            children.append(
                subprocess.Popen(
                    [
                        *covswarm_argv(),
                        "bridge",
                        "ros2",
                        "--ids",
                        f"0-{agents - 1}",
                        "--connect",
                        endpoint,
                        "--swarm",
                        swarm,
                        "--publish-state",
                        "--verbose",
                    ],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )  # fmt: skip
            )
            shutil.rmtree(out / "ros2", ignore_errors=True)  # a run needs a new folder
            subprocess.run(
                [*covswarm_argv(), "run", "--robots", "none", "--connect", endpoint,
                 "--swarm", swarm, "--scenario", scenario, "--agents", str(agents),
                 "--duration", repr(duration), "--seed", str(seed), "--out", str(out / "ros2")],
                check=True, stdout=subprocess.DEVNULL,
            )  # fmt: skip
    finally:
        for child in reversed(children):
            child.send_signal(signal.SIGTERM)
            child.wait(timeout=30)
    return json.loads((out / "ros2" / "summary.json").read_text(encoding="utf-8"))


def sim_run(scenario: str, agents: int, duration: float, seed: int, out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)  # this script's own folder: a run needs a new one
    subprocess.run(
        [*covswarm_argv(), "run", "--scenario", scenario, "--agents", str(agents),
         "--duration", repr(duration), "--seed", str(seed), "--out", str(out)],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


@click.command()
@click.option("--scenario", default="passage", show_default=True)
@click.option("--agents", type=int, default=6, show_default=True)
@click.option("--duration", type=float, default=45.0, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/ros2-bridge"))
def main(scenario: str, agents: int, duration: float, seed: int, out: Path) -> None:
    ros2 = ros2_run(scenario, agents, duration, seed, out)
    sim = sim_run(scenario, agents, duration, seed, out / "sim")
    print("| robots | steady-state e_a | final e_a | initial e_a |")
    print("|---|---|---|---|")
    for name, summary in (("ROS 2 (bridge)", ros2), ("simulated (covswarm robot)", sim)):
        print(f"| {name} | {summary['steady_state_error_mean']:.4f} m | "
              f"{summary['final_error']:.4f} m | {summary['initial_error']:.4f} m |")  # fmt: skip
    ratio = ros2["steady_state_error_mean"] / sim["steady_state_error_mean"]
    print(f"\nsteady-state ratio ROS 2 / simulated: {ratio:.2f}")


if __name__ == "__main__":
    main()
