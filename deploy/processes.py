"""Child processes of ``covswarm run``: start, stop, and measure them (Linux /proc).

Children are started without ``preexec_fn``: the launcher already runs the embedded
router's threads, and Python documents ``preexec_fn`` in a threaded process as a deadlock
risk for the child. Each child instead takes the parent-death signal itself, first thing
in its ``covswarm`` entry point (:mod:`covswarm.deploy.lifeline`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from covswarm.deploy.lifeline import NICE_ENV, PARENT_ENV
from covswarm.deploy.plan import ChildSpec

TERMINATE_GRACE = 5.0  # s between SIGTERM and SIGKILL when stopping children
# Niceness added to robot and agent processes: the embedded router (in the launcher) and the
# coordinator serve every one of them, and on an overloaded machine an equal share among
# 40 processes starved the router: commands reached robots 13 s late and Zenoh sessions
# timed out (robots' tokens lost before the start, docs/scaling.md, 1000 robots).
CHILD_NICE = {"robot": 5, "agent": 5}


@dataclass
class Child:
    """A started child; ``exit_code`` is set once the launcher has noticed it exited."""

    spec: ChildSpec
    process: subprocess.Popen
    log_path: Path
    exit_code: int | None = None


# RunResult.cpu's role of the launcher process itself.
LAUNCHER = "launcher"


@dataclass
class RunResult:
    """How the children of a run ended and what they used (the summary table shows it)."""

    exit_code: int
    rss: dict[str, list[float]]  # role -> RSS (MB) of each child at the end of the mission
    # role -> CPU use of each child during the mission, % of a core; the launcher's own (its
    # embedded router and display) under LAUNCHER.
    cpu: dict[str, list[float]]
    members: dict[str, list[int]] = field(default_factory=dict)  # role -> robots per child


def spawn(spec: ChildSpec, log_dir: Path) -> Child:
    """Start one child in its own process group (Ctrl-C reaches only the launcher)."""
    log_path = log_dir / f"{spec.name}.log"
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            spec.argv,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            process_group=0,
            env={
                **os.environ,
                PARENT_ENV: str(os.getpid()),
                **({NICE_ENV: str(CHILD_NICE[spec.role])} if spec.role in CHILD_NICE else {}),
            },
        )
    return Child(spec, process, log_path)


def stop_children(children: Sequence[Child], grace: float = TERMINATE_GRACE) -> None:
    """SIGTERM every live child, SIGKILL whatever is left after ``grace``, reap all."""
    for child in children:
        if child.process.poll() is None:
            child.process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for child in children:
        try:
            child.process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.process.kill()
            child.process.wait()


def rss_mb(pid: int) -> float | None:
    """Resident set size of a live process in MB (Linux /proc), None if it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a live process in s (Linux /proc), None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    # Fields 14 and 15 of proc(5) (utime, stime); fields[0] is field 3 (state).
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextmanager
def interrupts() -> Iterator[list[int]]:
    """Signals received (SIGINT, SIGTERM) as a list the main loop polls; handlers restored."""
    received: list[int] = []
    previous = {
        sig: signal.signal(sig, lambda signum, _frame: received.append(signum))
        for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        yield received
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
