"""Shared helpers of the tests that start real processes (not a test module).

Each run gets its own swarm name; its processes are found by that name in /proc (every
child has ``--swarm NAME`` on its command line), which is how tests check that no child
outlives the launcher, and how whatever a failed test left behind is killed, by pid.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from covswarm import protocol
from covswarm.deploy.plan import auto_per_process, auto_robots_per_process, covswarm_argv
from covswarm.deploy.router import free_port


def swarm_pids(swarm: str, *words: str) -> set[int]:
    """Live (non-zombie) processes whose command line names ``swarm`` and ``words``."""
    wanted = {swarm.encode(), *(w.encode() for w in words)}
    pids = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue  # exited while we looked
        if wanted <= set(cmdline) and state != "Z":
            pids.add(int(entry.name))
    return pids


def split_packing_team(cores: int) -> tuple[int, float]:
    """(agents, rate Hz): the smallest team whose auto packing on ``cores`` cores puts its
    brains in processes of several, smaller than its robot processes (deploy.plan), at the
    first rate from 10 Hz up (doubling) where that team has at most 40 robots per core: a
    faster rate packs fewer brains a process, so the team stays small whatever the brain-tick
    (deploy.plan.BRAIN_TICK: a run of that team says ``--brain-tick``, or its launcher would
    measure its own, deploy.host_speed)."""
    for rate in (10.0, 20.0, 40.0, 80.0, 160.0):
        for agents in range(2, 40 * cores + 1):
            brains = auto_per_process(agents, cores, rate)
            if 1 < brains < auto_robots_per_process(agents, cores):
                return agents, rate
    raise AssertionError("no team of at most 40 robots a core splits brains from robots")


def wait_until(predicate: Callable[[], bool], timeout: float, period: float = 0.2) -> bool:
    """Poll ``predicate`` every ``period`` s for up to ``timeout`` s; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


@contextmanager
def launch(out: Path, *args: str, swarm: str | None = None) -> Iterator[subprocess.Popen]:
    """``covswarm run`` in the background; killed (with whatever it left) if the test fails.

    Its output goes to ``<out>.launcher.log`` beside ``out``.
    """
    swarm_args = ["--swarm", swarm] if swarm else []
    log = (out.parent / f"{out.name}.launcher.log").open("wb")
    process = subprocess.Popen(
        [*covswarm_argv(), "run", "--out", str(out), *swarm_args, *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        log.close()
        for pid in swarm_pids(swarm) if swarm else ():
            os.kill(pid, signal.SIGKILL)


def finish_runs(folder: Path, runs: dict[str, tuple[str, ...]], timeout: float = 240.0) -> dict:
    """Several ``covswarm run``s started together, each with its own swarm, waited to their
    end (exit code 0); their summary.json by name. ``runs``: name -> run arguments; outputs
    in ``folder``/name.

    Together, not one after the other: a run of a few robots takes a fraction of a core, so
    the wall time is the longest mission's, not their sum."""
    with ExitStack() as stack:
        launched = {
            name: stack.enter_context(launch(folder / name, *args, swarm=new_swarm()))
            for name, args in runs.items()
        }
        deadline = time.monotonic() + timeout
        for name, launcher in launched.items():
            code = launcher.wait(timeout=max(1.0, deadline - time.monotonic()))
            assert code == 0, (folder / f"{name}.launcher.log").read_text()
    return {name: json.loads((folder / name / "summary.json").read_text()) for name in runs}


def new_swarm() -> str:
    """A swarm name of its own for one test run."""
    return f"e2e-{secrets.token_hex(4)}"


def open_router(scheme: str = "tcp", secure: Path | None = None) -> tuple[object, str]:
    """A router-mode Zenoh session on a free loopback port: (session, endpoint).

    ``scheme``: "tcp", or "tls" with ``secure`` (a covswarm secure folder). Tried five times:
    the port can be taken between probing and binding."""
    import zenoh

    from covswarm.protocol import session_config

    for attempt in range(5):
        endpoint = f"{scheme}/127.0.0.1:{free_port()}"
        try:
            return zenoh.open(session_config(None, [endpoint], "router", secure=secure)), endpoint
        except zenoh.ZError:
            if attempt == 4:
                raise
    raise AssertionError("unreachable")


def alive_tokens(session: object, selector: str) -> list[str]:
    """Keys of the liveliness tokens matching ``selector`` (error replies left out)."""
    replies = session.liveliness().get(selector, timeout=1.0)
    return [str(reply.ok.key_expr) for reply in replies if reply.ok is not None]


class Latest:
    """Newest decoded message per key, filled from Zenoh callbacks."""

    def __init__(self, cls: type[protocol.Message]) -> None:
        self.cls = cls
        self.lock = threading.Lock()
        self.values: dict[int, protocol.Message] = {}

    def __call__(self, sample: object) -> None:
        message = self.cls.decode(sample.payload.to_bytes())
        if getattr(message, "stats", True) is None:
            return  # agents send their stats about once a second: keep the last that had them
        with self.lock:
            self.values[message.id] = message

    def snapshot(self) -> dict[int, protocol.Message]:
        with self.lock:
            return dict(self.values)


def stop_children(children: list[subprocess.Popen]) -> list[int]:
    """SIGTERM every child still running, then their exit codes (a child that does not exit
    within 10 s is killed, and its code is the kill's)."""
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGTERM)
    codes = []
    for child in children:
        try:
            codes.append(child.wait(timeout=10))
        except subprocess.TimeoutExpired:
            child.kill()
            codes.append(child.wait())
    return codes


def watch_team(session: object, swarm: str) -> tuple[Latest, Latest]:
    """The newest Pose and AgentState of every robot of ``swarm``, subscribed on ``session``."""
    poses = Latest(protocol.Pose)
    states = Latest(protocol.AgentState)
    session.declare_subscriber(protocol.all_poses_selector(swarm), poses)
    session.declare_subscriber(protocol.all_agent_states_selector(swarm), states)
    return poses, states


def stop_process(child: subprocess.Popen) -> None:
    """SIGTERM ``child`` if it still runs; SIGKILL if it has not exited 10 s later."""
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def mission_started(run: subprocess.Popen, out: Path, timeout: float = 90.0) -> str:
    """Wait until the ``covswarm run`` launched into ``out`` started its mission; its Zenoh
    endpoint (launch.json). Fails with the launcher's log if it does not."""
    log = out / "logs" / "coordinator-0.log"
    started = wait_until(
        lambda: run.poll() is None and log.exists() and "mission started" in log.read_text(),
        timeout,
    )
    assert started, (out.parent / f"{out.name}.launcher.log").read_text()
    return json.loads((out / "launch.json").read_text())["endpoint"]


def steer_cli(endpoint: str, swarm: str, *args: str) -> subprocess.CompletedProcess:
    """``covswarm steer`` on ``swarm`` through ``endpoint`` with ``args``; its result."""
    return subprocess.run(
        [*covswarm_argv(), "steer", "--connect", endpoint, "--swarm", swarm, *args],
        capture_output=True,
        text=True,
        timeout=60,
    )


@contextmanager
def running_swarm(folder: Path, *args: str) -> Iterator[tuple[str, str]]:
    """(endpoint, swarm) of a ``covswarm run`` with ``args`` writing into ``folder``/run,
    once its mission started; everything of it killed at the end."""
    swarm, out = new_swarm(), folder / "run"
    with launch(out, *args, swarm=swarm) as run:
        yield mission_started(run, out), swarm
