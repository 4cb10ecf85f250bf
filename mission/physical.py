"""Physical figures of a run: how close robots came, and how hard their wheels worked.

Pure numpy/scipy over recorded samples, shared by ``covswarm sim`` and the coordinator, so
both write the same keys into summary.json (:func:`physical_summary`). Robots are disks of
``diameter`` (m): a *close approach* is an episode during which a pair's centres are nearer
than one diameter (their bodies touch or overlap), counted once per episode from the first
sample below to the first sample back at or above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# Close approaches listed one by one in summary.json and marked on the trajectory plot (all
# are counted).
LISTED_APPROACHES = 200


@dataclass(frozen=True)
class CloseApproach:
    """One episode of a pair nearer than a diameter. Times in s, distances in m."""

    pair: tuple[int, int]  # robot ids, smaller first
    start: float
    duration: float
    closest: float  # smallest centre distance during the episode
    at: tuple[float, float]  # midpoint of the pair at its closest (for the plot)


def proximity(
    t: np.ndarray, trajectories: np.ndarray, diameter: float, ids: list[int] | None = None
) -> tuple[float | None, float | None, list[CloseApproach]]:
    """(smallest centre distance over the run, when, close-approach episodes).

    t: (T,) s; trajectories: (T, n, 2) m, NaN where a robot is unknown at a sample; ids: the
    robot id of each column (default 0..n-1). An episode's duration sums the sample
    intervals that begin below one diameter; the last sample counts for nothing. A kd-tree
    per sample keeps this O(T n log n), so a 1000-robot record costs seconds, not minutes.
    """
    t = np.asarray(t, dtype=float)
    trajectories = np.asarray(trajectories, dtype=float)
    n = trajectories.shape[1]
    ids = list(range(n)) if ids is None else list(ids)
    steps = np.diff(t, append=t[-1]) if t.size else t
    smallest, when = np.inf, None
    # The open episodes as arrays sorted by pair code (i n + j, i < j), so that a sample's
    # pairs are matched in bulk: a crowded team has millions of pair-samples, and one Python
    # step each took 87 % of a 20 000-robot sim (py-spy, 3 Dec 2026).
    codes = np.zeros(0, dtype=np.int64)
    start, duration, closest = np.zeros(0), np.zeros(0), np.zeros(0)
    at = np.zeros((0, 2))
    done: list[tuple[np.ndarray, ...]] = []  # closed episodes: (codes, start, ...) batches
    for k in range(t.size):
        known = np.flatnonzero(np.isfinite(trajectories[k]).all(axis=1))
        new_codes, dist, mid = np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 2))
        if known.size >= 2:
            points = trajectories[k, known]
            tree = cKDTree(points)
            d, _ = tree.query(points, k=2)
            if d[:, 1].min() < smallest:
                smallest, when = float(d[:, 1].min()), float(t[k])
            pairs = tree.query_pairs(diameter, output_type="ndarray").reshape(-1, 2)
            gaps = points[pairs[:, 0]] - points[pairs[:, 1]]
            dist = np.sqrt(np.einsum("ij,ij->i", gaps, gaps))
            near = dist < diameter  # query_pairs is inclusive
            pairs, dist = pairs[near], dist[near]
            mid = 0.5 * (points[pairs[:, 0]] + points[pairs[:, 1]])
            ends = np.sort(known[pairs], axis=1)
            new_codes = ends[:, 0].astype(np.int64) * n + ends[:, 1]
            order = np.argsort(new_codes)
            new_codes, dist, mid = new_codes[order], dist[order], mid[order]
        going_on = np.isin(codes, new_codes, assume_unique=True)
        done.append((codes[~going_on], start[~going_on], duration[~going_on],
                     closest[~going_on], at[~going_on]))  # fmt: skip
        codes, start, duration = codes[going_on], start[going_on], duration[going_on]
        closest, at = closest[going_on], at[going_on]
        row = np.searchsorted(codes, new_codes)
        seen = row < codes.size
        seen[seen] = codes[row[seen]] == new_codes[seen]
        rows = row[seen]  # episodes going on, in new_codes' order
        nearer = dist[seen] < closest[rows]
        closest[rows[nearer]] = dist[seen][nearer]
        at[rows[nearer]] = mid[seen][nearer]
        duration += steps[k]
        fresh = ~seen
        codes = np.concatenate((codes, new_codes[fresh]))
        start = np.concatenate((start, np.full(int(fresh.sum()), t[k])))
        duration = np.concatenate((duration, np.full(int(fresh.sum()), steps[k])))
        closest = np.concatenate((closest, dist[fresh]))
        at = np.concatenate((at, mid[fresh]))
        order = np.argsort(codes, kind="stable")
        codes, start, duration = codes[order], start[order], duration[order]
        closest, at = closest[order], at[order]
    done.append((codes, start, duration, closest, at))
    approaches = [
        _approach((int(code) // n, int(code) % n), [s, d, c, a], ids)
        for batch in done
        for code, s, d, c, a in zip(*(x.tolist() for x in batch), strict=True)
    ]
    approaches.sort(key=lambda a: (a.start, a.pair))
    return (None if when is None else smallest), when, approaches


def _approach(pair: tuple[int, int], entry: list, ids: list[int]) -> CloseApproach:
    start, duration, closest, at = entry
    a, b = sorted((ids[pair[0]], ids[pair[1]]))
    return CloseApproach((a, b), start, duration, closest, (float(at[0]), float(at[1])))


def wheel_figures(t: np.ndarray, wheels: np.ndarray, max_wheel_speed: float) -> dict:
    """Largest rim speed commanded and time spent saturated, from commands held per sample.

    t: (T,) s, the time each command was issued; wheels: (T, n, 2) m/s (NaN: no command).
    A command is saturated when a wheel is at the limit (the mapping scales both wheels to
    it). ``saturated_time``: robot-seconds under a saturated command (each command held until
    the next sample); ``saturated_fraction``: the share of robot-commands saturated.
    """
    t = np.asarray(t, dtype=float)
    wheels = np.asarray(wheels, dtype=float)
    peak = np.nanmax(np.abs(wheels), axis=2, initial=0.0)  # (T, n)
    issued = np.isfinite(wheels).all(axis=2)
    saturated = issued & (peak >= max_wheel_speed * (1.0 - 1e-9))
    held = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 0.0))
    return {
        "max_wheel_speed_used": float(peak[issued].max(initial=0.0)),
        "saturated_time": float((saturated * held[:, None]).sum()),
        "saturated_fraction": float(saturated.sum() / max(issued.sum(), 1)),
    }


def agent_wheel_figures(stats: dict[int, dict[str, float]], mission_time: float) -> dict:
    """:func:`wheel_figures`' keys from the agents' own counts (their AgentState.stats:
    ``wheel_max`` m/s and ``saturated_s`` s of mission under a saturated command), for a
    distributed run whose coordinator never sees the commands. None without such stats."""
    reported = [entry for entry in stats.values() if "wheel_max" in entry]
    if not reported:
        return dict.fromkeys(("max_wheel_speed_used", "saturated_time", "saturated_fraction"))
    saturated = float(sum(entry.get("saturated_s", 0.0) for entry in reported))
    return {
        "max_wheel_speed_used": float(max(entry["wheel_max"] for entry in reported)),
        "saturated_time": saturated,
        "saturated_fraction": saturated / max(len(reported) * mission_time, 1e-9),
    }


def physical_summary(
    t: np.ndarray, trajectories: np.ndarray, diameter: float, ids: list[int] | None = None
) -> tuple[dict, list[CloseApproach]]:
    """The summary.json keys of :func:`proximity`, and the episodes (for the plot).

    ``min_pairwise_distance`` (m, null with fewer than two robots), ``min_distance_t`` (s),
    ``close_approaches`` (episodes), ``close_approach_time`` (pair-seconds below a
    diameter), ``robot_diameter``, and the first LISTED_APPROACHES episodes
    (``close_approach_list``: pair, start, duration, closest, ``at`` = the pair's midpoint
    at its closest, which the trajectory plot marks).
    """
    smallest, when, approaches = proximity(t, trajectories, diameter, ids)
    return {
        "robot_diameter": float(diameter),
        "min_pairwise_distance": smallest,
        "min_distance_t": when,
        "close_approaches": len(approaches),
        "close_approach_time": float(sum(a.duration for a in approaches)),
        "close_approach_list": [
            {
                "pair": list(a.pair),
                "start": a.start,
                "duration": a.duration,
                "closest": a.closest,
                "at": list(a.at),
            }
            for a in approaches[:LISTED_APPROACHES]
        ],
    }, approaches
