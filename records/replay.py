"""``covswarm replay RUN_DIR``: an animation of a recorded run (S, cells, robots, e_a).

Reads RUN_DIR/run.mcap back (the robots, S(t), the cells and e_a channels of
covswarm.records.recorder) and renders one frame every ``speed / fps`` s of mission time,
each showing the newest message of every channel at that time. GIF through Pillow; MP4
through ffmpeg, only when ffmpeg is on the PATH. :func:`read_agent_states` reads back what
the agents said (their AgentStates), which the animation does not show.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
import numpy as np

from covswarm.protocol import AgentState, ProtocolError
from covswarm.records.recorder import (
    AGENT_STATE_ENCODING,
    AGENT_STATE_SCHEMA,
    AGENT_STATES_TOPIC,
    CELLS_TOPIC,
    DOMAIN_TOPIC,
    ERROR_TOPIC,
    MCAP_FILE,
    METADATA_NAME,
    ROBOTS_TOPIC,
    mcap_part,
)
from covswarm.records.scene import ROBOT_DIAMETER, ROBOT_LIFETIME
from covswarm.runtime.options import FiniteFloat
from covswarm.world.model import box_vertices

HEADING_LENGTH = 0.15  # m, the heading arrow drawn on each robot


@dataclass
class Recording:
    """What a run.mcap holds, as arrays. Times are mission times (s)."""

    metadata: dict[str, Any] = field(default_factory=dict)
    pose_t: list[float] = field(default_factory=list)  # distinct /robots log times
    # The robots in the scene at each pose_t: id -> (x, y, theta).
    poses: list[dict[int, tuple[float, float, float]]] = field(default_factory=list)
    domain_t: list[float] = field(default_factory=list)
    domains: list[np.ndarray] = field(default_factory=list)  # (k, 2) each
    cells_t: list[float] = field(default_factory=list)
    cells: list[list[np.ndarray]] = field(default_factory=list)
    error_t: list[float] = field(default_factory=list)
    error: list[float] = field(default_factory=list)
    truncated: list[str] = field(default_factory=list)  # parts read up to where they broke off

    @property
    def end(self) -> float:
        """The last pose time (s), 0 without poses."""
        return self.pose_t[-1] if self.pose_t else 0.0


def obstacle_polygons(metadata: Mapping[str, Any]) -> list[np.ndarray]:
    """The recorded obstacles, (k, 2) vertices (m) each: the metadata's
    ``obstacle_polygons``, or in a recording from before it the boxes [xmin, xmax, ymin,
    ymax] of ``obstacles`` (ValueError if one is no box)."""
    if "obstacle_polygons" in metadata:
        polygons = metadata["obstacle_polygons"] or []
        return [np.asarray(p, dtype=float).reshape(-1, 2) for p in polygons]
    return [box_vertices(box) for box in metadata.get("obstacles") or []]


def _yaw(q: Any) -> float:
    """Heading (rad) of a planar quaternion (rotation about +z)."""
    return 2.0 * math.atan2(q.z, q.w)


def _loop_points(entity: Any) -> np.ndarray:
    points = entity.lines[0].points if entity.lines else []
    return np.array([[p.x, p.y] for p in points], dtype=float).reshape(-1, 2)


def recording_parts(run_dir: Path) -> list[Path]:
    """A run folder's records in mission order: run.mcap, then the parts resumed
    coordinators wrote beside it (run-1.mcap, run-2.mcap, ...: records.recorder.record_names)."""
    parts = [run_dir / MCAP_FILE] if (run_dir / MCAP_FILE).is_file() else []
    k = 1
    while (part := run_dir / mcap_part(k)).is_file():
        parts.append(part)
        k += 1
    return parts


MCAP_MAGIC = b"\x89MCAP0\r\n"  # every MCAP file's first bytes (the MCAP specification)


def _records(
    path: Path, topics: list[str], decoded: bool = True
) -> tuple[list[Any], dict[str, Any], bool]:
    """(the messages of ``topics`` in log time order, decoded (schema, channel, message,
    decoded) or not (schema, channel, message); the run's metadata; whether the file ended
    early) of the MCAP file at ``path``; ValueError if it is no MCAP file. A file whose
    writer was killed (a coordinator SIGKILLed before it wrote the summary and footer: the
    first part of a resumed run) is read as a stream up to its last whole record."""
    from mcap.reader import NonSeekingReader, make_reader

    factories = decoder_factories() if decoded else ()
    metadata: dict[str, Any] = {}
    with open(path, "rb") as stream:
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ValueError(f"{path}: not an MCAP file")
        stream.seek(0)
        try:
            reader = make_reader(stream, decoder_factories=factories)
            for entry in reader.iter_metadata():
                if entry.name == METADATA_NAME:
                    metadata = {k: _json_or_text(v) for k, v in entry.metadata.items()}
            read = reader.iter_decoded_messages if decoded else reader.iter_messages
            return list(read(topics=topics, log_time_order=True)), metadata, False
        except Exception:  # noqa: BLE001 -- no footer or summary: read it as a stream below
            pass
        stream.seek(0)
        streamed = NonSeekingReader(stream, validate_crcs=False, decoder_factories=factories)
        read = streamed.iter_decoded_messages if decoded else streamed.iter_messages
        messages = []
        try:
            for item in read(topics=topics, log_time_order=False):
                messages.append(item)
        except Exception:  # noqa: BLE001 -- the record cut short where its writer died
            pass
    messages.sort(key=lambda item: item[2].log_time)  # stable: a tick's messages in order
    return messages, metadata, True


def read_recording(paths: str | Path | Sequence[str | Path]) -> Recording:
    """Decode a run.mcap written by RunRecorder, or the parts of a resumed run in mission
    order (:func:`recording_parts`); ValueError if they hold no robot poses. A part whose
    writer was killed is read up to its last whole record and named in ``truncated``."""
    parts = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    record = Recording()
    robots: dict[int, tuple[float, float, float]] = {}
    updated: dict[int, float] = {}
    topics = [ROBOTS_TOPIC, DOMAIN_TOPIC, CELLS_TOPIC, ERROR_TOPIC]
    for path in parts:
        messages, metadata, truncated = _records(path, topics)
        record.metadata = record.metadata or metadata
        if truncated:
            record.truncated.append(path.name)
        for _, channel, message, update in messages:
            t = message.log_time / 1e9
            if channel.topic == ERROR_TOPIC:
                value = update.get("e_a")
                record.error_t.append(t)
                record.error.append(math.nan if value is None else float(value))
            elif channel.topic == ROBOTS_TOPIC:
                # Scene semantics: an entity replaces the robot's previous one, and a robot
                # not updated for ROBOT_LIFETIME leaves the scene.
                for e in update.entities:
                    pose = e.arrows[0].pose
                    robots[int(e.id)] = (
                        pose.position.x, pose.position.y, _yaw(pose.orientation)
                    )  # fmt: skip
                    updated[int(e.id)] = t
                scene = {i: p for i, p in robots.items() if t - updated[i] <= ROBOT_LIFETIME}
                if record.pose_t and record.pose_t[-1] == t:  # a second message of a tick
                    record.poses[-1] = scene
                else:
                    record.pose_t.append(t)
                    record.poses.append(scene)
            elif channel.topic == DOMAIN_TOPIC:
                record.domain_t.append(t)
                record.domains.append(_loop_points(update.entities[0]))
            else:
                record.cells_t.append(t)
                record.cells.append([_loop_points(e) for e in update.entities])
    if not record.pose_t:
        names = ", ".join(str(p) for p in parts)
        raise ValueError(f"{names}: no messages on {ROBOTS_TOPIC}")
    return record


@dataclass
class AgentStates:
    """The AgentStates of a run.mcap (/agents/states), in log time order: ``t[k]`` (s of
    mission time, when the coordinator saw it) and ``states[k]`` as the agent sent it;
    ``rejected`` counts the payloads that did not decode (left out); ``truncated``: the file
    ended early (its coordinator was killed) and was read up to its last whole record."""

    t: list[float] = field(default_factory=list)
    states: list[AgentState] = field(default_factory=list)
    rejected: int = 0
    truncated: bool = False

    def of(self, robot: int) -> list[tuple[float, AgentState]]:
        """(log time, state) of every state robot ``robot``'s agent sent, in time order."""
        return [(t, s) for t, s in zip(self.t, self.states, strict=True) if s.id == robot]

    def at(self, robot: int, t: float) -> tuple[float, AgentState] | None:
        """(log time, state) of the newest state of robot ``robot`` logged at or before
        mission time ``t`` (None if it had sent none yet)."""
        earlier = [(ts, s) for ts, s in self.of(robot) if ts <= t]
        return earlier[-1] if earlier else None


