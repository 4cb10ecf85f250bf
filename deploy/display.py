"""What ``covswarm run`` shows: live progress while it runs, a summary table at the end."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from covswarm.coordinator.monitor import HEADLINE_STATS
from covswarm.coordinator.pace import pace_sentence
from covswarm.deploy.processes import RunResult


@dataclass
class Progress:
    """What the display shows; updated by the launcher loop."""

    agents: int
    duration: float
    ready: set[tuple[str, int]] = field(default_factory=set)  # (role, id) seen alive
    status: Any = None  # latest protocol.Status
    # A planned route's lines, one per goal (mission.scenarios.route_lines): shown with
    # the start-up, before the mission starts.
    routes: tuple[str, ...] = ()


# s of wall time between two progress lines when the output is not a terminal (a pipe, a
# log file), where the live display does not refresh.
PLAIN_PERIOD = 10.0


class PlainLines:
    """Progress as a plain line every PLAIN_PERIOD s of wall time on a ``console`` (rich)
    that is not a terminal; nothing on one that is (its live display shows it)."""

    def __init__(self, console: Any) -> None:
        self.console = console
        self._next = math.inf if console.is_terminal else 0.0

    def __call__(self, line: Callable[[], str]) -> None:
        """Log ``line()`` if a line is due (``line`` is called only then)."""
        if time.monotonic() >= self._next:
            self.console.log(line())
            self._next = time.monotonic() + PLAIN_PERIOD


def ready_counts(progress: Progress) -> list[tuple[str, int, int]]:
    """(label, processes ready, expected) of the start-up, per role."""
    n = progress.agents
    return [
        (label, sum(1 for r, _ in progress.ready if r == role), total)
        for label, role, total in (
            ("coordinator", "coordinator", 1), ("robots", "robot", n), ("agents", "agent", n)
        )
    ]  # fmt: skip


def progress_line(progress: Progress) -> str:
    """What :func:`render` shows, on one plain line (for an output that is not a terminal)."""
    n, status = progress.agents, progress.status
    if status is None or status.state == "waiting":
        counts = ", ".join(f"{label} {k}/{total}" for label, k, total in ready_counts(progress))
        return f"start-up: {counts} ready"
    script = status.t if status.script_t is None else status.script_t
    error = "-" if status.error is None else f"{status.error:.4f} m"
    pace = "" if status.pace is None or status.pace >= 1.0 else f" at {status.pace:.2f}x"
    return (
        f"{status.state}: {script:.1f} / {progress.duration:.1f} s{pace}, e_a {error}, "
        f"alive {status.alive_robots}/{n} robots, {status.alive_agents}/{n} agents"
    )


def render(progress: Progress) -> Any:
    """Start-up: processes ready per role. Mission: time, e_a, processes alive."""
    from rich.progress_bar import ProgressBar
    from rich.table import Table

    def bar(completed: float, total: float, text: str) -> Table:
        row = Table.grid(padding=(0, 1))
        row.add_row(ProgressBar(total=total, completed=completed, width=30), text)
        return row

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    n = progress.agents
    status = progress.status
    if status is None or status.state == "waiting":
        table.add_row("phase", "start-up (waiting for liveliness tokens)")
        for label, count, total in ready_counts(progress):
            table.add_row(f"{label} ready", bar(count, total, f"{count}/{total}"))
        for line in progress.routes:
            table.add_row("route", line.removeprefix("route "))
        return table
    table.add_row("phase", status.state)
    script = status.t if status.script_t is None else status.script_t
    text = f"{script:.1f} / {progress.duration:.1f} s"
    if status.pace == 0.0:  # the deploy hold (coordinator.pace): S waits at S(0)
        text += " (deploying: the team spreads over S(0) before S moves)"
    elif status.pace is not None and status.pace < 1.0:  # an overloaded team: S slowed down
        text += f" at {status.pace:.2f}x (the agents do not hold their rate)"
    table.add_row("mission", bar(script, progress.duration, text))
    table.add_row("e_a", "-" if status.error is None else f"{status.error:.4f} m")
    table.add_row("robots alive", f"{status.alive_robots}/{n}")
    table.add_row("agents alive", f"{status.alive_agents}/{n}")
    return table


def live_brain_tick(
    result: RunResult, held_rate_hz: float | None, time_scale: float
) -> float | None:
    """CPU of the agent processes per brain-step during the mission, s: their CPU (% of a
    core each, ``result.cpu``) over the steps their brains took per wall second, the held
    rate (mission steps per mission s per brain, summary.json's pace) x the brains they host
    (``result.members``) x ``time_scale`` (mission s per wall s). None without those
    figures.

    The live counterpart of ``covswarm bench --brain-tick`` (sans-IO, no router): it adds
    what a real process pays for Zenoh and real traffic, and depends much less than the held
    rate on how much CPU other programs left the run (a starved process steps less often;
    each step costs somewhat more, as more messages wait for it).
    """
    cpu, brains = result.cpu.get("agent", []), sum(result.members.get("agent", []))
    if not cpu or not brains or not held_rate_hz or len(cpu) != len(result.members["agent"]):
        return None
    return sum(cpu) / 100.0 / (held_rate_hz * brains * time_scale)


def world_line(summary: dict[str, Any]) -> str:
    """The arena figures of summary.json (mission.world_metrics) on one console line."""
    clearance = summary.get("min_obstacle_clearance")
    line = (
        f"{summary['obstacle_contacts']} obstacle contacts; closest to a wall "
        + ("-" if clearance is None else f"{clearance:.3f} m")
        + f"; S over obstacles up to {summary['domain_obstacle_overlap']:.4f} m^2"
    )
    if summary.get("goals"):
        line += f"; goals reached {summary['goals_reached']} of {summary['goals']}"
    return line


def summary_table(
    summary: dict[str, Any], result: RunResult, out_dir: Path, time_scale: float = 1.0
) -> Any:
    """The closing table: errors, per-agent figures, memory, processes lost."""
    from rich.table import Table

    table = Table(title=f"covswarm run: {summary.get('scenario')}", show_header=False)
    table.add_column(style="bold")
    table.add_column()

    def fmt(value: Any, unit: str = "") -> str:
        return "-" if value is None else f"{value:.4g}{unit}"

    table.add_row("agents", str(summary.get("agents")))
    table.add_row("feedforward", str(summary.get("feedforward")))
    table.add_row("kappa", fmt(summary.get("kappa")))
    table.add_row("mission time", fmt(summary.get("mission_time"), " s"))
    if (pace := summary.get("pace")) is not None:  # what the machine held (coordinator.pace)
        table.add_row("rate held", pace_sentence(pace))
    table.add_row("e_a initial", fmt(summary.get("initial_error"), " m"))
    table.add_row("e_a steady state (2nd half)", fmt(summary.get("steady_state_error_mean"), " m"))
    table.add_row("e_a final", fmt(summary.get("final_error"), " m"))
    # Physical figures (mission.physical): how close robots came, how hard wheels worked.
    closest, diameter = summary.get("min_pairwise_distance"), summary.get("robot_diameter")
    if diameter is not None:
        table.add_row("closest robots", fmt(closest, " m"))
        table.add_row(
            f"close approaches (< {diameter:g} m)",
            f"{summary.get('close_approaches', 0)}, {summary.get('close_approach_time', 0.0):.1f} "
            "pair-s",
        )
    if summary.get("min_obstacle_clearance") is not None or summary.get("goals"):
        table.add_row("arena", world_line(summary))  # a workspace, obstacles or goals
    if summary.get("max_wheel_speed_used") is not None:
        table.add_row(
            "wheels",
            f"up to {summary['max_wheel_speed_used']:.2f} m/s, saturated "
            f"{summary['saturated_time']:.1f} robot-s ({summary['saturated_fraction']:.1%})",
        )
    team = summary.get("agent_stats", {}).get("team", {})
    for name in HEADLINE_STATS:
        if name in team:
            f = team[name]
            table.add_row(
                f"agent {name}", f"mean {f['mean']:.4g}  min {f['min']:.4g}  max {f['max']:.4g}"
            )
    for role, values in sorted(result.rss.items()):
        table.add_row(
            f"RSS per {role} process", f"mean {np.mean(values):.0f} MB  max {max(values):.0f} MB"
        )
        if (hosted := sum(result.members.get(role, ()))) > len(values):
            table.add_row(f"RSS per {role}", f"{sum(values) / hosted:.1f} MB")
    for role, values in sorted(result.cpu.items()):
        table.add_row(
            f"CPU per {role} process",
            f"mean {np.mean(values):.1f}%  max {max(values):.1f}% of a core (total "
            f"{sum(values):.0f}%)",
        )
    others = sum(sum(values) for role, values in result.cpu.items() if role != "agent")
    if others:  # what the agents cannot have of the machine
        table.add_row("CPU outside the agents", f"{others:.0f}% of a core")
    held = (summary.get("pace") or {}).get("held_rate_hz")
    if (tick := live_brain_tick(result, held, time_scale)) is not None:
        table.add_row(
            "CPU per brain-tick (live)",
            f"{1e3 * tick:.2f} ms (agent processes' CPU / brain steps; sans-IO: covswarm "
            "bench --brain-tick)",
        )
    lost = summary.get("lost_processes", [])
    table.add_row("liveliness lost", ", ".join(map(describe_loss, lost)) or "none")
    if (unexpected := summary.get("unexpected") or {}).get("total"):
        # ids outside the team that held tokens or sent poses or states (coordinator.team)
        ids = ", ".join(map(str, unexpected["first_ids"]))
        more = "+" if unexpected["distinct_ids"] > len(unexpected["first_ids"]) else ""
        table.add_row(
            "outside the team",
            f"[yellow]ids {ids}{more}: {unexpected['total']} tokens and messages refused",
        )
    table.add_row("outputs", str(out_dir))
    return table


def describe_loss(loss: dict) -> str:
    """A lost token of summary.json's lost_processes, with when: "robot 5 at t = 10.8 s"
    (mission time), or "before the start" (a process that left and came back is then
    named twice, each with its time)."""
    when = "before the start" if loss.get("t") is None else f"at t = {loss['t']:.1f} s"
    return f"{loss['role']} {loss['id']} {when}"
