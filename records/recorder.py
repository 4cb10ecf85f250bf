"""RunRecorder: a run's channels, written to run.mcap and optionally served live to Foxglove.

One foxglove-sdk Context holds the channels (docs/records.md lists them); its sinks are the
MCAP writer (``run.mcap`` in the output folder) and, with ``live_port``, a Foxglove
WebSocket server on 127.0.0.1, so a live viewer and the file see exactly the same messages.
Poses also go to trajectories.csv. Log times are mission times (ns since the mission's
start, never decreasing), so two runs line up in a viewer.

The coordinator (``covswarm run``) and the simulator (``covswarm sim``) feed it; it owns no
clock and no network of its own besides the optional server.

A full disk stops the records, never the run (issue 21). foxglove's MCAP sink does not
raise when a write fails (it prints an error per message and leaves a file cut mid-chunk),
so the recorder checks the free space of the output folder itself, at most every
SPACE_CHECK_PERIOD s of mission time and every SPACE_CHECK_WRITES writes, and stops writing
files while MIN_FREE_BYTES are left: enough to finish the chunk in memory (at most
MCAP_CHUNK_SIZE before compression), run.mcap's summary and footer, trajectories.csv's
buffer and the coordinator's summary.json. An OSError while writing (another process
filled the disk first) or a failing close stops the records the same way. Stopping logs
one warning; ``disk`` says why and when, and counts the writes left out since.
"""

from __future__ import annotations

import json
import logging
import math
import os
import platform
import time
from collections.abc import Callable, Mapping, Sequence
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

log = logging.getLogger("covswarm.records")

MCAP_FILE = "run.mcap"
ROBOTS_TOPIC = "/robots"  # foxglove.SceneUpdate, one entity per robot, at the pose rate
DOMAIN_TOPIC = "/domain"  # foxglove.SceneUpdate, S(t) as a line loop, at the pose rate
CELLS_TOPIC = "/cells"  # foxglove.SceneUpdate, Voronoi cells, every CELL_PERIOD
ARENA_TOPIC = "/arena"  # foxglove.SceneUpdate, workspace and obstacles, every ARENA_PERIOD
ERROR_TOPIC = "/error"  # JSON {e_a, robots}, at the e_a sample rate
AGENT_STATS_TOPIC = "/agents/stats"  # JSON {agents: [{id, ...stats}], mean: {...}}
STEERING_TOPIC = "/steering"  # JSON, one message per steering event
AGENT_STATES_TOPIC = "/agents/states"  # msgpack, each AgentState payload as its agent sent it
METADATA_NAME = "run"  # the MCAP metadata record with the run's parameters and versions
CELL_PERIOD = 1.0  # s of mission time between two recorded tessellations
ARENA_PERIOD = 1.0  # s: static, but repeated so that a live viewer joining late sees it
# Largest share of a core the recorded tessellation may take (about 4 ms at 100 robots,
# 50 ms at 1000): beyond it cells are recorded less often, like the coordinator's e_a.
CELL_SHARE = 0.02
MCAP_CHUNK_SIZE = 256 * 1024  # bytes before compression (foxglove's default is 1 MiB)
MIN_FREE_BYTES = 4 * MCAP_CHUNK_SIZE  # files stop being written below this (module notes)
SPACE_CHECK_PERIOD = 0.1  # s of mission time between two free-space checks, at most
SPACE_CHECK_WRITES = 32  # writes between two free-space checks, at most


def free_bytes(path: Path) -> int:
    """Bytes an unprivileged writer may still use on the file system of ``path``."""
    stat = os.statvfs(path)
    return stat.f_bavail * stat.f_frsize