def read_agent_states(path: str | Path) -> AgentStates:
    """The AgentStates recorded in a run.mcap, decoded with covswarm.protocol (a payload
    that does not decode is counted in ``rejected``). Empty for a record without them
    (``--no-record-states``, a simulation, an older file). A file whose coordinator was
    killed is read up to its last whole record (``truncated``); ValueError for a file that
    is no MCAP file."""
    messages, _, truncated = _records(Path(path), [AGENT_STATES_TOPIC], decoded=False)
    record = AgentStates(truncated=truncated)
    for _, _, message in messages:
        try:
            state = AgentState.decode(message.data)
        except ProtocolError:
            record.rejected += 1
            continue
        record.t.append(message.log_time / 1e9)
        record.states.append(state)
    return record


def decoder_factories() -> list[Any]:
    """mcap decoders for a run.mcap: protobuf (the Foxglove schemas), JSON channels and
    the AgentStates (covswarm.protocol.AgentState; ProtocolError if one is malformed)."""
    from mcap.decoder import DecoderFactory
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

    class CovswarmDecoderFactory(DecoderFactory):
        def decoder_for(self, message_encoding: str, schema: Any) -> Any:
            if message_encoding == "json":
                return json.loads
            if message_encoding == AGENT_STATE_ENCODING and schema is not None:
                return AgentState.decode if schema.name == AGENT_STATE_SCHEMA else None
            return None

    return [ProtobufDecoderFactory(), CovswarmDecoderFactory()]


