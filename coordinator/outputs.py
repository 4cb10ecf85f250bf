"""What a run leaves behind: summary.json (for ``covswarm sim`` too), the report files,
the run recorder, and the mission file a restarted coordinator resumes from."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from covswarm.coordinator.config import CoordinatorConfig
from covswarm.coordinator.core import CoordinatorSettings, Observed
from covswarm.coordinator.monitor import (
    agent_figures,
    agent_guards,
    losses_summary,
    team_changes_summary,
)
from covswarm.coordinator.pace import Pace, ScriptClock, gain_ramp
from covswarm.coordinator.steering import Steering
from covswarm.mission.crowding import Crowding
from covswarm.mission.physical import agent_wheel_figures, physical_summary
from covswarm.mission.report import neighbor_histogram, steady_state_mean, write_outputs
from covswarm.mission.scenarios import Scenario
from covswarm.mission.world_metrics import (
    DOMAIN_FILE,
    goal_times,
    world_summary,
    write_domain_csv,
)
from covswarm.records.recorder import LIVE_HOST, RunRecorder

log = logging.getLogger("covswarm.coordinator")


def mission_summary(
    scenario: Scenario,
    *,
    law: str,
    feedforward: bool,
    kappa: float,
    duration: float,
    dynamics: str,
    t: np.ndarray,
    error: np.ndarray,
    final_positions: np.ndarray,
    final_polygon: np.ndarray,
    trajectories: np.ndarray,
    crowding: Crowding,
    wheels: dict[str, Any],
    ids: list[int] | None = None,
    script_start: float | None = None,
) -> dict[str, Any]:
    """The summary.json keys every run has, ``covswarm sim``'s and ``covswarm run``'s alike.

    t: (T,) s; error: (T,) m, e_a at t; final_positions: (n, 2) m and final_polygon (k, 2)
    m at the last sample; trajectories: (T, n, 2) m (NaN where a robot is absent), robots
    ``ids`` (default 0..n-1); ``wheels``: the wheel-speed figures
    (mission.physical.wheel_figures' keys, measured or reported by the agents);
    ``script_start``: s, when S started moving after a deploy hold (coordinator.pace):
    the steady-state e_a is over the script's part, not the team spreading over a still S(0).
    """
    scripted = np.ones(t.shape, dtype=bool) if script_start is None else t >= script_start
    return {
        "scenario": scenario.name,
        "agents": int(final_positions.shape[0]),
        "law": law,
        "feedforward": feedforward,
        "kappa": float(kappa),
        "duration": float(duration),
        "dynamics": dynamics,
        "steady_state_error_mean": (
            steady_state_mean(t[scripted], error[scripted]) if scripted.any() else math.nan
        ),
        "final_error": float(error[-1]),
        "initial_error": float(error[0]),
        "neighbor_histogram": neighbor_histogram(final_positions, final_polygon),
        "crowding": crowding.to_dict(),
        **physical_summary(t, trajectories, scenario.robot_diameter, ids)[0],
        **wheels,
    }


def run_goals(
    t: np.ndarray,
    polygons: list[np.ndarray],
    scenario_goals: tuple[tuple[float, float], ...],
    steering: Steering | None,
    pace: Pace | None = None,
) -> tuple[list[tuple[float, float]], list[float | None]]:
    """The goals of a run and when S's centroid reached each (s, None if never): the
    scenario's (its route's goals, in order, while its script moves S: until the first
    accepted steering request) and every accepted goto's goal, from its acceptance until the
    next accepted request (a goto pre-empted before arriving is not reached).
    (covswarm.mission.world_metrics.goal_times in each window.) ``pace``: the run's script
    clock, whose script times the steering records are in (None: the same as ``t``)."""
    accepted = [] if steering is None else [r for r in steering.records if r.accepted]
    when = [r.t if pace is None else pace.mission_time(r.t) for r in accepted]
    windows: list[tuple[float, float, list[tuple[float, float]]]] = []
    first = when[0] if accepted else math.inf
    if scenario_goals:
        windows.append((-math.inf, first, list(scenario_goals)))
    for k, record in enumerate(accepted):
        request = record.request or {}
        if request.get("kind") == "goto":
            until = when[k + 1] if k + 1 < len(accepted) else math.inf
            windows.append((when[k], until, [tuple(request["goal"])]))
    goals: list[tuple[float, float]] = []
    times: list[float | None] = []
    for begin, end, wanted in windows:
        rows = [i for i, when in enumerate(t) if begin <= when <= end]
        goals += wanted
        if rows:
            times += goal_times(t[rows], [polygons[i] for i in rows], wanted)
        else:
            times += [None] * len(wanted)
    return goals, times


def arena_summary(
    settings: CoordinatorSettings, observed: Observed, steering: Steering | None
) -> dict[str, Any]:
    """summary.json's arena keys of a run (covswarm.mission.world_metrics.world_summary, as
    ``covswarm sim`` writes them) over the e_a samples: robots' positions and S; goals from
    the scenario and from accepted goto requests (:func:`run_goals`)."""
    record = observed.record
    t = np.array(record.t)
    scenario = settings.scenario
    summary = world_summary(
        t,
        record.trajectories(),
        record.polygons,
        0.5 * scenario.robot_diameter,
        scenario.world,
        ids=record.robot_ids(),
    )
    goals, times = run_goals(t, record.polygons, scenario.goals, steering, observed.pace)
    summary.update(
        goals=len(goals),
        goals_reached=sum(when is not None for when in times),
        goal_times=times,
        goal_list=[list(goal) for goal in goals],
    )
    return summary


def script_start(observed: Observed) -> float | None:
    """Mission time (s) S started moving after a deploy hold (coordinator.pace), or None."""
    pace = observed.pace
    return None if pace is None or pace.released is None else pace.released[0]


def pace_summary(settings: CoordinatorSettings, observed: Observed) -> dict[str, Any]:
    """The run's pace (coordinator.pace.Pace.summary), its deploy hold with the gain the
    agents were broadcast while it held (settings.deploy_kappa, else kappa) and the s it
    took to reach it from the mission's (coordinator.pace.gain_ramp)."""
    assert observed.pace is not None
    pace = observed.pace.summary(observed.agent_stats, observed.mission_time())
    if "deploy" in pace:
        pace["deploy"]["kappa"] = settings.hold_kappa
        pace["deploy"]["kappa_ramp_s"] = gain_ramp(settings.kappa, settings.hold_kappa)
    return pace