ERROR_SCHEMA = "covswarm.ErrorSample"  # names of the JSON channels' schemas
AGENT_STATS_SCHEMA = "covswarm.AgentStats"
STEERING_SCHEMA = "covswarm.SteeringEvent"
# Named, without a definition: the payloads are protocol messages, decoded by
# covswarm.protocol.AgentState.decode (no viewer decodes msgpack; records.replay does).
AGENT_STATE_SCHEMA = "covswarm.AgentState"
AGENT_STATE_ENCODING = "msgpack"

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
    "late_held": ("number", "fraction of mission periods skipped, the robot held, in a pack"),
    "rx_total": ("number", "messages received"),
    "coalesced": ("number", "messages superseded before they were read"),
    "stale_dropped": ("number", "neighbours dropped as stale"),
    "step_errors": ("number", "control steps that raised"),
    "batch_fallbacks": ("number", "batched local steps retaken one by one (a bad view)"),
    "turn_capped": ("number", "steps whose turn rate was capped for the period held"),
    "arc_turned": ("number", "steps turned in place: the held turn was over ARC_TURN"),
    "overrun_gained": (
        "number",
        "filter rows whose gain was sampled over the command timeout, not the expected hold",
    ),
    "slid": ("number", "steps stopped dead by the filter that turned toward their slide"),
    "stranded_followed": (
        "number",
        "robots followed as obstacles: their token lives without their agent's",
    ),
    "cell_empty": ("number", "mission steps with no cell in S (outside S, dominated)"),
    "stale_stretched": ("number", "mission steps that kept neighbours past the stale timeout"),
    "pose_too_old": (
        "number",
        "mission steps that stopped the robot: its pose too old to steer from",
    ),
    "duty_scaled": ("number", "mission steps sped up for a command that times out early"),
    "speed_limited": ("number", "mission steps slowed for robots the filter may not see yet"),
    "aligning": ("number", "steps before the mission that turned the robot to face S's start"),
    "mission_steps": ("number", "control steps while the mission ran"),
    "guarded": ("number", "steps the amplification guard rescaled"),
    "candidates": ("number", "robots known (dead-reckoned)"),
    "local_set": ("number", "robots in the local Voronoi diagram"),
    "neighbors": ("number", "Voronoi neighbours"),
    "state_subs": ("number", "AgentState subscriptions"),
    "tile_radius": ("number", "beacon tiles listened to around the agent's own"),
    "beacon_unconfirmed": ("number", "beacon-only robots left out, never confirmed (total)"),
    "beacon_doubted": (
        "number",
        "filter rows left out: robots known from an old beacon, state awaited (robot-steps)",
    ),
    "obstacles_kept": (
        "number",
        "near robots kept in the filter where last known: vanished or only relayed (total)",
    ),
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


def mcap_part(k: int) -> str:
    """The record of a run's k-th resumed coordinator (k >= 1): run-<k>.mcap."""
    return MCAP_FILE.replace(".mcap", f"-{k}.mcap")


