"""``covswarm run``: one real distributed run on this machine.

Starts an embedded Zenoh router (a router-mode session in this process, on a free loopback
port), then the coordinator, one ``covswarm robot`` and one ``covswarm agent`` process per
robot, staggered: on a 2-core machine start-up (imports) dominates, so only a few processes
start at a time and the next ones wait until those hold their liveliness token. Shows live
progress, reports children that die, and shuts everything down on completion, Ctrl-C or
SIGTERM. Children die with the launcher even if it is SIGKILLed (PR_SET_PDEATHSIG).

Scaling (docs/scaling.md): ``--agents-per-process K`` packs K brains into one agent
process and K robots into one robot process; ``auto`` packs by what holds real time
(deploy.plan.auto_per_process) and hosts a big team's robots in one process per core;
``--time-scale`` runs mission time slower than wall time (``auto``: as slow as this host
needs to hold the rate, deploy.plan.holding_time_scale). Robot and agent processes run at
a lower priority than the launcher (its embedded router) and the coordinator, which serve
them all (deploy.processes.CHILD_NICE). A team spread over several hosts runs one
``covswarm run`` per host with the same ``--swarm``, ``--agents`` and ``--seed``:
``--ids`` picks the host's slice, ``--router-listen``/``--router-connect`` link the hosts'
embedded routers, and every host but one says ``--no-coordinator``.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import click
from rich.console import Console

from covswarm.coordinator.broadcastable import check_broadcastable
from covswarm.coordinator.config import DEPLOY_TIMEOUT, planned_wall
from covswarm.coordinator.main import OUTPUTS_NOT_WRITTEN
from covswarm.coordinator.pace import check_deploy_kappa
from covswarm.deploy.display import live_brain_tick, summary_table
from covswarm.deploy.host_speed import measure_brain_tick
from covswarm.deploy.plan import (
    BRAIN_TICK,
    SOLO_PER_CORE,
    RunConfig,
    auto_robots_per_process,
    capacity_note,
    command_timeout,
    console_spec,
    covswarm_argv,
    holding_time_scale,
    parse_per_process,
    plan_children,
    scenario_kappa,
    team_size,
)
from covswarm.deploy.router import free_port, zenoh_session
from covswarm.deploy.supervisor import run_processes
from covswarm.mission.crowding import crowding
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import SCENARIO_HELP, route_lines
from covswarm.protocol import check_swarm, new_swarm_name
from covswarm.protocol.keys import parse_ids
from covswarm.protocol.security import (
    ROUTER,
    SECURE_OPTION,
    credentials_end,
    expiry_warning,
    require_identities,
)
from covswarm.records.live import FOXGLOVE_OPTION, LIVE_HOST, port_is_free
from covswarm.runtime.options import (
    ENDPOINT,
    FAULT_DELAY_MAX,
    MAX_RATE,
    RUN_TIME_SCALE_OPTION,
    agents_option,
    check_deploy_options,
    check_new_folder,
    default_out,
    deploy_options,
    float_option,
    kappa_option,
    law_option,
    out_option,
    pose_delay_option,
    pose_loss_option,
    refuse_unused,
    switch_option,
)
from covswarm.sim_robot.process import gather_drops

# A secured run's console token, handed to the console child (owner-only; removed at the end).
CONSOLE_TOKEN = "console.token"


@click.command("run")
@click.option("--scenario", default="passage", show_default=True, help=SCENARIO_HELP)
@agents_option("Team size [scenario default].")
@kappa_option("Gain [scenario].")
@switch_option("feedforward", "Agents use the dc/dt feedforward term (--no-feedforward: drop it).")
@law_option(
    "The agents' control law: da, domain-motion feedforward (docs/tracking.md); d1, the "
    "paper's TVD-D1."
)
@float_option("--duration", low=0, low_open=True, help="Mission length, s [scenario default].")
@click.option(
    "--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Initial poses."
)
@out_option(help="Output folder [runs/run-<scenario>-<timestamp>].")
@float_option(
    "--rate", low=0.5, high=MAX_RATE, default=10.0, help="Control rate of every agent, Hz."
)
@float_option(
    "--state-period",
    low=0.0,
    high=0.5,
    default=0.1,
    help="Least time between two AgentStates of an agent, s (0: one every control step).",
)
@click.option("--swarm", help="Swarm name (key prefix) [random, unique per run].")
@click.option(
    "--connect", type=ENDPOINT, help="Join this Zenoh endpoint instead of an embedded router."
)
@click.option(
    "--ids",
    help="Only these robot ids (and their agents) on this host, e.g. 0-49 [all]; needs --swarm.",
)
@switch_option(
    "coordinator",
    "--no-coordinator: the coordinator runs on another host: end when it says done; needs --swarm.",
)
@click.option(
    "--router-listen",
    type=ENDPOINT,
    multiple=True,
    help="Endpoint the embedded router listens on, e.g. tls/10.0.0.1:7447 (beyond loopback "
    "with --secure) [a free loopback port].",
)
@click.option(
    "--router-connect",
    type=ENDPOINT,
    multiple=True,
    help="Another host's router for the embedded router to connect to (repeatable).",
)
@click.option(
    "--robots",
    type=click.Choice(["sim", "none"]),
    default="sim",
    show_default=True,
    help="sim: a simulated robot per agent; none: the robots come from bridges that join "
    "the swarm (covswarm bridge ros2), and the mission starts once all are there. Needs --swarm.",
)
@float_option(
    "--cmd-timeout",
    low=0.01,
    help="The robots' command timeout, s: how long a robot drives its last command, which "
    "the agents plan for; with --robots none, the bridge's --cmd-timeout [0.5, or longer "
    "for a team the host cannot step at --rate: launch.json's cmd_timeout_s].",
)
@click.option(
    "--agents-per-process",
    default="auto",
    show_default=True,
    help="Agent brains per agent process and robots per robot process: a positive integer, "
    "or auto (one each up to 8 agents per core on this host, else one agent process per "
    "core, split further where a batch would not hold the rate; deploy/plan.py).",
)
@RUN_TIME_SCALE_OPTION
@pose_loss_option(
    "Fault injection: every agent drops this fraction of the positions it receives (its "
    "robot's poses and its neighbours' AgentStates; seeded)."
)
@pose_delay_option("Fault injection: every agent receives those positions this many s late.")
@float_option(
    "--fault-step-delay",
    low=0.0,
    high=FAULT_DELAY_MAX,
    default=0.0,
    help="Fault injection: every agent step takes this many s more (a sleep): a starved team.",
)
@switch_option(
    "pace",
    "The coordinator slows the mission down to the rate the agents hold (--no-pace: S keeps "
    "the script's speed).",
)
@deploy_options(DEPLOY_TIMEOUT)
@switch_option("safety", "Agents filter for collisions (--no-safety: they run without the filter).")
@switch_option(
    "prediction",
    "--no-prediction: agents control from poses as received, not predicted to the command's time.",
)
@float_option(
    "--command-latency",
    low=0.0,
    high=0.5,
    default=0.0,
    help="Every agent's --command-latency: the robots' known time from a command's stamp to "
    "the wheels acting on it, s; at most the measured one (docs/real-robots.md).",
)
@float_option(
    "--startup-timeout",
    low=0,
    low_open=True,
    default=300.0,
    help="Give up if the team is not up after this many s.",
)
@FOXGLOVE_OPTION
@switch_option("record", "The coordinator writes run.mcap and trajectories.csv.", show_default=True)
@switch_option(
    "record-states",
    "The coordinator records every AgentState in run.mcap (/agents/states).",
    show_default=True,
)
@click.option(
    "--console",
    is_flag=True,
    help="Also serve the operator console (covswarm console) on 127.0.0.1.",
)
@click.option(
    "--console-port",
    type=click.IntRange(0, 65535),
    default=7480,
    show_default=True,
    help="Port of --console (0: a free one).",
)
@float_option(
    "--max-domain-speed",
    low=0,
    low_open=True,
    help="Fastest a steered vertex of S may move, m/s [the coordinator's default].",
)
@float_option(
    "--brain-tick",
    low=0,
    low_open=True,
    high=1.0,
    help="s of CPU one brain-tick costs live on this host, for auto packing and the capacity "
    "warning (and whether robots keep commands for late steps) [measured at launch for a "
    "team beyond 8 agents per core: deploy/host_speed.py].",
)
@SECURE_OPTION
def run_command(foxglove_port: int | None, **options: Any) -> None:
    """Run the swarm as real processes over Zenoh on this machine (or this host's slice)."""
    ctx = click.get_current_context()
    refuse_unused(ctx, ("console_port",), options["console"], "--console")
    recorded = options["record"] or not options["record_states"]
    refuse_unused(ctx, ("record_states",), recorded, "a recorded run (not with --no-record)")
    check_deploy_options(ctx, options["deploy_error"])
    # FOXGLOVE_OPTION (shared with covswarm coordinator) names its value foxglove_port.
    run_swarm(RunConfig(foxglove=foxglove_port, **options))


def host_brain_tick(run: RunConfig, agents: int, cores: int, console: Console) -> tuple[float, str]:
    """s of CPU one brain-tick costs live here, for ``agents`` brains on ``cores`` cores,
    and where the figure comes from (launch.json's ``brain_tick_source``): "given"
    (``--brain-tick``), else "measured" (deploy.host_speed, ~2 s) when they are beyond a
    process per brain, else "reference" (plan.BRAIN_TICK: a process per brain, packing is
    not in question)."""
    if run.brain_tick is not None:
        return run.brain_tick, "given"
    if agents <= SOLO_PER_CORE * max(cores, 1):
        return BRAIN_TICK, "reference"
    measured = measure_brain_tick()
    console.log(measured.describe())
    return measured.brain_tick, "measured"


def hand_over_token(path: Path) -> str:
    """A new console token, written to ``path`` for the console child alone (owner-only;
    never on a command line, which every local user can read, nor in its log) and returned
    for the URL the launcher prints: a secured console needs it even on loopback
    (console.access.needs_token)."""
    from covswarm.console.access import new_token

    token = new_token()
    path.unlink(missing_ok=True)  # O_EXCL below: a file planted there is not reused
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as file:
        file.write(token + "\n")
    return token


def run_swarm(run: RunConfig) -> None:
    """The run ``run`` describes: router, children, live display, summary; exits with its
    status."""
    if (run.ids is not None or not run.coordinator) and not run.swarm:
        raise click.UsageError("--ids and --no-coordinator need --swarm (the same on every host)")
    if run.robots == "none" and not run.swarm:
        raise click.UsageError("--robots none needs --swarm, the name the bridges join")
    if run.connect is not None and (run.router_listen or run.router_connect):
        raise click.UsageError("--connect joins a router: no --router-listen/--router-connect")
    if run.secure is None and run.connect is None and run.router_listen:
        from covswarm.protocol.session import check_open_listen  # imports zenoh

        try:
            check_open_listen(run.router_listen)
        except ValueError as exc:
            raise click.UsageError(str(exc)) from None
    if run.time_scale is None and (run.ids is not None or not run.coordinator):
        raise click.UsageError(
            "--time-scale auto times this host alone: a team over several hosts needs one "
            "number on all of them"
        )
    if run.console and run.console_port and not port_is_free(run.console_port):
        raise click.UsageError(f"--console-port: 127.0.0.1:{run.console_port} is already in use")
    if run.foxglove is not None and not run.coordinator:
        raise click.UsageError("--foxglove: the coordinator serves the live view; run it there")
    if run.foxglove is not None and not port_is_free(run.foxglove):
        raise click.UsageError(f"--foxglove: {LIVE_HOST}:{run.foxglove} is already in use")
    if run.foxglove == 0:  # a free one, chosen here so that the launcher can say which
        run = replace(run, foxglove=free_port(LIVE_HOST))
    try:
        scenario = load_scenario(run.scenario, run.agents)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    try:
        swarm = check_swarm(run.swarm) if run.swarm is not None else new_swarm_name()
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--swarm") from None
    n = team_size(run, scenario)
    try:
        ids = None if run.ids is None else parse_ids(run.ids)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--ids") from None
    if ids is not None and ids[-1] >= n:
        raise click.BadParameter(f"ids go up to {ids[-1]} in a team of {n}", param_hint="--ids")
    here = n if ids is None else len(ids)
    cores = len(os.sched_getaffinity(0))
    duration = scenario.duration if run.duration is None else run.duration
    try:
        check_broadcastable(scenario, scenario_kappa(run, scenario), duration)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    try:
        check_deploy_kappa(run.deploy_error, run.deploy_kappa)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    if run.agents_per_process.strip().lower() != "auto":
        try:  # a number needs no brain-tick: refused before the host is timed
            parse_per_process(run.agents_per_process, here)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--agents-per-process") from None
    # Timed once the cheap checks passed: a refused run does not wait for it.
    console = Console()
    brain_tick, brain_tick_source = host_brain_tick(run, here, cores, console)
    if run.time_scale is None:
        run = replace(run, time_scale=holding_time_scale(here, cores, run.rate, brain_tick))
        console.log(
            f"--time-scale auto: {run.time_scale:g} ({here} brains at {run.rate:g} Hz, "
            f"~{1e3 * brain_tick:.3g} ms a brain-tick, {cores} cores)"
        )
    wall_rate = run.rate * run.time_scale  # control periods per second of wall time
    try:
        packing = parse_per_process(run.agents_per_process, here, cores, wall_rate, brain_tick)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--agents-per-process") from None
    robot_packing = packing
    if run.agents_per_process.strip().lower() == "auto":
        robot_packing = auto_robots_per_process(here, cores)
    out_dir = run.out
    if out_dir is None:
        out_dir = default_out("run", scenario.name)  # new by construction
    else:
        check_new_folder(out_dir)
    run = replace(run, swarm=swarm, out=out_dir)
    if run.secure is not None:
        # Every child needs its own certificate: one missing would make that child exit and
        # the launcher wait for its token forever, so all are checked before anything starts.
        planned = plan_children(
            run, scenario, endpoint="tcp/127.0.0.1:7447", base=(), ids=ids,
            per_process=packing, robots_per_process=robot_packing,
        )  # fmt: skip
        names = {s.identity for s in planned} | ({"console"} if run.console else set())
        if run.connect is not None:
            names.add("operator")  # the launcher's own session joins that router as it
        from covswarm.protocol.session import check_router_folder  # imports zenoh

        try:
            require_identities(run.secure, sorted(names))
            if run.connect is None:  # the embedded router's files, as covswarm router's
                check_router_folder(run.secure, run.router_listen or ())
                names.add(ROUTER)
            end, ending = credentials_end(run.secure, sorted(names))
        except ValueError as exc:
            raise click.UsageError(str(exc)) from None
        # Said here once for the run (each child also logs it).
        wall = planned_wall(duration, run.deploy_timeout, run.time_scale)
        if (warning := expiry_warning(ending, end, datetime.now(timezone.utc), wall)) is not None:
            console.log(f"[yellow]warning: {warning}")
    log_dir = out_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    if (crowd := crowding(scenario, n, duration)).crowded:
        console.log(f"[yellow]warning: {crowd.warning(n, safety=run.safety)}")
    planned = command_timeout(here, cores, run.rate, run.time_scale, brain_tick)
    timeout = planned if run.cmd_timeout is None else run.cmd_timeout
    if timeout < planned:
        console.log(
            f"[yellow]warning: --cmd-timeout {timeout:g} s is shorter than the {planned:.2g} s "
            "this host's steps of the team need: robots will stop between commands"
        )
    if (note := capacity_note(here, cores, run.rate, run.time_scale, brain_tick)) is not None:
        console.log(f"[yellow]warning: {note}; robots keep a command for {timeout:.2g} s")
    with zenoh_session(
        run.connect, max(1000, 4 * n), run.router_listen, run.router_connect, secure=run.secure
    ) as (session, endpoint):  # fmt: skip
        console.log(
            f"swarm {swarm} on {endpoint}; {here if run.robots == 'sim' else 'no'} robots + "
            f"{here} agents here (team of {n}), {packing} per process"
            f"{'' if robot_packing == packing else f' ({robot_packing} per robot process)'}; "
            f"logs in {log_dir}"
        )
        specs = plan_children(
            run, scenario, endpoint=endpoint, base=covswarm_argv(), ids=ids,
            per_process=packing, robots_per_process=robot_packing, cmd_timeout=timeout,
        )  # fmt: skip
        if run.foxglove is not None:
            console.log(f"Foxglove live view on ws://{LIVE_HOST}:{run.foxglove} (docs/records.md)")
        console_url = token_file = None
        if run.console:
            port = run.console_port or free_port()
            first = 1 if specs and specs[0].role == "coordinator" else 0
            console_url = f"http://127.0.0.1:{port}/"
            if run.secure is None:
                console.log(f"operator console on {console_url}")
            else:
                token_file = out_dir.resolve() / CONSOLE_TOKEN
                # One line, never wrapped: the URL is to be copied whole.
                console.print(
                    f"operator console on {console_url}?token={hand_over_token(token_file)}",
                    soft_wrap=True, markup=False, highlight=False,
                )  # fmt: skip
            specs.insert(first, console_spec(
                covswarm_argv(), endpoint=endpoint, swarm=swarm, port=port, secure=run.secure,
                token_file=token_file,
            ))  # fmt: skip
        (out_dir / "launch.json").write_text(
            json.dumps({"swarm": swarm, "endpoint": endpoint, "console": console_url,
                        "foxglove": run.foxglove,
                        "console_token_file": None if token_file is None else str(token_file),
                        "agents_per_process": packing,
                        "robots_per_process": robot_packing,
                        "brain_tick_s": brain_tick, "brain_tick_source": brain_tick_source,
                        "time_scale": run.time_scale,
                        "cmd_timeout_s": timeout,
                        "argv": [s.argv for s in specs]}, indent=1) + "\n", encoding="utf-8",
        )  # fmt: skip
        try:
            result = run_processes(
                specs, session=session, swarm=swarm, agents=n, duration=duration,
                log_dir=log_dir, startup_timeout=run.startup_timeout, console=console,
                routes=tuple(route_lines(scenario.motion)),
            )  # fmt: skip
        finally:
            if token_file is not None:
                token_file.unlink(missing_ok=True)  # the token dies with the run
    summary_path = out_dir / "summary.json"
    summary = None
    if summary_path.exists():
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    held = None if summary is None else (summary.get("pace") or {}).get("held_rate_hz")
    (out_dir / "resources.json").write_text(
        json.dumps(
            {
                "rss_mb": result.rss,
                "cpu_percent_of_core": result.cpu,
                "robots_per_process": result.members,
                "brain_tick_s": live_brain_tick(result, held, run.time_scale),
            },
            indent=1,
        )
        + "\n",
        encoding="utf-8",
    )
    console.print()  # the live display's last frame ends without a newline off a terminal
    if summary is not None:
        # Robots count what they drop per reason and say it once, at exit: a flood of forged
        # or broken commands shows here, not only in their logs.
        summary["robot_drops"] = {
            rid: counts
            for log in sorted(log_dir.glob("robot-*.log"))
            for rid, counts in gather_drops(
                log.read_text(encoding="utf-8", errors="replace")
            ).items()
        }
        try:
            summary_path.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
        except OSError as exc:  # a full disk: the coordinator's summary stays as it was
            console.log(f"[yellow]robot drops not added to {summary_path}: {exc.strerror}")
        console.print(summary_table(summary, result, out_dir, run.time_scale))
    elif not run.coordinator:
        console.log(f"the coordinator's host writes the summary; resources in {out_dir}")
    else:
        log = log_dir / "coordinator-0.log"
        lines = log.read_text("utf-8", errors="replace").splitlines() if log.exists() else []
        why = [line for line in lines if OUTPUTS_NOT_WRITTEN in line]
        reason = f": {why[-1].split(OUTPUTS_NOT_WRITTEN, 1)[1].strip()}" if why else ""
        console.log(f"[red]no summary written{reason} (see {log})")
        result.exit_code = result.exit_code or 1
    sys.exit(result.exit_code)