def build_summary(
    settings: CoordinatorSettings,
    observed: Observed,
    steering: Steering | None = None,
    recorder_disk: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """summary.json of a distributed run: :func:`mission_summary` plus process figures,
    the arena's figures (:func:`arena_summary`), the ids that were not of the team
    (coordinator.team.Roster) and, when recording, the recorder's disk state
    (``RunRecorder.disk``)."""
    record = observed.record
    final = record.positions[-1]
    ids = sorted(final)
    t = np.array(record.t)
    summary = mission_summary(
        settings.scenario,
        law=settings.law,
        feedforward=settings.feedforward,
        kappa=settings.kappa,
        duration=settings.duration,
        dynamics="unicycle",
        t=t,
        error=np.array(record.error),
        final_positions=np.array([final[i] for i in ids]).reshape(-1, 2),
        final_polygon=record.polygons[-1],
        trajectories=record.trajectories(),
        crowding=settings.crowding,
        wheels=agent_wheel_figures(observed.agent_stats, observed.mission_time()),
        ids=record.robot_ids(),
        script_start=script_start(observed),
    )
    return {
        **summary,
        "agents": settings.agents,  # the team asked for, not the robots seen at the end
        "mission_time": observed.mission_time(),
        "samples": len(record.t),
        "alive_at_end": {
            "agents": observed.liveness.count("agent"),
            "robots": observed.liveness.count("robot"),
        },
        "lost_processes": losses_summary(observed.liveness.events),
        "team_changes": team_changes_summary(observed.team_changes, record),
        "agent_stats": agent_figures(observed.agent_stats),
        "guards": agent_guards(observed.agent_stats),
        "rejected_messages": observed.rejected,
        "foreign_domains": observed.foreign_domains,
        "undiscovered_start": observed.undiscovered_start,
        "wrong_id_messages": observed.wrong_ids,
        "error_samples_clipped": observed.clipped_samples,
        "tile_size": settings.tile_size,
        **({} if observed.pace is None else {"pace": pace_summary(settings, observed)}),
        "started_wall": observed.started_wall,
        **arena_summary(settings, observed, steering),
        **({} if observed.roster is None else {"unexpected": observed.roster.summary()}),
        **({} if steering is None else steering_summary(steering)),
        **({} if recorder_disk is None else {"recorder_disk": dict(recorder_disk)}),
    }


def steering_summary(steering: Steering) -> dict[str, Any]:
    """summary.json's record of steering: every request, refusals per reason, the limit."""
    return {
        "steering": [record.to_dict() for record in steering.records],
        "steering_refused": dict(sorted(steering.refused.items())),
        "steering_omitted": steering.records.omitted,
        "steering_largest_jump": steering.largest_jump,
        "max_domain_speed": steering.limits.max_speed,
    }


def write_run_outputs(
    out_dir: Path,
    settings: CoordinatorSettings,
    observed: Observed,
    steering: Steering | None,
    recorder_disk: dict[str, Any] | None = None,
) -> None:
    """summary.json, error.csv, error.png, trajectories.png through mission.report, and
    domain.csv: S at every recorded instant (those of trajectories.csv), or at the e_a
    samples when nothing was recorded."""
    record = observed.record
    write_outputs(
        out_dir,
        summary=build_summary(settings, observed, steering, recorder_disk),
        t=np.array(record.t),
        error=np.array(record.error),
        trajectories=record.trajectories(),
        polygons=record.polygons,
        obstacles=[o.vertices for o in settings.scenario.world.obstacles],
        workspace=settings.scenario.workspace,
        density=settings.scenario.density(
            record.t[-1] if observed.pace is None else observed.pace.script_time(record.t[-1])
        )
        if record.t
        else None,
        script_start=script_start(observed),
    )
    if observed.domain_t:
        write_domain_csv(
            out_dir / DOMAIN_FILE, np.array(observed.domain_t), observed.domain_polygons
        )
    else:
        write_domain_csv(out_dir / DOMAIN_FILE, np.array(record.t), record.polygons)


def open_recorder(config: CoordinatorConfig, settings: CoordinatorSettings) -> RunRecorder | None:
    """The run's recorder (run.mcap in ``config.out`` unless --no-record, live view on
    --foxglove), or None. A resumed coordinator records its part beside the first
    (run-1.mcap, ...). LiveViewError if the live view cannot start."""
    out_dir = config.out if config.record else None
    if out_dir is None and config.foxglove is None:
        return None
    scenario = settings.scenario
    recorder = RunRecorder(
        out_dir,
        run_metadata={
            "source": "run",
            "scenario": scenario.name,
            "law": settings.law,
            "feedforward": settings.feedforward,
            "kappa": settings.kappa,
            "seed": config.seed,
            "agents": settings.agents,
            "duration": settings.duration,
            "swarm": settings.swarm,
            "time_scale": settings.time_scale,
            "pose_rate_hz": settings.rate,
            "pace": settings.pace,
            "deploy_error": settings.deploy_error,
            "deploy_timeout": settings.deploy_timeout,
            "deploy_kappa": settings.deploy_kappa,
            "max_domain_speed": settings.max_domain_speed,
        },
        workspace=scenario.workspace,
        obstacles=[o.vertices for o in scenario.world.obstacles],
        live_port=config.foxglove,
        continued=config.resume,
    )
    if recorder.live_port is not None:
        log.info("Foxglove live view on ws://%s:%d", LIVE_HOST, recorder.live_port)
    return recorder


def read_script_clock(path: Path, swarm: str) -> ScriptClock | None:
    """The script's clock recorded in ``path`` for ``swarm``; None without the file (a
    first coordinator stopped before it ever recorded one); ValueError if malformed."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc}") from None
    try:
        return ScriptClock.from_json(text, swarm)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def read_mission_start(path: Path, swarm: str) -> float:
    """The start wall time recorded in ``path`` for ``swarm`` (ValueError if there is none)."""
    try:
        mission = json.loads(path.read_text(encoding="utf-8"))
        started = float(mission["started_wall"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"no mission start in {path}: {exc}") from None
    if mission.get("swarm") != swarm or not math.isfinite(started):
        raise ValueError(f"{path} is not a mission of swarm {swarm!r}")
    return started