def _json_or_text(value: str) -> Any:
    try:
        return json.loads(value)
    except ValueError:
        return value


def frame_times(end: float, fps: float, speed: float) -> np.ndarray:
    """Mission times of the frames: every speed / fps s from 0 to ``end`` inclusive."""
    step = speed / fps
    return np.arange(math.floor(end / step + 1e-9) + 1) * step


def _latest(times: list[float], at: float) -> int | None:
    """Index of the newest entry with time <= at (None if there is none yet)."""
    k = int(np.searchsorted(times, at, side="right")) - 1
    return k if k >= 0 else None


def render(
    record: Recording, out: Path, *, fps: float = 10.0, speed: float = 1.0, dpi: int = 80
) -> int:
    """Write the animation to ``out`` (.gif or .mp4); returns the number of frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import animation
    from matplotlib.collections import EllipseCollection, LineCollection, PolyCollection

    suffix = out.suffix.lower()
    if suffix == ".gif":
        writer: Any = animation.PillowWriter(fps=fps)
    elif suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise click.ClickException(
                "MP4 needs ffmpeg on the PATH and it was not found: install it "
                "(e.g. apt-get install ffmpeg) or write a GIF (--out replay.gif)"
            )
        writer = animation.FFMpegWriter(fps=fps)
    else:
        raise click.UsageError(f"--out must end in .gif or .mp4, not {out.name!r}")

    times = frame_times(record.end, fps, speed)
    meta = record.metadata
    fig = plt.figure(figsize=(7.2, 5.6), layout="constrained")
    grid = fig.add_gridspec(2, 1, height_ratios=(4.0, 1.0))
    ax, ax_err = fig.add_subplot(grid[0]), fig.add_subplot(grid[1])
    ax.set_aspect("equal")
    workspace = meta.get("workspace")
    if workspace:
        ax.set_xlim(workspace[0], workspace[1])
        ax.set_ylim(workspace[2], workspace[3])
    else:
        every = np.array([xy[:2] for poses in record.poses for xy in poses.values()])
        every = np.vstack([every, *record.domains]) if record.domains else every
        low, high = every.min(axis=0) - 0.2, every.max(axis=0) + 0.2
        ax.set_xlim(low[0], high[0])
        ax.set_ylim(low[1], high[1])
    ax.add_collection(
        PolyCollection(obstacle_polygons(meta), color="#8c4d40", alpha=0.5), autolim=False
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    cell_lines = LineCollection([], colors="0.6", linewidths=0.7)
    ax.add_collection(cell_lines)
    (domain_line,) = ax.plot([], [], color="k", linewidth=1.5)
    robots = ax.quiver(
        [0.0], [0.0], [0.0], [0.0], color="#e08a1a", angles="xy", scale_units="xy", scale=1.0,
        width=0.006, zorder=4,
    )  # fmt: skip
    bodies = EllipseCollection(
        ROBOT_DIAMETER, ROBOT_DIAMETER, 0.0, units="xy", offsets=np.zeros((0, 2)),
        offset_transform=ax.transData, facecolors="#1f59d9", alpha=0.85, zorder=3,
    )  # fmt: skip
    ax.add_collection(bodies)
    title = ax.set_title("")
    ax_err.plot(record.error_t, record.error, color="0.8", linewidth=1.0)
    (error_line,) = ax_err.plot([], [], color="C3", linewidth=1.5)
    ax_err.set_xlim(0.0, max(record.end, 1e-3))
    finite = [e for e in record.error if math.isfinite(e)]
    ax_err.set_ylim(0.0, 1.05 * max(finite) if finite else 1.0)
    ax_err.set_xlabel("mission time (s)")
    ax_err.set_ylabel("e_a (m)")
    label = f"{meta.get('scenario', '?')}, {meta.get('agents', '?')} robots"

    def draw(frame: int) -> None:
        at = float(times[frame])
        k = _latest(record.pose_t, at)
        poses = np.array(list(record.poses[k].values()) if k is not None else []).reshape(-1, 3)
        bodies.set_offsets(poses[:, :2])
        robots.set_offsets(poses[:, :2])
        robots.N = len(poses)
        robots.set_UVC(HEADING_LENGTH * np.cos(poses[:, 2]), HEADING_LENGTH * np.sin(poses[:, 2]))
        if (d := _latest(record.domain_t, at)) is not None:
            closed = np.vstack([record.domains[d], record.domains[d][:1]])
            domain_line.set_data(closed[:, 0], closed[:, 1])
        if (c := _latest(record.cells_t, at)) is not None:
            cell_lines.set_segments([np.vstack([p, p[:1]]) for p in record.cells[c] if len(p)])
        e = int(np.searchsorted(record.error_t, at, side="right"))
        error_line.set_data(record.error_t[:e], record.error[:e])
        title.set_text(f"{label}   t = {at:5.1f} s")

    movie = animation.FuncAnimation(fig, draw, frames=len(times), blit=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task(f"rendering {out.name}", total=len(times))
        movie.save(
            out,
            writer=writer,
            dpi=dpi,
            progress_callback=lambda i, _n: bar.update(task, completed=i + 1),
        )
    plt.close(fig)
    return len(times)


@click.command("replay")
@click.argument(
    "run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), metavar="RUN_DIR"
)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="replay.gif or replay.mp4 (MP4 needs ffmpeg) [RUN_DIR/replay.gif].",
)
@click.option(
    "--fps",
    type=FiniteFloat(min=0, min_open=True, max=60),
    default=10.0,
    show_default=True,
    help="Frames per second of the animation.",
)
@click.option(
    "--speed",
    type=FiniteFloat(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Mission seconds per second of animation.",
)
@click.option(
    "--dpi",
    type=click.IntRange(min=20, max=300),
    default=80,
    show_default=True,
    help="Resolution of the frames, dots per inch.",
)
def replay_command(run_dir: Path, out: Path | None, fps: float, speed: float, dpi: int) -> None:
    """Render an animation of a recorded run (RUN_DIR/run.mcap, and run-1.mcap, ... of a
    resumed one): S, cells, robots, e_a."""
    parts = recording_parts(run_dir)
    if not parts:
        raise click.UsageError(f"{run_dir} has no {MCAP_FILE} (record one with covswarm run/sim)")
    try:
        record = read_recording(parts)
    except Exception as exc:  # a foreign or empty file: say so, never a traceback
        raise click.ClickException(f"cannot read {run_dir}: {exc}") from None
    for name in record.truncated:
        click.echo(
            f"{name} ends early (its coordinator stopped before closing it): read up to there"
        )
    out = run_dir / "replay.gif" if out is None else out
    frames = render(record, out, fps=fps, speed=speed, dpi=dpi)
    size = out.stat().st_size / 1e6
    click.echo(f"wrote {out} ({frames} frames, {record.end:.1f} s of mission, {size:.2f} MB)")
