"""CPU of one packed robot process (``covswarm robot --ids``), per robot, fed commands.

Usage: .venv/bin/python scripts/robot_cpu.py [--robots 500] [--window 8] [--rate 10]
[--repeats 3] [--covswarm PATH ...] [--py-spy FILE]

Opens a Zenoh router on a free loopback port in this process (explicit endpoints, no
scouting: protocol.session), starts ``PATH robot --ids 0-(N-1)`` on a grid of poses inside a
walled 10 m workspace, and plays its agents from here: a WheelCommand per robot at
``--rate`` Hz (slow arcs, so every robot drives and some meet the walls), the World every
second, and a subscriber on every pose (so the poses do leave the process). Once every
robot's pose has arrived, starts the commands, waits two seconds, then reads the robot
process's CPU (/proc/PID/stat, user + system) over ``--window`` seconds and prints it as %
of a core (and its main thread's: the rest is Zenoh's threads) and as us per robot-step (at
the robot's 20 Hz), with the poses received per second, the UTC time and the load
(``uptime``). The robot process is stopped by its pid.

``--covswarm`` may be given several times (e.g. another worktree's
``.venv/bin/covswarm``): each run takes the executables in turn, ``--repeats`` times, so
their figures are interleaved (this VM's speed drifts within minutes; compare pairs, not
absolutes), and a summary gives each one's range. ``--py-spy FILE``: also ``py-spy record``
the robot process over the window (raw format, 100 Hz) into FILE (suffixed per run).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import zenoh

from covswarm import protocol
from covswarm.protocol.session import session_config
from covswarm.world.model import World
from covswarm.world.wire import to_message

HALF = 5.0  # m: the workspace is [-HALF, HALF]^2
SETTLE = 2.0  # s after every robot's first pose before the window
STEP_RATE = 20.0  # Hz: covswarm robot's default --rate


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def grid_poses(n: int) -> list[str]:
    """``--pose`` values for n robots on a square grid inside the workspace."""
    side = max(1, int(n**0.5 + 0.999))
    pitch = (2 * HALF - 0.4) / side
    return [
        f"{-HALF + 0.2 + pitch * (k % side + 0.5):.3f},"
        f"{-HALF + 0.2 + pitch * (k // side + 0.5):.3f},{0.1 * k:.3f}"
        for k in range(n)
    ]


def cpu_seconds(pid: int) -> tuple[float, float]:
    """CPU s (user + system) of the process and of its main thread (the rest is Zenoh's)."""

    def read(path: str) -> float:
        with open(path, encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    return read(f"/proc/{pid}/stat"), read(f"/proc/{pid}/task/{pid}/stat")


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def one_run(
    covswarm: str, session: zenoh.Session, endpoint: str, args: argparse.Namespace, tag: str
) -> dict:
    n = args.robots
    swarm = protocol.new_swarm_name()
    received = [0] * n
    heard = [False] * n

    def on_pose(sample: zenoh.Sample) -> None:
        rid = int(str(sample.key_expr).rsplit("/", 2)[1])
        received[rid] += 1
        heard[rid] = True

    poses = session.declare_subscriber(f"covswarm/{swarm}/robot/*/pose", on_pose)
    commands = [session.declare_publisher(protocol.cmd_key(swarm, i)) for i in range(n)]
    worlds = session.declare_publisher(protocol.world_key(swarm))
    world = World((-HALF, HALF, -HALF, HALF))
    argv = [covswarm, "robot", "--ids", f"0-{n - 1}", "--connect", endpoint, "--swarm", swarm]
    for pose in grid_poses(n):
        argv += ["--pose", pose]
    robot = subprocess.Popen(argv)
    stop = threading.Event()

    def agents() -> None:
        seq, period, next_world = 0, 1.0 / args.rate, 0.0
        while not stop.is_set():
            wall, now = time.time(), time.monotonic()
            if now >= next_world:
                worlds.put(to_message(world, 0, wall).encode())
                next_world = now + 1.0
            for i, publisher in enumerate(commands):
                left = 0.05 + 0.01 * (i % 7)
                command = protocol.WheelCommand(
                    id=i, left=left, right=left + 0.02, stamp=wall, seq=seq, pose_stamp=wall
                )
                publisher.put(command.encode())
            seq += 1
            stop.wait(max(0.0, period - (time.monotonic() - now)))

    feeder = threading.Thread(target=agents, daemon=True)
    try:
        # Commands only once every robot is up (resting robots publish too): queued while
        # the process declares its keys, they would be stale when it reads them.
        deadline = time.monotonic() + args.start_timeout
        while not all(heard):
            if robot.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"robot process did not come up ({sum(heard)}/{n} robots)")
            time.sleep(0.2)
        feeder.start()
        time.sleep(SETTLE)
        spy = None
        if args.py_spy:
            exe = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
            out = f"{args.py_spy}.{tag}"
            spy = subprocess.Popen(
                [exe, "record", "-r", "100", "--format", "raw", "-p", str(robot.pid)]
                + ["-d", str(int(args.window)), "-o", out, "--nonblocking"],
                stdout=subprocess.DEVNULL,
            )
        load = uptime()
        started = datetime.now(UTC).strftime("%H:%M:%S")
        cpu0, wall0, got0 = cpu_seconds(robot.pid), time.monotonic(), sum(received)
        time.sleep(args.window)
        cpu1, wall1, got1 = cpu_seconds(robot.pid), time.monotonic(), sum(received)
        if spy is not None:
            spy.wait()
    finally:
        stop.set()
        if feeder.is_alive():
            feeder.join()
        robot.send_signal(signal.SIGINT)
        try:
            robot.wait(10)
        except subprocess.TimeoutExpired:
            robot.kill()
            robot.wait()
        poses.undeclare()
        for publisher in commands:
            publisher.undeclare()
        worlds.undeclare()
    span = wall1 - wall0
    share = (cpu1[0] - cpu0[0]) / span
    return {
        "covswarm": covswarm,
        "utc": started,
        "cpu": 100.0 * share,
        "main": 100.0 * (cpu1[1] - cpu0[1]) / span,
        "us_per_robot_step": 1e6 * share / (n * STEP_RATE),
        "poses_per_s": (got1 - got0) / span,
        "load": load.split("load average:")[-1].strip(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=500)
    parser.add_argument("--window", type=float, default=8.0)
    parser.add_argument("--rate", type=float, default=10.0, help="commands per robot per s")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--covswarm", action="append", default=[])
    parser.add_argument("--py-spy", default=None)
    parser.add_argument("--start-timeout", type=float, default=60.0)
    args = parser.parse_args()
    paths = args.covswarm or [str(Path(sys.executable).with_name("covswarm"))]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    results: list[dict] = []
    with zenoh.open(session_config(None, [endpoint], "router")) as session:
        for repeat in range(args.repeats):
            for k, path in enumerate(paths):
                r = one_run(path, session, endpoint, args, f"{repeat}.{k}")
                results.append(r)
                print(
                    f"{r['utc']} UTC  {path}: {r['cpu']:.1f} % of a core "
                    f"(main thread {r['main']:.1f}), "
                    f"{r['us_per_robot_step']:.2f} us/robot-step, "
                    f"{r['poses_per_s']:.0f} poses/s, load {r['load']}",
                    flush=True,
                )
    if len(results) > 1:
        for path in paths:
            cpus = sorted(r["cpu"] for r in results if r["covswarm"] == path)
            print(f"{path}: {args.robots} robots, {cpus[0]:.1f}-{cpus[-1]:.1f} % of a core")


if __name__ == "__main__":
    main()
