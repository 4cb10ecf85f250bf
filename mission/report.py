"""Run outputs shared by ``covswarm sim`` and the coordinator.

``write_outputs`` writes summary.json, error.csv, error.png and trajectories.png into a folder.
The JSON and CSV hold no timestamps or paths, so a deterministic run gives byte-identical
files. Only the simulator and the coordinator import this module (it pulls in matplotlib).
"""

from __future__ import annotations

import csv
import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

Box = tuple[float, float, float, float]


def steady_state_mean(t: np.ndarray, error: np.ndarray) -> float:
    """Mean of e_a over the second half of the run (t >= t_end / 2), ignoring NaN samples."""
    t, error = np.asarray(t, dtype=float), np.asarray(error, dtype=float)
    window = error[t >= t[0] + 0.5 * (t[-1] - t[0])]
    window = window[np.isfinite(window)]
    return float(window.mean()) if window.size else float("nan")


def neighbor_histogram(positions: np.ndarray, polygon: np.ndarray) -> dict[int, int]:
    """{number of Voronoi neighbours: number of robots}, sorted by neighbour count."""
    from covswarm.tvd.coverage import neighbors

    counts = Counter(len(s) for s in neighbors(positions, polygon))
    return dict(sorted(counts.items()))


def write_outputs(
    out_dir: str | Path,
    *,
    summary: dict[str, Any],
    t: np.ndarray,
    error: np.ndarray,
    trajectories: np.ndarray,
    polygons: list[np.ndarray],
    error_compare: np.ndarray | None = None,
    obstacles: Sequence[np.ndarray] = (),
    workspace: Box | None = None,
    density: Any = None,
    script_start: float | None = None,
) -> Path:
    """Write the four output files and return the folder.

    t, error, error_compare: (T,); trajectories: (T, n, 2), NaN where a robot's position is
    unknown; polygons: T arrays (k, 2), the domain at each sample; obstacles: every obstacle
    of the world (boxes, convex polygons, a map's pieces) as its vertices (k, 2) m;
    workspace: (xmin, xmax, ymin, ymax) m or None; density: phi at the last sample
    (covswarm.tvd.density.Density, shaded under the final domain), None when uniform;
    script_start: s, when S started moving after a deploy hold (error.png's steady-state
    window is then the second half of what follows, as summary.json's), None without one.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = np.asarray(t, dtype=float)
    error = np.asarray(error, dtype=float)
    compare = None if error_compare is None else np.asarray(error_compare, dtype=float)
    (out / "summary.json").write_text(
        json.dumps(_plain(summary), indent=2, sort_keys=True) + "\n", encoding="utf-8"
    )
    _write_csv(out / "error.csv", t, error, compare)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = _error_figure(plt, t, error, compare, script_start)
    _mark_steering(fig.axes[0], summary.get("steering", ()))
    fig.savefig(out / "error.png", dpi=120)
    plt.close(fig)
    fig = _trajectory_figure(
        plt, summary, np.asarray(trajectories, float), polygons, obstacles, workspace, density
    )
    fig.savefig(out / "trajectories.png", dpi=120)
    plt.close(fig)
    return out


def _plain(value: Any) -> Any:
    """JSON-ready copy: numpy scalars/arrays to Python, dict keys to str."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _write_csv(path: Path, t: np.ndarray, error: np.ndarray, compare: np.ndarray | None) -> None:
    header = ["t", "e_a"] + ([] if compare is None else ["e_a_without_feedforward"])
    columns = [t, error] + ([] if compare is None else [compare])
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        # repr gives the shortest string that reads back to the same float.
        writer.writerows([repr(float(v)) for v in row] for row in zip(*columns, strict=True))


