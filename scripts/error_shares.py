"""Who makes a run's e_a: the share of the robots farthest from their centroids.

Usage: .venv/bin/python scripts/error_shares.py RUN_DIR [--at 0.5,0.6,0.7,0.8,0.9,1] [--top 10]
       [--seconds 1,2,3,5] [--interpolate]

Reads a run's output folder (``covswarm run`` or ``covswarm sim``: trajectories.csv and
domain.csv) and, at each fraction ``--at`` of its last recorded time (or at each time
``--seconds``), places every robot at its latest recorded pose, tessellates S of the nearest
recorded instant (covswarm.tvd.coverage.tessellate) and prints one Markdown row. With
``--interpolate`` each robot is placed between its two records around the time and S's
vertices between S's two (a live run records each robot every 50 ms or so, and its latest
pose overstated e_a: 0.082 against 0.056 m over 15-30 s of a 1000-robot run). The row:
e_a = ||p - c|| (m), the share of e_a^2 carried by the ``--top`` robots farthest from
their centroids, e_a without them, the median robot's distance to its centroid (mm) and
the robots outside S. A few stragglers (robots left outside a moving S) show as a large
share; a team off its CVT as a whole as a small one. docs/scaling.md quotes it.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import click
import numpy as np

from covswarm.mission.world_metrics import DOMAIN_FILE
from covswarm.records.trajectories import read_trajectories
from covswarm.tvd.coverage import as_vectors, tessellate


def read_domains(path: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """domain.csv's instants (T,) s and S at each, vertices (k, 2) m, in file order."""
    rows = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    times, starts = np.unique(rows[:, 0], return_index=True)
    bounds = [*sorted(starts), len(rows)]
    by_start = {start: rows[start:end, 2:4] for start, end in itertools.pairwise(bounds)}
    return times, [by_start[start] for start in starts]


def latest_positions(rows: np.ndarray, t: float) -> np.ndarray:
    """(n, 2) m: each robot's latest recorded position at or before ``t`` (rows: t, id, x,
    y, theta, as read_trajectories gives them, in time order); robots ids 0..n-1."""
    upto = rows[rows[:, 0] <= t]
    ids = upto[:, 1].astype(int)
    positions = np.full((int(rows[:, 1].max()) + 1, 2), np.nan)
    positions[ids] = upto[:, 2:4]  # later rows overwrite earlier ones
    return positions


def robot_tracks(rows: np.ndarray) -> list[np.ndarray | None]:
    """Each robot's rows (t, id, x, y, theta) in time order, by id (None: never recorded);
    ``rows`` as read_trajectories gives them, in time order; robot ids 0..n-1."""
    ids = rows[:, 1].astype(int)
    order = np.argsort(ids, kind="stable")  # by robot, each still in time order
    present, starts = np.unique(ids[order], return_index=True)
    tracks: list[np.ndarray | None] = [None] * (int(ids.max()) + 1)
    for robot, track in zip(present.tolist(), np.split(rows[order], starts[1:]), strict=True):
        tracks[robot] = track
    return tracks


def interpolated_positions(tracks: list[np.ndarray | None], t: float) -> np.ndarray:
    """(n, 2) m: each robot's position at ``t``, linear between its records around it, its
    first or last record beyond them, NaN for a robot first recorded after ``t`` (tracks:
    :func:`robot_tracks`)."""
    positions = np.full((len(tracks), 2), np.nan)
    for robot, own in enumerate(tracks):
        if own is not None and own[0, 0] <= t:
            positions[robot] = [np.interp(t, own[:, 0], own[:, k]) for k in (2, 3)]
    return positions


def domain_at(times: np.ndarray, polygons: list[np.ndarray], t: float) -> np.ndarray:
    """S's vertices (k, 2) at ``t``: linear between the recorded instants around it when
    both have the same vertices, else those of the nearest instant."""
    after = int(np.searchsorted(times, t))
    if 0 < after < len(times) and polygons[after - 1].shape == polygons[after].shape:
        share = (t - times[after - 1]) / (times[after] - times[after - 1])
        return (1.0 - share) * polygons[after - 1] + share * polygons[after]
    return polygons[int(np.argmin(np.abs(times - t)))]


def outside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(n,) bool: points strictly outside the convex polygon (k, 2), either orientation."""
    after = np.roll(polygon, -1, axis=0)
    edges = after - polygon
    twice_area = np.sum(polygon[:, 0] * after[:, 1] - after[:, 0] * polygon[:, 1])
    rel = points[:, None, :] - polygon[None, :, :]
    cross = edges[None, :, 0] * rel[:, :, 1] - edges[None, :, 1] * rel[:, :, 0]
    return np.any(np.sign(twice_area) * cross < 0.0, axis=1)


def shares(
    run_dir: Path,
    at: list[float],
    top: int,
    seconds: list[float] | None = None,
    interpolate: bool = False,
) -> list[dict[str, float]]:
    """One dict per fraction of ``at`` (or per time of ``seconds``): t, e_a, top_share,
    e_a_rest, median_mm, outside; ``interpolate``: positions and S between records."""
    rows = read_trajectories(run_dir / "trajectories.csv")
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    times, polygons = read_domains(run_dir / DOMAIN_FILE)
    out = []
    instants = seconds if seconds is not None else [f * rows[:, 0].max() for f in at]
    tracks = robot_tracks(rows) if interpolate else []
    for t in instants:
        if interpolate:
            positions, polygon = interpolated_positions(tracks, t), domain_at(times, polygons, t)
        else:
            positions = latest_positions(rows, t)
            polygon = polygons[int(np.argmin(np.abs(times - t)))]
        known = np.isfinite(positions).all(axis=1)
        points, _, batch = tessellate(positions[known], polygon)
        error = np.linalg.norm(points - as_vectors(batch.centroid), axis=1)
        squares = np.sort(error**2)[::-1]
        total = float(squares.sum())
        out.append(
            {
                "t": t,
                "e_a": total**0.5,
                "top_share": float(squares[:top].sum()) / total if total > 0.0 else 0.0,
                "e_a_rest": float(squares[top:].sum()) ** 0.5,
                "median_mm": float(np.median(error)) * 1e3,
                "outside": int(outside(positions[known], polygon).sum()),
            }
        )
    return out


@click.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--at", "at", default="0.5,0.6,0.7,0.8,0.9,1", show_default=True)
@click.option("--top", type=click.IntRange(min=1), default=10, show_default=True)
@click.option("--seconds", default=None, help="Times (s) instead of --at's fractions: 1,2,3,5")
@click.option("--interpolate", is_flag=True, help="Robots and S between their records.")
def main(run_dir: Path, at: str, top: int, seconds: str | None, interpolate: bool) -> None:
    """Who makes the e_a of the run in RUN_DIR (module docstring)."""
    fractions = [float(f) for f in at.split(",")]
    times = None if seconds is None else [float(t) for t in seconds.split(",")]
    print(
        f"| t, s | e_a, m | top {top} share of e_a^2 | e_a without them, m | median, mm |", end=""
    )
    print(" outside S |")
    print("|---|---|---|---|---|---|")
    for row in shares(run_dir, fractions, top, times, interpolate):
        print(
            f"| {row['t']:.3g} | {row['e_a']:.3f} | {row['top_share']:.2f} | "
            f"{row['e_a_rest']:.3f} | {row['median_mm']:.1f} | {row['outside']} |"
        )


if __name__ == "__main__":
    main()
