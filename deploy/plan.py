"""What ``covswarm run`` starts: one ChildSpec (role, ids, command line) per process.

``covswarm run``'s options are one RunConfig; each child's options are its own config
object (CoordinatorConfig, RobotConfig, AgentProcessConfig), made from the RunConfig by one
function per kind and written as a command line by runtime.options.config_argv.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from covswarm.agent.config import AgentProcessConfig
from covswarm.coordinator.config import DEPLOY_TIMEOUT, CoordinatorConfig
from covswarm.mission.scenarios import Scenario
from covswarm.protocol.keys import format_ids
from covswarm.protocol.security import SINGLE_ROLES, identity_name
from covswarm.runtime.options import config_argv
from covswarm.sim_robot.config import RobotConfig


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

    @property
    def identity(self) -> str:
        """The certificate it presents under ``--secure`` (protocol.security): a robot or
        agent process's names exactly the robots or brains it hosts."""
        return identity_name(self.role, None if self.role in SINGLE_ROLES else self.members)


# The default packing of brains into agent processes (``--agents-per-process auto``).
# Up to SOLO_PER_CORE agents per core each gets its own process (a process is a robot's
# unit of failure, as on real robots; 100 robots one per process took 9 minutes to start,
# docs/scaling.md). Beyond, packing follows what holds real time, from the CPU cost of one
# brain-tick (a brain's whole period in a packed process: draining, decoding, step, filter,
# encoding, puts) as live runs measure it (the summary's "CPU per brain-tick (live)", which
# adds Zenoh to ``covswarm bench --brain-tick``). That is the host's: the launcher measures
# it (deploy.host_speed) and passes it to every function below as ``brain_tick``:
# - if the team fits, agents x rate x brain_tick within the cores the rest of the run
#   leaves them (:func:`agent_cores`), one agent process per core, of at most
#   PERIOD_SHARE / (rate x brain_tick) brains each: a process steps its brains one after
#   the other, and that keeps its batch within three quarters of a period (150 at 10 Hz
#   and 0.5 ms; at half a period, 300 robots ran in 3 processes of 100 rather than 2 of
#   150 and took 149 % of agent CPU rather than 129-138 %: more processes than cores take
#   turns);
# - if it does not, no packing holds the rate: one agent process per core, as many brains
#   as it takes. Fewer processes start sooner (each costs its imports and ~80 MB) and share
#   more decoding; the brains whose turn comes after a period's deadline hold (agent.pack)
#   either way, and the launcher says which rate the machine could hold
#   (:func:`capacity_note`).
SOLO_PER_CORE = 8
# s of CPU per brain-tick where none was measured (a team small enough for a process per
# brain, or a test's): 0.43-0.55 ms live for 300 to 1000 robots in packs of 150 to 500 on
# this 2-core VM, 2026-11-27 18:00-18:03 UTC (docs/scaling.md, "Half a millisecond a
# brain-tick").
BRAIN_TICK = 0.5e-3
# What the rest of a run takes from the agents' cores (:func:`agent_cores`): a fixed
# OTHER_CORES (the router, the coordinator, the launcher, the system) and, per robot,
# OTHER_TICKS brain-ticks of CPU a second (its simulated robot's steps and poses, the
# coordinator's monitoring and recording of it, the router's forwarding). Live on this
# 2-core VM, 29 Nov 2026: 1000 robots, 0.74-0.78 cores outside the agents at ~1 ms a
# brain-tick (six runs of circle-1000, 28-29 Nov); 300 robots at --time-scale 0.3-0.4,
# 0.30-0.34 cores (docs/scaling.md, "The launcher times the host").
OTHER_CORES = 0.2
OTHER_TICKS = 0.6
# A process far from holding its rate costs more per brain-tick: its brains take turns
# late, skip periods and stop their robots, and each turn takes in more at once (every
# domain and beacon since the last one). Live, 1000 robots on this 2-core VM at 10 and at 3
# Hz asked: 0.72-0.99 ms (held 1.2-2.0 Hz) against BRAIN_TICK, 2026-11-27 19:58-20:31 UTC
# (docs/scaling.md, "A thousand robots in real time"); 400 robots, which held 8.0 of 10 Hz,
# stayed at BRAIN_TICK. On 29 Nov, 2.31-2.45 ms live against 1.08 ms measured at launch
# (docs/scaling.md, "The launcher times the host"). So :func:`capacity_note` expects a rate
# between the two; the time scale it suggests holds the rate, at the brain-tick.
LATE_PER_BRAIN_TICK = 2.0
PERIOD_SHARE = 0.75  # of a control period, for one process's batch of brains


