"""What ``covswarm run`` starts: one ChildSpec (role, ids, command line) per process."""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from covswarm.mission.scenarios import Scenario
from covswarm.protocol.keys import format_ids


@dataclass(frozen=True)
class ChildSpec:
    """One process to start: its role, id(s) and command line.

    A robot or agent process may host several robots or brains (``--agents-per-process``):
    ``idents`` lists them (empty: just ``ident``); the process is ready once every one of
    them holds its liveliness token.
    """

    role: str  # "coordinator" | "robot" | "agent"
    ident: int
    argv: tuple[str, ...]
    idents: tuple[int, ...] = ()

    @property
    def members(self) -> tuple[int, ...]:
        return self.idents or (self.ident,)

    @property
    def name(self) -> str:
        return f"{self.role}-{format_ids(list(self.members))}"


# The default packing of brains into agent processes (and robots into robot processes),
# from docs/scaling.md's measurements of 100 robots on 2 cores: one per process (K = 1)
# took 9 minutes to bring up 201 processes at 85 MB per brain, K = 20 took 4-8 s and
# K = 50 held 10 Hz with 0.02 % of periods missed, at 3.6 MB per brain. Up to
# SOLO_PER_CORE agents per core each gets its own process (a process is a robot's unit of
# failure, as on real robots); beyond, one agent process per core, at most MAX_PACKED brains
# each (a process steps its brains one after the other: 50 at ~0.9 ms fill half a 10 Hz
# period).
SOLO_PER_CORE = 8
MAX_PACKED = 50


