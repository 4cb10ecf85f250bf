"""RunRecorder: a run's channels, written to run.mcap and optionally served live to Foxglove.

One foxglove-sdk Context holds the channels (docs/records.md lists them); its sinks are the
MCAP writer (``run.mcap`` in the output folder) and, with ``live_port``, a Foxglove
WebSocket server on 127.0.0.1, so a live viewer and the file see exactly the same messages.
Poses also go to trajectories.csv. Log times are mission times (ns since the mission's
start, never decreasing), so two runs line up in a viewer.

The coordinator (``covswarm run``) and the simulator (``covswarm sim``) feed it; it owns no
clock and no network of its own besides the optional server.
"""

from __future__ import annotations

import json
import math
import platform
import time
from collections.abc import Mapping, Sequence
from importlib import metadata as package_metadata
from pathlib import Path
from types import TracebackType
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import SceneUpdateChannel
from foxglove.mcap import MCAPWriteOptions

from covswarm.records import scene
from covswarm.records.live import LIVE_HOST
from covswarm.records.trajectories import TRAJECTORIES_FILE, TrajectoryWriter

MCAP_FILE = "run.mcap"
ROBOTS_TOPIC = "/robots"  # foxglove.SceneUpdate, one entity per robot, at the pose rate
DOMAIN_TOPIC = "/domain"  # foxglove.SceneUpdate, S(t) as a line loop, at the pose rate
CELLS_TOPIC = "/cells"  # foxglove.SceneUpdate, Voronoi cells, every CELL_PERIOD
ARENA_TOPIC = "/arena"  # foxglove.SceneUpdate, workspace and obstacles, every ARENA_PERIOD
ERROR_TOPIC = "/error"  # JSON {e_a, robots}, at the e_a sample rate
AGENT_STATS_TOPIC = "/agents/stats"  # JSON {agents: [{id, ...stats}], mean: {...}}
STEERING_TOPIC = "/steering"  # JSON, one message per steering event
METADATA_NAME = "run"  # the MCAP metadata record with the run's parameters and versions
CELL_PERIOD = 1.0  # s of mission time between two recorded tessellations
ARENA_PERIOD = 1.0  # s: static, but repeated so that a live viewer joining late sees it
# Largest share of a core the recorded tessellation may take (about 4 ms at 100 robots,
# 50 ms at 1000): beyond it cells are recorded less often, like the coordinator's e_a.
CELL_SHARE = 0.02

ERROR_SCHEMA = "covswarm.ErrorSample"  # names of the JSON channels' schemas
AGENT_STATS_SCHEMA = "covswarm.AgentStats"
STEERING_SCHEMA = "covswarm.SteeringEvent"

_ERROR_SCHEMA = {
    "type": "object",
    "properties": {
        "e_a": {"type": "number", "description": "aggregate CVT error ||p - c(p, t)||, m"},
        "robots": {"type": "integer", "description": "robots in the sample"},
    },
}
# The stats an agent reports (agent.brain.AgentBrain.stats; records may not import agent),
# declared so that a viewer's path editor types /agents/stats.mean.rate_hz and the rest.
# Counters of dropped messages (drop_<reason>) vary with what arrived: additionalProperties.
AGENT_STATS_FIELDS: dict[str, tuple[str, str]] = {
    "rate_hz": ("number", "control rate held, Hz"),
    "step_us_p50": ("number", "control step wall time, median, microseconds"),
    "step_us_p99": ("number", "control step wall time, 99th percentile, microseconds"),
    "rx_per_s": ("number", "messages received per second"),
    "pose_age_ms_p50": ("number", "pose-to-command latency, median, ms"),
    "pose_age_ms_p99": ("number", "pose-to-command latency, 99th percentile, ms"),
    "robot_clock_bound_ms": ("number", "agent clock minus its robot's is at most this, ms"),
    "safety_active": ("number", "robot-steps the safety filter changed the velocity"),
    "safety_relaxed": ("number", "robot-steps the safety filter could not hold every pair"),
    "wheel_max": ("number", "largest rim speed commanded, m/s"),
    "saturated_s": ("number", "time under a saturated wheel command, s"),
    "missed_deadline": ("number", "fraction of mission periods whose command went out late"),
    "rx_total": ("number", "messages received"),
    "coalesced": ("number", "messages superseded before they were read"),
    "stale_dropped": ("number", "neighbours dropped as stale"),
    "step_errors": ("number", "control steps that raised"),
    "mission_steps": ("number", "control steps while the mission ran"),
    "guarded": ("number", "steps the amplification guard rescaled"),
    "candidates": ("number", "robots known (dead-reckoned)"),
    "local_set": ("number", "robots in the local Voronoi diagram"),
    "neighbors": ("number", "Voronoi neighbours"),
    "state_subs": ("number", "AgentState subscriptions"),
    "tile_radius": ("number", "beacon tiles listened to around the agent's own"),
}
_STAT_PROPERTIES = {
    name: {"type": kind, "description": text} for name, (kind, text) in AGENT_STATS_FIELDS.items()
}
_DROP_COUNTER = {"type": "number", "description": "drop_<reason>: messages refused, per reason"}
_STATS_SCHEMA = {
    "type": "object",
    "properties": {
        "agents": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {"id": {"type": "integer"}, **_STAT_PROPERTIES},
                "additionalProperties": _DROP_COUNTER,
            },
        },
        "mean": {
            "type": "object",
            "description": "team mean of each stat",
            "properties": _STAT_PROPERTIES,
            "additionalProperties": _DROP_COUNTER,
        },
    },
}
_STEERING_SCHEMA = {"type": "object", "properties": {"t": {"type": "number"}}}