def agent_cores(agents: int, cores: int, brain_tick: float = BRAIN_TICK) -> float:
    """Cores of ``cores`` left to ``agents`` brains by the rest of their run (OTHER_CORES,
    OTHER_TICKS brain-ticks of ``brain_tick`` s per robot and second), at least a quarter."""
    cores = max(cores, 1)
    return max(cores - OTHER_CORES - OTHER_TICKS * agents * brain_tick, 0.25 * cores)


def fits(agents: int, cores: int, rate: float, brain_tick: float = BRAIN_TICK) -> bool:
    """Whether ``agents`` brains at ``rate`` Hz (of wall time) fit ``cores`` cores, a
    brain-tick costing ``brain_tick`` s of CPU."""
    return agents * rate * brain_tick <= agent_cores(agents, cores, brain_tick)


def auto_per_process(
    agents: int, cores: int, rate: float = 10.0, brain_tick: float = BRAIN_TICK
) -> int:
    """Brains per agent process for ``agents`` brains at ``rate`` Hz (wall time) on a host
    with ``cores`` cores where a brain-tick costs ``brain_tick`` s (the rule above)."""
    if agents <= SOLO_PER_CORE * max(cores, 1):
        return 1
    per_core = -(-agents // max(cores, 1))
    if not fits(agents, cores, rate, brain_tick):
        return per_core
    return max(1, min(per_core, int(PERIOD_SHARE / (rate * brain_tick))))


def fitting_rate(agents: int, cores: int, brain_tick: float = BRAIN_TICK) -> float:
    """Hz (of wall time) at which ``agents`` brains would just fit ``cores`` cores, a
    brain-tick costing ``brain_tick`` s of CPU (:func:`agent_cores`)."""
    return agent_cores(agents, cores, brain_tick) / (agents * brain_tick)


def late_rate(agents: int, cores: int, brain_tick: float = BRAIN_TICK) -> float:
    """Hz of wall time that ``agents`` brains hold on ``cores`` cores when they do not fit:
    the lower end of what :func:`capacity_note` expects (LATE_PER_BRAIN_TICK)."""
    share = agent_cores(agents, cores, brain_tick)
    return share / (agents * LATE_PER_BRAIN_TICK * brain_tick)


def capacity_note(
    agents: int, cores: int, rate: float, time_scale: float = 1.0, brain_tick: float = BRAIN_TICK
) -> str | None:
    """What the launcher says when ``agents`` brains at ``rate`` Hz of mission time, run at
    ``time_scale`` (mission s per wall s), do not fit ``cores`` cores at ``brain_tick`` s
    of CPU a brain-tick (:func:`fits`); None when they do."""
    wall_rate = rate * time_scale
    if fits(agents, cores, wall_rate, brain_tick):
        return None
    need = agents * wall_rate * brain_tick
    held = fitting_rate(agents, cores, brain_tick)
    late = held / LATE_PER_BRAIN_TICK  # late_rate's
    return (
        f"{agents} brains at {rate:g} Hz (x{time_scale:g}: {wall_rate:g} Hz of wall time) "
        f"need ~{need:.1f} cores of agent CPU (~{1e3 * brain_tick:.3g} ms a brain-tick); "
        f"this host has {cores}: expect "
        f"{late / time_scale:.2g}-{held / time_scale:.2g} Hz (the further from the rate, the "
        f"lower: late brains cost up to ~{1e3 * LATE_PER_BRAIN_TICK * brain_tick:.3g} ms a "
        f"brain-tick), or run at --time-scale "
        f"{holding_time_scale(agents, cores, rate, brain_tick):g} (or auto)"
    )


# The share of the rate :func:`capacity_note` expects at best that ``--time-scale auto``
# asks for. The launcher's brain-tick (deploy.host_speed) is a sans-IO pack's; live, with
# Zenoh and the rest of the run on the same cores, it costs more. circle-1000 on this
# 2-core VM, 30 Nov 2026 (launcher: 0.48-0.53 ms, the best-case scale 0.28): at 0.28x the
# agents held 8.56 of 10 Hz (14 % of periods missed, 0.64 ms a brain-tick live), at 0.2x
# 9.99 Hz (0 %, 0.58 ms). Live cost 1.16-1.42 times the launcher's timing in three runs
# that day; at 0.7 the one at 1.42 held 9.64 Hz (4 % missed), so 0.6 (up to 1.67 times);
# docs/scaling.md, "A time scale the host holds" and "The robots act on a command".
HOLDING_SHARE = 0.6


def holding_time_scale(
    agents: int, cores: int, rate: float, brain_tick: float = BRAIN_TICK
) -> float:
    """The time scale (mission s per wall s, at most 1) at which ``agents`` brains hold
    ``rate`` Hz of mission time on ``cores`` cores, a brain-tick costing ``brain_tick`` s of
    CPU: 1 when they fit in real time (:func:`fits`), else HOLDING_SHARE of the scale at
    which they would just fit, rounded down to two significant digits."""
    if fits(agents, cores, rate, brain_tick):
        return 1.0
    scale = HOLDING_SHARE * fitting_rate(agents, cores, brain_tick) / rate
    digits = 1 - math.floor(math.log10(scale))
    return math.floor(scale * 10**digits) / 10**digits


# s: a simulated robot's command timeout, the one its brain assumes too: it stops when its
# brain has said nothing for that long (a dead or stalled brain must not leave it driving).
COMMAND_TIMEOUT = RobotConfig.cmd_timeout
# A team that cannot hold its rate steps each brain every 1 / (held rate) s, and a robot
# that stops at its command timeout before the next step drives less far than its step
# meant while S is paced by the steps held (scripts/held_commands.py: 100 agents at 1.67
# Hz, e_a's second half 0.53 m stopping 0.5 s after each command, 0.019 m at 0.9 s). So
# the timeout covers this many of the gaps expected at the lower end of capacity_note, at
# BRAIN_TICK: not at the host's brain-tick, which on a slower host makes it cover every gap.
# A brain then speeds up a command that stops before its next step (agent.brain.MAX_DUTY),
# and robots that stopped and robots that drove the whole gap differ: 1000 robots on 2
# cores, 29 Nov 2026, one run each, held 0.81 Hz stopping 1.0 s after each command (e_a's
# second half 0.050 m, 5 close approaches) and 0.49 Hz stopping at 2.8 s (the measured
# brain-tick's: 2.87 m, 44 robots outside S, 44 close approaches; docs/scaling.md, "The
# launcher times the host").
GAP_MARGIN = 1.5


def command_timeout(
    agents: int, cores: int, rate: float, time_scale: float = 1.0, brain_tick: float = BRAIN_TICK
) -> float:
    """The robots' command timeout, s of mission time, for ``agents`` brains at ``rate`` Hz
    of mission time run at ``time_scale`` on ``cores`` cores: COMMAND_TIMEOUT when they fit
    at ``brain_tick`` s a brain-tick (:func:`fits`), else GAP_MARGIN gaps between two steps
    at the lowest rate :func:`capacity_note` expects at BRAIN_TICK (1000 robots on 2 cores:
    1.5 Hz, 1.0 s)."""
    if fits(agents, cores, rate * time_scale, brain_tick):
        return COMMAND_TIMEOUT
    late = late_rate(agents, cores) / time_scale  # Hz of mission time, at BRAIN_TICK
    return max(COMMAND_TIMEOUT, GAP_MARGIN / min(late, rate))


def auto_robots_per_process(agents: int, cores: int) -> int:
    """Simulated robots per robot process under ``auto`` packing: one each while the brains
    have a process each (:func:`auto_per_process`), else one robot process per core. A
    robot process steps its robots and encodes their poses as numpy batches
    (sim_robot.process.step_robots, PosePayloads), and its main thread spends ~1 us of CPU
    per robot-step on stepping and a few more on each pose's put, so 500 robots at 20 Hz
    take 10-14 % of a core (scripts/robot_cpu.py, 28 Nov 2026), while every process more
    costs its imports (~0.5 s of CPU at start-up) and ~50 MB."""
    if agents <= SOLO_PER_CORE * max(cores, 1):
        return 1
    return -(-agents // max(cores, 1))


def parse_per_process(
    text: str,
    agents: int,
    cores: int | None = None,
    rate: float = 10.0,
    brain_tick: float = BRAIN_TICK,
) -> int:
    """``--agents-per-process``: a positive integer, or "auto" (:func:`auto_per_process` for
    ``agents`` brains at ``rate`` Hz of wall time on ``cores`` cores, default the cores this
    process may run on, a brain-tick costing ``brain_tick`` s). ValueError with the reason
    for anything else."""
    if text.strip().lower() == "auto":
        if cores is None:
            cores = len(os.sched_getaffinity(0))
        return auto_per_process(agents, cores, rate, brain_tick)
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


@dataclass(frozen=True)
class RunConfig:
    """Every ``covswarm run`` option, with the option's name (``--pose-loss`` is
    ``pose_loss``): the CLI builds it with ``RunConfig(**options)``. ``None``: the
    scenario's value (agents, duration, kappa), a generated name (swarm), a dated folder
    (out), the whole team (ids), an embedded router (connect)."""

    scenario: str = "passage"
    agents: int | None = None
    kappa: float | None = None
    feedforward: bool = True
    law: str = "da"
    duration: float | None = None
    seed: int = 0
    out: Path | None = None
    rate: float = 10.0  # the agents' control rate
    state_period: float = 0.1  # s, least time between two AgentStates of an agent
    swarm: str | None = None
    connect: str | None = None
    ids: str | None = None  # this host's slice, e.g. "0-49"
    coordinator: bool = True  # False: it runs on another host
    router_listen: tuple[str, ...] = ()
    router_connect: tuple[str, ...] = ()
    robots: str = "sim"  # "sim" | "none" (bridges bring them)
    # s: the robots' command timeout, which the agents plan their commands for; None: the
    # launcher's (command_timeout), given to its simulated robots too
    cmd_timeout: float | None = None
    agents_per_process: str = "auto"  # parse_per_process
    time_scale: float | None = 1.0  # None: auto (the launcher's holding_time_scale)
    pose_loss: float = 0.0
    pose_delay: float = 0.0
    safety: bool = True
    prediction: bool = True
    command_latency: float = 0.0  # s from a command's stamp to the wheels acting on it
    startup_timeout: float = 300.0
    foxglove: int | None = None
    record: bool = True
    record_states: bool = True  # the coordinator records the agents' AgentStates
    console: bool = False
    console_port: int = 7480
    max_domain_speed: float | None = None
    secure: Path | None = None
    pace: bool = True  # the coordinator slows the script to what the agents hold
    deploy_error: float | None = None  # m: the coordinator's deploy hold (coordinator.pace)
    deploy_timeout: float = DEPLOY_TIMEOUT  # s: the longest deploy hold
    deploy_kappa: float | None = None  # 1/s: the gain during the hold (None: kappa)
    fault_step_delay: float = 0.0  # s of sleep per agent step (agent.faults.delay_steps)
    # s of CPU a brain-tick costs live on this host; None: measured at launch when the team
    # is beyond a process per brain (deploy.host_speed), else BRAIN_TICK
    brain_tick: float | None = None


# Options of a run that its coordinator and agents take as they are, under the same name.
_EVERY_CHILD = ("feedforward", "law", "time_scale", "secure")


def _passed_on(run: RunConfig, *names: str) -> dict[str, Any]:
    """``run``'s fields ``names``, as keyword arguments of a child's config of the same names."""
    return {name: getattr(run, name) for name in names}


def coordinator_config(run: RunConfig, scenario: Scenario, endpoint: str) -> CoordinatorConfig:
    """The coordinator of ``run``: the team, the mission, where its outputs and records go."""
    if run.swarm is None or run.out is None:
        raise ValueError("a planned run needs its swarm and output folder")
    return CoordinatorConfig(
        connect=(endpoint,),
        agents=team_size(run, scenario),
        duration=scenario.duration if run.duration is None else run.duration,
        kappa=scenario_kappa(run, scenario),
        agent_rate=run.rate,
        **_passed_on(run, "swarm", "out", "scenario", "max_domain_speed", "foxglove"),
        **_passed_on(run, "record", "record_states"),
        **_passed_on(run, "pace", "deploy_error", "deploy_timeout", "deploy_kappa"),
        **_passed_on(run, "seed", *_EVERY_CHILD),
    )


def robot_config(
    run: RunConfig,
    endpoint: str,
    group: Sequence[int],
    poses: np.ndarray,
    packed: bool,
    cmd_timeout: float = COMMAND_TIMEOUT,
) -> RobotConfig:
    """The robot process of ``run`` simulating robots ``group``, at ``poses`` ((n, 3) x, y,
    heading of the full team): ``--id``/``--x``/``--y``/``--theta`` for one robot per
    process, ``--ids`` and a ``--pose`` each when ``packed`` (a group of one included);
    stopping ``cmd_timeout`` s after a robot's last command (:func:`command_timeout`)."""
    common = {
        "connect": (endpoint,),
        "swarm": run.swarm,
        "time_scale": run.time_scale,
        "cmd_timeout": cmd_timeout,
    }
    if not packed:
        (i,) = group
        x, y, theta = (float(v) for v in poses[i])
        return RobotConfig(id=i, x=x, y=y, theta=theta, secure=run.secure, **common)
    pose = tuple(",".join(repr(float(v)) for v in poses[i]) for i in group)
    return RobotConfig(ids=format_ids(list(group)), pose=pose, secure=run.secure, **common)


def agent_config(
    run: RunConfig,
    scenario: Scenario,
    endpoint: str,
    group: Sequence[int],
    phase: float,
    packed: bool,
    cmd_timeout: float = COMMAND_TIMEOUT,
) -> AgentProcessConfig:
    """The agent process of ``run`` running the brains of ``group`` (``--ids`` when
    ``packed``, else ``--id``), starting its control periods at ``phase`` of a period; the
    scenario's bodies for its safety filter; its robots' command timeout."""
    one = not packed
    return AgentProcessConfig(
        connect=(endpoint,),
        cmd_timeout=cmd_timeout,
        id=group[0] if one else None,
        ids=None if one else format_ids(list(group)),
        tick_phase=phase,
        # With a gain of its own for the deploy hold, the agents take the one broadcast
        # with the domain (the coordinator's: the hold's, then the mission's).
        kappa=None if run.deploy_kappa is not None else scenario_kappa(run, scenario),
        pose_seed=run.seed,
        body_diameter=scenario.robot_diameter,
        workspace=scenario.workspace,
        **_passed_on(run, "swarm", "rate", "state_period", "pose_loss", "pose_delay"),
        **_passed_on(run, "prediction", "safety", "command_latency"),
        **_passed_on(run, "fault_step_delay", *_EVERY_CHILD),
    )


def scenario_kappa(run: RunConfig, scenario: Scenario) -> float:
    """The mission's gain of ``run``: --kappa, else the scenario's."""
    return scenario.kappa if run.kappa is None else run.kappa


def team_size(run: RunConfig, scenario: Scenario) -> int:
    """The team of ``run`` (all hosts): --agents, else the scenario's."""
    return scenario.agents if run.agents is None else run.agents


def plan_children(
    run: RunConfig,
    scenario: Scenario,
    *,
    endpoint: str,
    base: Sequence[str],
    ids: Sequence[int] | None = None,
    per_process: int = 1,
    robots_per_process: int | None = None,
    cmd_timeout: float = COMMAND_TIMEOUT,
) -> list[ChildSpec]:
    """Coordinator first (it must see everyone arrive), then robot i and agent i in turn.

    Pairs rather than all robots first: a waiting robot already runs its loop, so starting
    every robot before the (slower to import) agents would load the machine while the
    agents start. The coordinator holds the mission until everyone is up either way.

    ``run``: the run's options (``swarm`` and ``out`` set); ``scenario``: its loaded
    scenario; ``endpoint``: the router the children join; ``base``: how to run covswarm
    (:func:`covswarm_argv`). ``ids``: the slice of the team this host runs (default: all of
    it); a robot starts where it would in the full team, so hosts that split a team with the
    same seed reproduce the one-host run. ``per_process`` brains share an agent process,
    ``robots_per_process`` (default ``per_process``) robots a robot process, which starts
    just before the first agent process of its robots; ``run.coordinator`` False leaves the
    coordinator to another host, ``run.robots`` "none" the robots to bridges (covswarm
    bridge ros2) that join the swarm. ``cmd_timeout``: the simulated robots' command
    timeout, which their brains are told (:func:`command_timeout`).
    Agent process k of n gets ``--tick-phase k/n``: their batches of brains take turns
    within the control period instead of colliding on the cores at chance moments. Each
    child's command line is its config object's (runtime.options.config_argv).
    """
    n = team_size(run, scenario)
    specs = []
    if run.coordinator:
        config = coordinator_config(run, scenario, endpoint)
        specs.append(ChildSpec("coordinator", 0, (*base, "coordinator", *config_argv(config))))
    poses = initial_poses(scenario, n, run.seed)
    chosen = list(range(n)) if ids is None else sorted(ids)
    processes = -(-len(chosen) // per_process)
    robots = per_process if robots_per_process is None else robots_per_process
    robot_groups = [] if run.robots != "sim" else [
        chosen[k : k + robots] for k in range(0, len(chosen), robots)
    ]  # fmt: skip
    for start in range(0, len(chosen), per_process):
        group = chosen[start : start + per_process]
        members = tuple(group) if per_process > 1 else ()
        while robot_groups and robot_groups[0][0] <= group[-1]:
            hosted = robot_groups.pop(0)
            robot = robot_config(run, endpoint, hosted, poses, robots > 1, cmd_timeout)
            argv = (*base, "robot", *config_argv(robot))
            specs.append(ChildSpec("robot", hosted[0], argv, tuple(hosted) if robots > 1 else ()))
        phase = start // per_process / processes
        agent = agent_config(run, scenario, endpoint, group, phase, per_process > 1, cmd_timeout)
        specs.append(ChildSpec("agent", group[0], (*base, "agent", *config_argv(agent)), members))
    return specs


def console_spec(
    base: Sequence[str],
    *,
    endpoint: str,
    swarm: str,
    port: int,
    secure: Path | None = None,
    token_file: Path | None = None,
) -> ChildSpec:
    """The operator console of ``covswarm run --console``: ``covswarm console`` on
    127.0.0.1:``port`` (no token on loopback in open mode; secured, the token in
    ``token_file``, never on its command line); it holds no liveliness token, so the
    supervisor counts it ready once spawned."""
    secured = () if secure is None else ("--secure", str(secure), "--token-file", str(token_file))
    argv = (
        *base, "console", "--connect", endpoint, "--swarm", swarm, "--port", str(port), *secured,
    )  # fmt: skip
    return ChildSpec("console", 0, argv)