def _error_figure(
    plt: Any,
    t: np.ndarray,
    error: np.ndarray,
    compare: np.ndarray | None,
    script_start: float | None = None,
) -> Any:
    fig, ax = plt.subplots(figsize=(8, 4.5), layout="constrained")
    curves = [("with $\\partial c/\\partial t$", error, "tab:blue", "-")]
    if compare is not None:
        curves.append(("without $\\partial c/\\partial t$", compare, "tab:red", ":"))
    scripted = np.ones(t.shape, dtype=bool) if script_start is None else t >= script_start
    if not scripted.any():
        scripted[:] = True  # held to the end: the whole run
    start = t[scripted][0]
    t_half = start + 0.5 * (t[-1] - start)
    if start > t[0]:
        ax.axvspan(t[0], start, color="tab:green", alpha=0.08, zorder=0, label="deploy hold")
    for label, values, color, style in curves:
        mean = steady_state_mean(t[scripted], values[scripted])
        ax.plot(t, values, color=color, linestyle=style, linewidth=1.4, label=label)
        ax.hlines(mean, t_half, t[-1], colors=color, linestyles="--", linewidth=1.0)
        ax.annotate(
            f"steady-state mean {mean:.4g} m",
            (t_half, mean),
            xytext=(4, 4 if color == "tab:blue" else -13),
            textcoords="offset points",
            color=color,
            fontsize=9,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    ax.axvspan(t_half, t[-1], color="0.93", zorder=0)
    positive = np.concatenate([c[1][np.isfinite(c[1]) & (c[1] > 0)] for c in curves])
    if positive.size:
        ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("$e_a = \\|p - c(p, t)\\|$ [m]")
    ax.set_title("Aggregate CVT error (shaded: steady-state window)")
    ax.set_xlim(t[0], t[-1])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper right")
    return fig


def _mark_steering(ax: Any, requests: Any) -> None:
    """Steering requests (summary.json's ``steering``) on the e_a plot: accepted ones as a
    green line at their arrival and a band while S moved (until the motion's end, or the
    next accepted request, which takes over from it), refused ones as a red dotted line."""
    seen: set[bool] = set()
    taken = sorted(float(r["t"]) for r in requests if r["accepted"])
    for request in requests:
        accepted, t = bool(request["accepted"]), float(request["t"])
        label = None
        if accepted not in seen:
            label = "steering request" if accepted else "refused steering request"
            seen.add(accepted)
        color = "tab:green" if accepted else "tab:red"
        ax.axvline(t, color=color, linestyle="-" if accepted else ":", linewidth=1.0, label=label)
        if accepted and request["duration"] > 0:
            later = [other for other in taken if other > t]
            end = min([t + float(request["duration"]), *later[:1]])
            ax.axvspan(t, end, color=color, alpha=0.12, zorder=0)
    if seen:
        ax.legend(loc="upper right")


def _trajectory_figure(
    plt: Any,
    summary: dict[str, Any],
    trajectories: np.ndarray,
    polygons: list[np.ndarray],
    obstacles: Sequence[np.ndarray],
    workspace: Box | None,
    density: Any,
) -> Any:
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Polygon, Rectangle

    from covswarm.tvd.coverage import cells

    fig, ax = plt.subplots(figsize=(8, 7), layout="constrained")
    if workspace is not None:
        xmin, xmax, ymin, ymax = workspace
        ax.add_patch(
            Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, color="k", lw=1.5)
        )
    # One collection, however many pieces a map has.
    ax.add_collection(PolyCollection(obstacles, color="tab:red", alpha=0.6))

    # Domain: centroid trace (vertex mean) and a few outlines, darker as time goes on.
    centres = np.array([np.asarray(p, float).mean(axis=0) for p in polygons])
    ax.plot(centres[:, 0], centres[:, 1], "k--", lw=1.0, label="domain centre path")
    shown = np.unique(np.linspace(0, len(polygons) - 1, 7).round().astype(int))
    for rank, index in enumerate(shown):
        shade = 0.75 - 0.6 * rank / max(len(shown) - 1, 1)
        ax.add_patch(Polygon(polygons[index], closed=True, fill=False, ec=str(shade), lw=1.0))

    if density is not None:
        _shade_density(ax, density, np.asarray(polygons[-1], float))

    n = trajectories.shape[1]
    alpha = 0.8 if n <= 20 else 0.35
    colors = plt.get_cmap("tab20")(np.arange(n) % 20)
    for i in range(n):
        ax.plot(trajectories[:, i, 0], trajectories[:, i, 1], color=colors[i], lw=0.8, alpha=alpha)

    final = _last_known(trajectories)
    known = np.isfinite(final).all(axis=1)
    polygon = np.asarray(polygons[-1], float)
    if known.any():
        for cell in cells(final[known], polygon):
            if len(cell):
                ax.add_patch(Polygon(cell, closed=True, fill=False, ec="tab:blue", lw=0.8))
        ax.scatter(
            *final[known].T,
            s=14 if n > 20 else 30,
            c=colors[known],
            ec="k",
            lw=0.5,
            zorder=3,
            label="final robots + Voronoi cells",
        )
    goals = np.asarray(summary.get("goal_list") or [], float).reshape(-1, 2)
    if len(goals):  # where S's centroid was sent: filled once reached
        times = list(summary.get("goal_times") or [None] * len(goals))
        reached = np.array([when is not None for when in times])
        for rows, face, label in ((reached, "gold", "goal reached"), (~reached, "none", "goal")):
            if rows.any():
                ax.scatter(*goals[rows].T, marker="*", s=220, fc=face, ec="k", zorder=5,
                           label=label)  # fmt: skip
        for k, (x, y) in enumerate(goals, start=1):
            ax.annotate(str(k), (x, y), xytext=(6, 6), textcoords="offset points", zorder=5)
    still = list(summary.get("still", ()))  # covswarm sim --still's dead robots
    if still:
        ax.scatter(
            *final[still].T, marker="s", s=40, c="k", zorder=4,
            label="dead robots (still generators)",
        )  # fmt: skip
    ax.add_patch(Polygon(polygon, closed=True, fill=False, ec="tab:blue", lw=1.8))
    first = trajectories[0][np.isfinite(trajectories[0]).all(axis=1)]
    ax.scatter(*first.T, marker="x", s=10, c="0.4", lw=0.8, label="start")
    close = [entry["at"] for entry in summary.get("close_approach_list", ())]
    if close:
        ax.scatter(
            *np.array(close).T, marker="o", s=60, facecolors="none", edgecolors="red", lw=1.2,
            zorder=4, label=f"close approach (< {summary['robot_diameter']:g} m)",
        )  # fmt: skip

    ax.set_aspect("equal")
    if workspace is not None:
        pad = 0.05 * max(workspace[1] - workspace[0], workspace[3] - workspace[2])
        ax.set_xlim(workspace[0] - pad, workspace[1] + pad)
        ax.set_ylim(workspace[2] - pad, workspace[3] + pad)
    else:
        ax.autoscale_view()
    title = ", ".join(
        f"{key} {summary[key]}"
        for key in ("scenario", "agents", "law", "dynamics")
        if key in summary
    )
    ax.set_title(f"{title}\n(grey: domain over time, dark blue: final domain)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="lower left", fontsize=8, framealpha=0.9)
    return fig


def _shade_density(ax: Any, density: Any, polygon: np.ndarray) -> None:
    """phi over the final domain as a light-to-dark green image clipped to the domain."""
    from matplotlib.patches import Polygon

    (xmin, ymin), (xmax, ymax) = polygon.min(axis=0), polygon.max(axis=0)
    x, y = np.meshgrid(np.linspace(xmin, xmax, 200), np.linspace(ymin, ymax, 200))
    phi = density.phi(np.stack([x, y], axis=-1))
    image = ax.imshow(
        phi, extent=(xmin, xmax, ymin, ymax), origin="lower", cmap="Greens", alpha=0.6, zorder=0
    )
    image.set_clip_path(Polygon(polygon, closed=True, transform=ax.transData))
    ax.figure.colorbar(image, ax=ax, shrink=0.6, label="final density $\\phi(q, t)$")


def _last_known(trajectories: np.ndarray) -> np.ndarray:
    """(n, 2): each robot's last non-NaN position (NaN if never known)."""
    valid = np.isfinite(trajectories).all(axis=2)  # (T, n)
    last = trajectories.shape[0] - 1 - np.argmax(valid[::-1], axis=0)
    final = trajectories[last, np.arange(trajectories.shape[1])]
    final[~valid.any(axis=0)] = np.nan
    return final