def auto_per_process(agents: int, cores: int) -> int:
    """Brains per agent process for ``agents`` brains on a host with ``cores`` cores."""
    if agents <= SOLO_PER_CORE * max(cores, 1):
        return 1
    return min(MAX_PACKED, -(-agents // max(cores, 1)))


def parse_per_process(text: str, agents: int, cores: int | None = None) -> int:
    """``--agents-per-process``: a positive integer, or "auto" (:func:`auto_per_process` for
    ``agents`` brains on ``cores`` cores, default the cores this process may run on).
    ValueError with the reason for anything else."""
    if text.strip().lower() == "auto":
        if cores is None:
            cores = len(os.sched_getaffinity(0))
        return auto_per_process(agents, cores)
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"must be a positive integer or auto, not {text!r}")
    return value


def covswarm_argv() -> list[str]:
    """How to run ``covswarm`` with this interpreter, readable in ``ps``.

    The console script next to sys.executable (the venv's), else ``python -c`` on the entry
    point, so children always run the same installation as the launcher.
    """
    script = Path(sys.executable).with_name("covswarm")
    if script.exists():
        return [sys.executable, str(script)]
    return [sys.executable, "-c", "from covswarm.deploy.cli import main; main()"]


def initial_poses(scenario: Scenario, n: int, seed: int) -> np.ndarray:
    """(n, 3) x, y, heading: positions as ``covswarm sim``, headings from their own stream."""
    positions = scenario.initial_positions(n, seed)
    headings = np.random.default_rng([seed, 1]).uniform(-np.pi, np.pi, size=n)
    return np.column_stack([positions, headings])


def plan_children(
    scenario: Scenario,
    *,
    scenario_arg: str,
    agents: int,
    seed: int,
    endpoint: str,
    swarm: str,
    rate: float,
    kappa: float,
    feedforward: bool,
    duration: float,
    out_dir: Path,
    base: Sequence[str],
    ids: Sequence[int] | None = None,
    per_process: int = 1,
    coordinator: bool = True,
    robots: bool = True,
    time_scale: float = 1.0,
    agent_args: Sequence[str] = (),
    secure: Path | None = None,
    law: str = "da",
    coordinator_args: Sequence[str] = (),
) -> list[ChildSpec]:
    """Coordinator first (it must see everyone arrive), then robot i and agent i in turn.

    Pairs rather than all robots first: a waiting robot already runs its loop, so starting
    every robot before the (slower to import) agents would load the machine while the
    agents start. The coordinator holds the mission until everyone is up either way.

    ``ids``: the slice of the team of ``agents`` this host runs (default: all of it); a
    robot starts where it would in the full team, so hosts that split a team with the same
    seed reproduce the one-host run. ``per_process`` robots (brains) share a robot (agent)
    process; ``coordinator=False`` leaves the coordinator to another host, ``robots=False``
    the robots to bridges (covswarm bridge ros2) that join the swarm. ``agent_args``
    are appended to every agent's command line (fault injection), ``coordinator_args`` to
    the coordinator's (recording, live view). ``secure``: every child
    gets ``--secure`` (protocol.security). Agent process k of n gets ``--tick-phase k/n``:
    their batches of brains take turns within the control period instead of colliding on
    the cores at chance moments. ``law``: the agents' control law, "da" or "d1"
    (covswarm.tvd.control.local_step), also recorded by the coordinator.
    """
    secured = () if secure is None else ("--secure", str(secure))
    common = ("--connect", endpoint, "--swarm", swarm, *secured)
    ff = ("--law", law) if feedforward else ("--law", law, "--no-feedforward")
    scale = () if time_scale == 1.0 else ("--time-scale", repr(time_scale))
    # The scenario's bodies, for the agents' safety filter (theirs by default: a Khepera IV).
    body = ("--body-diameter", repr(scenario.robot_diameter))
    specs = []
    if coordinator:
        argv = (
            *base, "coordinator", "--scenario", scenario_arg, *common, "--agents", str(agents),
            "--duration", repr(duration), "--kappa", repr(kappa), "--out", str(out_dir),
            "--feedforward" if feedforward else "--no-feedforward", "--law", law, *scale,
            *coordinator_args,
        )  # fmt: skip
        specs.append(ChildSpec("coordinator", 0, argv))
    poses = initial_poses(scenario, agents, seed)
    chosen = list(range(agents)) if ids is None else sorted(ids)
    processes = -(-len(chosen) // per_process)
    for start in range(0, len(chosen), per_process):
        group = chosen[start : start + per_process]
        if per_process == 1:
            (i,) = group
            x, y, theta = (repr(float(v)) for v in poses[i])
            robot_ids: tuple[str, ...] = ("--id", str(i), "--x", x, "--y", y, "--theta", theta)
            agent_ids: tuple[str, ...] = ("--id", str(i))
        else:
            listed = format_ids(group)
            agent_ids = ("--ids", listed)
            robot_ids = agent_ids + tuple(
                arg for i in group for arg in ("--pose", ",".join(repr(float(v)) for v in poses[i]))
            )
        robot = (*base, "robot", *robot_ids, *common, *scale)
        agent = (
            *base, "agent", *agent_ids, *common, "--rate", repr(rate), "--kappa", repr(kappa),
            "--tick-phase", repr(start // per_process / processes), *ff, *scale, *agent_args,
            *body,
        )  # fmt: skip
        members = tuple(group) if per_process > 1 else ()
        if robots:
            specs.append(ChildSpec("robot", group[0], robot, members))
        specs.append(ChildSpec("agent", group[0], agent, members))
    return specs


def recording_args(seed: int, foxglove_port: int | None, record: bool) -> tuple[str, ...]:
    """Coordinator options for the run's records: the seed (run.mcap's metadata), the live
    view's port, and --no-record when recording is off (covswarm.records)."""
    live = () if foxglove_port is None else ("--foxglove", str(foxglove_port))
    return ("--seed", str(seed), *live, *(() if record else ("--no-record",)))


def impairment_args(loss: float, delay: float, seed: int) -> tuple[str, ...]:
    """Agent options that inject pose loss and delay (none when both are zero)."""
    if loss == 0.0 and delay == 0.0:
        return ()
    return ("--drop-poses", repr(loss), "--delay-poses", repr(delay), "--pose-seed", str(seed))


def console_spec(
    base: Sequence[str], *, endpoint: str, swarm: str, port: int, secure: Path | None = None
) -> ChildSpec:
    """The operator console of ``covswarm run --console``: ``covswarm console`` on
    127.0.0.1:``port`` (no token on loopback); it holds no liveliness token, so the
    supervisor counts it ready once spawned."""
    secured = () if secure is None else ("--secure", str(secure))
    argv = (
        *base, "console", "--connect", endpoint, "--swarm", swarm, "--port", str(port), *secured,
    )  # fmt: skip
    return ChildSpec("console", 0, argv)