class LiveViewError(RuntimeError):
    """The live view's server could not start (typically: the port is taken)."""


def json_schema(name: str, schema: Mapping[str, Any]) -> foxglove.Schema:
    """A named JSON schema (viewers list its fields; the name identifies the channel's type)."""
    return foxglove.Schema(
        name=name, encoding="jsonschema", data=json.dumps({"title": name, **schema}).encode()
    )


def versions() -> dict[str, str]:
    """Versions of what produced a record (covswarm, foxglove-sdk, numpy, Python)."""
    found = {"python": platform.python_version(), "numpy": np.__version__}
    for name in ("covswarm", "foxglove-sdk", "eclipse-zenoh"):
        try:
            found[name] = package_metadata.version(name)
        except package_metadata.PackageNotFoundError:
            found[name] = "unknown"
    return found


def metadata_strings(values: Mapping[str, Any]) -> dict[str, str]:
    """MCAP metadata holds strings: strings stay, everything else becomes JSON."""
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in values.items()}


def record_names(out_dir: Path, continued: bool) -> tuple[str, str]:
    """(run.mcap, trajectories.csv), or the first free (run-<k>.mcap, trajectories-<k>.csv)."""
    if not continued:
        return MCAP_FILE, TRAJECTORIES_FILE
    k = 1
    while (out_dir / f"run-{k}.mcap").exists():
        k += 1
    return f"run-{k}.mcap", TRAJECTORIES_FILE.replace(".csv", f"-{k}.csv")


def _ns(t: float) -> int:
    return max(0, round(t * 1e9))