def record_names(out_dir: Path, continued: bool) -> tuple[str, str]:
    """(run.mcap, trajectories.csv), or the first free (run-<k>.mcap, trajectories-<k>.csv)."""
    if not continued:
        return MCAP_FILE, TRAJECTORIES_FILE
    k = 1
    while (out_dir / mcap_part(k)).exists():
        k += 1
    return mcap_part(k), TRAJECTORIES_FILE.replace(".csv", f"-{k}.csv")


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
        obstacles: Sequence[np.ndarray] = (),
        live_port: int | None = None,
        cell_share: float | None = CELL_SHARE,
        continued: bool = False,
        free_space: Callable[[Path], int] = free_bytes,
    ) -> None:
        """out_dir: where run.mcap and trajectories.csv go (None: live only);
        run_metadata: scenario, law, kappa, seed, agents, ... (versions are added);
        workspace: (xmin, xmax, ymin, ymax) m or None; obstacles: every obstacle of the
        world, whatever its shape, as a convex polygon (k, 2) m (World.obstacles' vertices);
        live_port: serve the channels on ws://127.0.0.1:PORT (0 picks a free port);
        cell_share: record cells less often than CELL_PERIOD when they cost more than this
        share of a core (None: always CELL_PERIOD, deterministic); continued: a restarted
        coordinator's part of a run, written beside the earlier parts as run-<k>.mcap and
        trajectories-<k>.csv (k = 1, 2, ...) instead of over them; free_space: bytes left
        on the output folder's file system (injected by tests)."""
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
        # foxglove-sdk refuses a schemaless channel in any encoding but JSON.
        self._states = foxglove.Channel(
            AGENT_STATES_TOPIC,
            schema=foxglove.Schema(name=AGENT_STATE_SCHEMA, encoding="", data=b""),
            message_encoding=AGENT_STATE_ENCODING,
            context=ctx,
        )
        self.workspace = workspace
        self.obstacles = tuple(np.asarray(p, dtype=float) for p in obstacles)
        self.metadata = {
            **run_metadata,
            "workspace": None if workspace is None else list(workspace),
            "obstacle_polygons": [p.tolist() for p in self.obstacles],
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
        self._out: Path | None = None
        self._free_space = free_space
        self._next_check, self._writes = -math.inf, 0
        # Why the files stopped (None: writing or never written), at which mission time,
        # and the writes left out of them since.
        self.disk: dict[str, Any] = {"stopped": None, "t": None, "writes_lost": 0}
        if out_dir is not None:
            out = self._out = Path(out_dir)
            out.mkdir(parents=True, exist_ok=True)
            if (free := free_space(out)) < MIN_FREE_BYTES:
                self._stop(f"{free} bytes free in {out}, {MIN_FREE_BYTES} needed", None)
            else:
                self._open_files(out, continued)
        self.cell_share = cell_share
        self._last_ns = 0
        self._next_cells = 0.0
        self._next_arena = 0.0
        self.counts = {
            "poses": 0, "cells": 0, "errors": 0, "stats": 0, "steering": 0, "states": 0,
        }  # fmt: skip

    def _open_files(self, out: Path, continued: bool) -> None:
        """run.mcap (or run-<k>.mcap) and trajectories.csv in ``out``."""
        mcap_name, csv_name = record_names(out, continued)
        self.mcap_path = out / mcap_name
        # compression_threads=0: compress on the calling thread, so the recorder's cost
        # shows up where it is paid and never competes with the swarm for the 2 cores.
        self._writer = foxglove.open_mcap(
            self.mcap_path,
            allow_overwrite=True,
            context=self.context,
            writer_options=MCAPWriteOptions(compression_threads=0, chunk_size=MCAP_CHUNK_SIZE),
        )
        self._writer.write_metadata(METADATA_NAME, metadata_strings(self.metadata))
        try:
            self._trajectories = TrajectoryWriter(out / csv_name)
        except OSError as exc:
            self._stop(f"cannot write {csv_name}: {exc}", None)

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
        if not len(ids) or not self._writing(t):
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
            try:
                self._trajectories.write(times, ids, poses)
            except OSError as exc:
                self._stop(f"cannot write trajectories: {exc}", float(np.max(times)))

    def domain(self, t: float, vertices: np.ndarray) -> None:
        """S(t): (k, 2) vertices, m."""
        if not self._writing(t):
            return
        self._domain.log(scene.domain_update(t, vertices), log_time=self._log_time(t))

    def cells_due(self, t: float) -> bool:
        """Whether a tessellation should be recorded at mission time t."""
        return t >= self._next_cells

    def cells(self, t: float, ids: Sequence[int], positions: np.ndarray, polygon: np.ndarray):
        """Tessellate and record the robots' Voronoi cells in S (the paper's V_i cap S).

        positions: (n, 2) m in the order of ids; polygon: (k, 2) S(t).
        """
        from covswarm.tvd.coverage import cells

        if not self._writing(t):
            return
        began = time.thread_time()
        pieces = cells(np.asarray(positions, dtype=float), np.asarray(polygon, dtype=float))
        self.log_cells(t, ids, pieces, time.thread_time() - began)

    def log_cells(
        self, t: float, ids: Sequence[int], pieces: Sequence[np.ndarray], cost: float
    ) -> None:
        """Record cells tessellated elsewhere (tvd.coverage.cells of the robots ``ids`` at
        mission time ``t``; the coordinator's worker thread): ``cost``, the CPU s the
        tessellation took, sets when the next is due (``cell_share``)."""
        if not self._writing(t):
            return
        self._cells.log(scene.cells_update(t, ids, pieces), log_time=self._log_time(t))
        share = self.cell_share
        self._next_cells = t + (CELL_PERIOD if share is None else max(CELL_PERIOD, cost / share))
        self.counts["cells"] += 1

    def error(self, t: float, e_a: float, robots: int) -> None:
        """One e_a(t) sample (m) over ``robots`` robots."""
        if not self._writing(t):
            return
        value = float(e_a) if math.isfinite(e_a) else None
        self._error.log({"e_a": value, "robots": int(robots)}, log_time=self._log_time(t))
        self.counts["errors"] += 1

    def agent_stats(self, t: float, stats: Mapping[int, Mapping[str, float]]) -> None:
        """The latest stats of every agent (AgentState.stats), with the team mean of each."""
        if not self._writing(t):
            return
        agents = [{"id": int(i), **_finite(stats[i])} for i in sorted(stats)]
        names = sorted({k for entry in agents for k in entry if k != "id"})
        mean = {}
        for name in names:
            values = [e[name] for e in agents if isinstance(e.get(name), int | float)]
            if values:
                mean[name] = float(np.mean(values))
        self._stats.log({"agents": agents, "mean": mean}, log_time=self._log_time(t))
        self.counts["stats"] += 1

    def agent_states(self, t: float, payloads: Sequence[bytes]) -> None:
        """AgentState payloads received by mission time t, one /agents/states message each,
        the bytes as the agents sent them (log time t, when the coordinator saw them)."""
        if not payloads or not self._writing(t):
            return
        log_time, log_state = self._log_time(t), self._states.log
        for payload in payloads:
            log_state(payload, log_time=log_time)
        self.counts["states"] += len(payloads)

    def steering(self, t: float, event: Mapping[str, Any]) -> None:
        """A steering event (who moved S how) at mission time t; ``event`` must be JSON-able.

        Logged at max(t, the last log time) so the file stays ordered; the payload keeps t.
        """
        if not self._writing(t):
            return
        self._steering.log({"t": float(t), **event}, log_time=self._log_time(t))
        self.counts["steering"] += 1

    def note(self, name: str, values: Mapping[str, Any]) -> None:
        """An extra MCAP metadata record (e.g. what recording cost), if writing a file."""
        if self._writer is not None and self._writing(None):
            self._writer.write_metadata(name, metadata_strings(values))

    # -- the disk -------------------------------------------------------------------------

    @property
    def recording(self) -> bool:
        """Whether anything is still written: a file, or the live view."""
        return self._writer is not None or self._trajectories is not None or self.server is not None

    def _writing(self, t: float | None) -> bool:
        """Whether to write a message at mission time ``t`` (None: now): checks the free
        space when due, stops the files below MIN_FREE_BYTES, counts what is left out."""
        if self._out is not None and (self._writer is not None or self._trajectories is not None):
            self._writes += 1
            due = self._writes >= SPACE_CHECK_WRITES or (t is not None and t >= self._next_check)
            if due:
                self._writes = 0
                self._next_check = -math.inf if t is None else t + SPACE_CHECK_PERIOD
                try:
                    free = self._free_space(self._out)
                except OSError as exc:
                    free, why = 0, f"cannot read the free space: {exc}"
                else:
                    why = f"{free} bytes left in {self._out} (< {MIN_FREE_BYTES})"
                if free < MIN_FREE_BYTES:
                    self._stop(why, t)
        if self.disk["stopped"] is not None:
            self.disk["writes_lost"] += 1
        return self.recording

    def _stop(self, why: str, t: float | None) -> None:
        """Stop writing files (the live view goes on): close them while there is room."""
        if self.disk["stopped"] is not None:
            return
        self.disk.update(stopped=why, t=t)
        log.warning(
            "recording stopped%s: %s; the mission goes on, what was written stays readable",
            "" if t is None else f" at t = {t:.2f} s",
            why,
        )
        self._close_files()

    def _close_files(self) -> None:
        """Finish run.mcap and trajectories.csv; a failure (a disk filled by someone
        else) is recorded in ``disk``, never raised."""
        writer, trajectories = self._writer, self._trajectories
        self._writer = self._trajectories = None
        for what, close in (("run.mcap", writer), ("trajectories", trajectories)):
            if close is None:
                continue
            try:
                close.close()
            except (OSError, RuntimeError) as exc:  # foxglove raises RuntimeError on I/O
                self.disk.setdefault("close_errors", []).append(f"{what}: {exc}")
                log.warning("closing %s failed: %s", what, exc)

    # -- lifetime -------------------------------------------------------------------------

    @property
    def live_port(self) -> int | None:
        return None if self.server is None else self.server.port

    def close(self) -> None:
        """Finish run.mcap (summary, statistics) and trajectories.csv; stop the server.
        Never raises for a full disk (see ``disk``)."""
        self._close_files()
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
    obstacles: Sequence[np.ndarray] = (),
) -> int:
    """run.mcap and trajectories.csv of a ``covswarm sim`` result; returns the stride used.

    t, error: (T,); trajectories: (T, n, 2) m; headings: (T, n) rad; polygons: T (k, 2)
    arrays; workspace, obstacles: as RunRecorder's. Robots are ids 0..n-1 (the simulator's
    order). Every ``sim_stride(dt)``-th step is recorded, and the last one.
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
