"""``covswarm coordinator``: broadcasts the moving domain S(t) and monitors the team.

The coordinator is the mission clock. It broadcasts Domain messages at a fixed rate
(vertices, vertex velocities, wall-clock stamp, mission time) so agents can extrapolate
between messages; it holds the domain at t = 0 ("waiting") until every agent and robot holds
a liveliness token, runs the scenario for its duration, says "done" for a moment and exits.

It is the one process that subscribes to every pose: it samples the aggregate error e_a(t)
over the robots alive, publishes Status, reports processes whose liveliness token
disappears and at the end writes the same outputs as ``covswarm sim`` (mission.report).
The decisions are in coordinator.core (sans-IO, unit-tested without a network), the Zenoh
shell in coordinator.link, the outputs in coordinator.outputs; this module is the CLI.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import click

from covswarm.coordinator.broadcastable import check_broadcastable
from covswarm.coordinator.config import (
    DEPLOY_TIMEOUT,
    MISSION_FILE,
    SCRIPT_FILE,
    STEERING_JOURNAL,
    CoordinatorConfig,
    planned_wall,
)
from covswarm.coordinator.core import (
    TILE_SPACINGS,
    WAITING,
    CoordinatorCore,
    CoordinatorSettings,
)
from covswarm.coordinator.link import CoordinatorLink
from covswarm.coordinator.outputs import (
    open_recorder,
    read_mission_start,
    read_script_clock,
    write_run_outputs,
)
from covswarm.coordinator.pace import pace_sentence
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import SCENARIO_HELP
from covswarm.protocol import check_swarm
from covswarm.protocol.security import SECURE_OPTION, watch_expiry
from covswarm.protocol.session import open_session, session_config
from covswarm.records.live import FOXGLOVE_OPTION
from covswarm.records.recorder import LiveViewError
from covswarm.runtime.claims import claim_exclusive
from covswarm.runtime.clock import StopFlag, scaled
from covswarm.runtime.options import (
    MAX_RATE,
    TIME_SCALE_OPTION,
    agents_option,
    check_deploy_options,
    connect_option,
    deploy_options,
    float_option,
    kappa_option,
    law_option,
    out_option,
    switch_option,
)

log = logging.getLogger("covswarm.coordinator")

# The coordinator's log line when the run's outputs could not be written; the launcher
# repeats it in its last line.
OUTPUTS_NOT_WRITTEN = "run outputs not written in"


def run_coordinator(config: CoordinatorConfig) -> None:
    """One coordinator run: wait for the team, broadcast, monitor, write the outputs."""
    try:
        scenario = load_scenario(config.scenario, config.agents)
        check_swarm(config.swarm)
        settings = CoordinatorSettings.from_config(config, scenario)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    try:
        check_broadcastable(scenario, settings.kappa, settings.duration)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    if settings.crowding.crowded:
        log.warning(settings.crowding.warning(settings.agents))
    mission_file = config.out / MISSION_FILE
    resume_wall = script = None
    if config.resume:
        try:
            resume_wall = read_mission_start(mission_file, config.swarm)
            script = read_script_clock(config.out / SCRIPT_FILE, config.swarm)
        except ValueError as exc:
            raise click.UsageError(f"--resume: {exc}") from None
    stop = StopFlag()
    zenoh_config = session_config(list(config.connect), secure=config.secure, role="coordinator")
    planned = planned_wall(settings.duration, settings.deploy_timeout, settings.time_scale)
    expiry = watch_expiry(config.secure, "coordinator", planned=planned)
    with open_session(zenoh_config) as session:
        expiry.start()  # its certificate's end stops the run; the outputs are still written
        claim = claim_exclusive(session, config.swarm, "coordinator", 0)
        if claim is None:
            raise click.ClickException(f"swarm {config.swarm!r} already has a coordinator")
        try:
            recorder = open_recorder(config, settings)
        except LiveViewError as exc:
            raise click.ClickException(f"--foxglove: {exc}") from None
        # e_a's tessellation on a worker thread: at 1000 robots it outlasts a broadcast period.
        sampler = ThreadPoolExecutor(max_workers=1, thread_name_prefix="e_a")
        core = CoordinatorCore(settings, recorder=recorder, offload=sampler.submit)
        try:
            if resume_wall is not None:
                journal = config.out / STEERING_JOURNAL
                lines = journal.read_text(encoding="utf-8").splitlines() if journal.exists() else []
                now = scaled(time.monotonic, settings.time_scale)()  # the Ticker's clock
                core.resume(resume_wall, now, time.time(), lines, script)
            CoordinatorLink(session, core, mission_file).run(stop)
        finally:
            sampler.shutdown(cancel_futures=True)
            if recorder is not None:
                recorder.note("recording", {**core.recording_note(), **recorder.counts})
                recorder.close()
    expiry.cancel()
    if recorder is not None and core.phase.state != WAITING:
        mission = core.phase.mission_time(core.phase.stopped_at or 0.0)
        cost = core.recording
        log.info(
            "recording took %.2f s of CPU over %.1f s of mission (%.2f%% of a core); %s; %s",
            cost["seconds"],
            mission,
            100 * cost["seconds"] / max(mission / config.time_scale, 1e-9),
            {k: v for k, v in cost.items() if k != "seconds"},
            recorder.counts,
        )
    if not core.observed.record.t:
        # run.mcap holds what was heard before the start (tokens, steering): kept
        log.info("no samples recorded (the mission never started): no summary or plots written")
        expiry.exit_if_expired()
        return
    disk = None if recorder is None else recorder.disk
    try:
        write_run_outputs(config.out, settings, core.observed, core.steering, disk)
    except OSError as exc:  # a full disk: the mission is over, its records stay readable
        log.error("%s %s: %s", OUTPUTS_NOT_WRITTEN, config.out, exc.strerror or exc)
        raise SystemExit(1) from None
    pace = core.pace.summary(core.observed.agent_stats, core.observed.mission_time())
    log.info("%s", pace_sentence(pace))
    log.info("wrote %s", config.out)
    expiry.exit_if_expired()


@click.command("coordinator")
@click.option("--scenario", default="passage", show_default=True, help=SCENARIO_HELP)
@connect_option("Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable).")
@click.option("--swarm", required=True, help="Swarm name (key prefix) shared by the run.")
@agents_option("Team size to wait for [scenario].")
@float_option("--duration", low=0, low_open=True, help="Mission length, s [scenario].")
@float_option("--rate", low=0.1, high=MAX_RATE, default=20.0, help="Domain broadcasts per second.")
@float_option(
    "--sample-rate",
    low=0.1,
    high=MAX_RATE,
    default=10.0,
    help="e_a samples per second (at most).",
)
@kappa_option("Gain [scenario].")
@float_option(
    "--tile-size",
    low=0,
    low_open=True,
    help=f"Beacon tile side broadcast to every agent, m [{TILE_SPACINGS:g} x the team's mean "
    "spacing in S(0)].",
)
@switch_option("feedforward", "How the agents run (recorded in summary.json).")
@law_option("The agents' control law (recorded in summary.json).")
@out_option(required=True, help="Output folder.")
@switch_option(
    "resume",
    f"Continue the mission recorded in OUT/{MISSION_FILE} (a restarted coordinator).",
    default=False,
)
@float_option(
    "--max-domain-speed",
    low=0,
    low_open=True,
    help="Fastest a steered vertex of S may move, m/s [robots' top speed less kappa x "
    "one body diameter, at least a quarter of it].",
)
@switch_option(
    "record", "Write OUT/run.mcap and OUT/trajectories.csv (docs/records.md).", show_default=True
)
@switch_option(
    "record-states",
    "Record every AgentState the agents send in run.mcap (/agents/states), with --record or "
    "--foxglove.",
    show_default=True,
)
@float_option(
    "--agent-rate",
    low=0,
    low_open=True,
    default=10.0,
    help="The agents' control rate, Hz (what their reported rates are held against).",
)
@switch_option(
    "pace",
    "Slow the mission's script down to the rate the agents hold (an overloaded machine); "
    "--no-pace: S runs at the script's speed whatever they hold.",
)
@deploy_options(DEPLOY_TIMEOUT)
@FOXGLOVE_OPTION
@click.option("--seed", type=int, help="Seed of the robots' start (recorded in run.mcap only).")
@TIME_SCALE_OPTION
@SECURE_OPTION
def coordinator_command(foxglove_port: int | None, **options: Any) -> None:
    """Broadcast the moving domain, monitor the team, write the run's outputs."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s coordinator %(message)s")
    check_deploy_options(click.get_current_context(), options["deploy_error"])
    # FOXGLOVE_OPTION (shared with covswarm run) names its value foxglove_port.
    run_coordinator(CoordinatorConfig(foxglove=foxglove_port, **options))