class RunRecorder:
    """The channels of one run and their sinks. Use as a context manager or call close()."""

    def __init__(
        self,
        out_dir: str | Path | None,
        *,
        run_metadata: Mapping[str, Any],
        workspace: tuple[float, float, float, float] | None = None,
        obstacles: Sequence[tuple[float, float, float, float]] = (),
        live_port: int | None = None,
        cell_share: float | None = CELL_SHARE,
        continued: bool = False,
    ) -> None:
        """out_dir: where run.mcap and trajectories.csv go (None: live only);
        run_metadata: scenario, law, kappa, seed, agents, ... (versions are added);
        live_port: serve the channels on ws://127.0.0.1:PORT (0 picks a free port);
        cell_share: record cells less often than CELL_PERIOD when they cost more than this
        share of a core (None: always CELL_PERIOD, deterministic); continued: a restarted
        coordinator's part of a run, written beside the earlier parts as run-<k>.mcap and
        trajectories-<k>.csv (k = 1, 2, ...) instead of over them."""
        self.context = foxglove.Context()
        ctx = self.context
        self._robots = SceneUpdateChannel(ROBOTS_TOPIC, context=ctx)
        self._domain = SceneUpdateChannel(DOMAIN_TOPIC, context=ctx)
        self._cells = SceneUpdateChannel(CELLS_TOPIC, context=ctx)
        self._arena = SceneUpdateChannel(ARENA_TOPIC, context=ctx)
        self._error, self._stats, self._steering = (
            foxglove.Channel(
                topic, schema=json_schema(name, schema), message_encoding="json", context=ctx
            )
            for topic, name, schema in (
                (ERROR_TOPIC, ERROR_SCHEMA, _ERROR_SCHEMA),
                (AGENT_STATS_TOPIC, AGENT_STATS_SCHEMA, _STATS_SCHEMA),
                (STEERING_TOPIC, STEERING_SCHEMA, _STEERING_SCHEMA),
            )
        )
        self.workspace, self.obstacles = workspace, tuple(obstacles)
        self.metadata = {
            **run_metadata,
            "workspace": None if workspace is None else list(workspace),
            "obstacles": [list(box) for box in obstacles],
            "versions": versions(),
        }
        self.server = None
        if live_port is not None:  # first, so that a busy port leaves no half-written file
            try:
                self.server = foxglove.start_server(
                    name="covswarm", host=LIVE_HOST, port=live_port, context=ctx
                )
            except RuntimeError as exc:
                raise LiveViewError(f"cannot serve on {LIVE_HOST}:{live_port}: {exc}") from None
        self.mcap_path: Path | None = None
        self._writer = None
        self._trajectories: TrajectoryWriter | None = None
        if out_dir is not None:
            out = Path(out_dir)
            out.mkdir(parents=True, exist_ok=True)
            mcap_name, csv_name = record_names(out, continued)
            self.mcap_path = out / mcap_name
            # compression_threads=0: compress on the calling thread, so the recorder's cost
            # shows up where it is paid and never competes with the swarm for the 2 cores.
            self._writer = foxglove.open_mcap(
                self.mcap_path,
                allow_overwrite=True,
                context=ctx,
                writer_options=MCAPWriteOptions(compression_threads=0),
            )
            self._writer.write_metadata(METADATA_NAME, metadata_strings(self.metadata))
            self._trajectories = TrajectoryWriter(out / csv_name)
        self.cell_share = cell_share
        self._last_ns = 0
        self._next_cells = 0.0
        self._next_arena = 0.0
        self.counts = {"poses": 0, "cells": 0, "errors": 0, "stats": 0, "steering": 0}

    # -- channels -------------------------------------------------------------------------

    def _log_time(self, t: float) -> int:
        """Mission time in ns, never before the last message logged (viewers need order)."""
        self._last_ns = max(self._last_ns, _ns(t))
        return self._last_ns

    def poses(
        self,
        t: float,
        ids: Sequence[int],
        poses: np.ndarray,
        times: np.ndarray | None = None,
        *,
        trajectories: bool = True,
    ) -> None:
        """Robots observed at mission time t: one /robots message (log time t).

        ids: n distinct ids, ascending; poses: (n, 3) x, y, theta; times: (n,) mission times
        the poses were measured at (entity timestamps; default t); trajectories: also append
        them to trajectories.csv (False when the caller writes the rows in time order itself,
        see trajectory_rows).
        """
        if not len(ids):
            return
        log_time = self._log_time(t)
        self._robots.log(scene.robots_update(t, ids, poses, times), log_time=log_time)
        if trajectories:
            self.trajectory_rows(t if times is None else times, ids, poses)
        self.counts["poses"] += 1
        if t >= self._next_arena and (self.workspace is not None or self.obstacles):
            self._arena.log(
                scene.arena_update(t, self.workspace, self.obstacles), log_time=log_time
            )
            self._next_arena = t + ARENA_PERIOD

    def trajectory_rows(
        self, times: float | np.ndarray, ids: Sequence[int], poses: np.ndarray
    ) -> None:
        """Rows of trajectories.csv: times (s, one or one per row), ids, poses (n, 3)."""
        if self._trajectories is not None:
            self._trajectories.write(times, ids, poses)

    def domain(self, t: float, vertices: np.ndarray) -> None:
        """S(t): (k, 2) vertices, m."""
        self._domain.log(scene.domain_update(t, vertices), log_time=self._log_time(t))

    def cells_due(self, t: float) -> bool:
        """Whether a tessellation should be recorded at mission time t."""
        return t >= self._next_cells

    def cells(self, t: float, ids: Sequence[int], positions: np.ndarray, polygon: np.ndarray):
        """Tessellate and record the robots' Voronoi cells in S (the paper's V_i cap S).

        positions: (n, 2) m in the order of ids; polygon: (k, 2) S(t).
        """
        from covswarm.tvd.coverage import cells

        began = time.thread_time()
        pieces = cells(np.asarray(positions, dtype=float), np.asarray(polygon, dtype=float))
        self._cells.log(scene.cells_update(t, ids, pieces), log_time=self._log_time(t))
        cost = time.thread_time() - began
        share = self.cell_share
        self._next_cells = t + (CELL_PERIOD if share is None else max(CELL_PERIOD, cost / share))
        self.counts["cells"] += 1

    def error(self, t: float, e_a: float, robots: int) -> None:
        """One e_a(t) sample (m) over ``robots`` robots."""
        value = float(e_a) if math.isfinite(e_a) else None
        self._error.log({"e_a": value, "robots": int(robots)}, log_time=self._log_time(t))
        self.counts["errors"] += 1

    def agent_stats(self, t: float, stats: Mapping[int, Mapping[str, float]]) -> None:
        """The latest stats of every agent (AgentState.stats), with the team mean of each."""
        agents = [{"id": int(i), **_finite(stats[i])} for i in sorted(stats)]
        names = sorted({k for entry in agents for k in entry if k != "id"})
        mean = {}
        for name in names:
            values = [e[name] for e in agents if isinstance(e.get(name), int | float)]
            if values:
                mean[name] = float(np.mean(values))
        self._stats.log({"agents": agents, "mean": mean}, log_time=self._log_time(t))
        self.counts["stats"] += 1

    def steering(self, t: float, event: Mapping[str, Any]) -> None:
        """A steering event (who moved S how) at mission time t; ``event`` must be JSON-able.

        Logged at max(t, the last log time) so the file stays ordered; the payload keeps t.
        """
        self._steering.log({"t": float(t), **event}, log_time=self._log_time(t))
        self.counts["steering"] += 1

    def note(self, name: str, values: Mapping[str, Any]) -> None:
        """An extra MCAP metadata record (e.g. what recording cost), if writing a file."""
        if self._writer is not None:
            self._writer.write_metadata(name, metadata_strings(values))

    # -- lifetime -------------------------------------------------------------------------

    @property
    def live_port(self) -> int | None:
        return None if self.server is None else self.server.port

    def close(self) -> None:
        """Finish run.mcap (summary, statistics) and trajectories.csv; stop the server."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._trajectories is not None:
            self._trajectories.close()
            self._trajectories = None
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self) -> RunRecorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()


def _finite(entry: Mapping[str, Any]) -> dict[str, Any]:
    """JSON has no NaN/inf: such stats become null."""
    return {
        k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in entry.items()
    }


SIM_POSE_RATE = 20.0  # Hz: the simulator records at the robots' pose rate of a live run


def sim_stride(dt: float) -> int:
    """Record every k-th simulator step, k = floor(1 / (dt x SIM_POSE_RATE)) >= 1: at least
    SIM_POSE_RATE (25 Hz at the default dt = 0.02 s), every step when dt >= 0.05 s."""
    return max(1, math.floor(1.0 / (dt * SIM_POSE_RATE) + 1e-9))


def record_simulation(
    out_dir: str | Path,
    *,
    t: np.ndarray,
    error: np.ndarray,
    trajectories: np.ndarray,
    headings: np.ndarray,
    polygons: Sequence[np.ndarray],
    dt: float,
    run_metadata: Mapping[str, Any],
    workspace: tuple[float, float, float, float] | None = None,
    obstacles: Sequence[tuple[float, float, float, float]] = (),
) -> int:
    """run.mcap and trajectories.csv of a ``covswarm sim`` result; returns the stride used.

    t, error: (T,); trajectories: (T, n, 2) m; headings: (T, n) rad; polygons: T (k, 2)
    arrays. Robots are ids 0..n-1 (the simulator's order). Every ``sim_stride(dt)``-th step
    is recorded, and the last one.
    """
    stride = sim_stride(dt)
    steps = list(range(0, len(t), stride))
    if steps[-1] != len(t) - 1:
        steps.append(len(t) - 1)
    ids = list(range(trajectories.shape[1]))
    with RunRecorder(
        out_dir,
        run_metadata={**run_metadata, "pose_rate_hz": 1.0 / (stride * dt)},
        workspace=workspace,
        obstacles=obstacles,
        cell_share=None,
    ) as recorder:
        for k in steps:
            tk = float(t[k])
            poses = np.column_stack([trajectories[k], headings[k]])
            recorder.domain(tk, polygons[k])
            recorder.poses(tk, ids, poses)
            recorder.error(tk, float(error[k]), len(ids))
            if recorder.cells_due(tk):
                recorder.cells(tk, ids, trajectories[k], polygons[k])
    return stride
