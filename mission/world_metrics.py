"""How a run went against its arena: contacts, clearance, S over obstacles, goals reached.

Pure numpy over recorded samples (``covswarm sim``'s every step, or a run's records), so the
simulator and the coordinator write the same keys into summary.json
(:func:`world_summary`). Robots are disks of ``radius`` m; a body's *clearance* is the
distance from its edge to the nearest obstacle or workspace wall (negative when it
overlaps one: covswarm.world.model.World.clearance minus the radius). A *contact* is an
episode during which a robot's clearance is at most CONTACT_TOLERANCE, counted once per
robot from the first sample at or below it to the first sample back above it. S's
centroid reaches a goal when its path (straight between samples) passes within
GOAL_TOLERANCE of it; goals are visited in order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from covswarm.tvd.geometry import nearest_points
from covswarm.world.model import World

CONTACT_TOLERANCE = 1e-3  # m: a body this close to an obstacle or wall touches it
GOAL_TOLERANCE = 1e-3  # m: S's centroid this close to a goal has reached it
LISTED_CONTACTS = 200  # contacts listed one by one in summary.json (all are counted)
DOMAIN_FILE = "domain.csv"


@dataclass(frozen=True)
class Contact:
    """One episode of a robot body within CONTACT_TOLERANCE of an obstacle or wall.

    Times in s, distances in m; ``closest``: the smallest clearance during the episode
    (negative: overlapping); ``what``: the obstacle's name, or "workspace", at that instant.
    """

    robot: int
    start: float
    duration: float
    closest: float
    what: str


def clearances(trajectories: np.ndarray, radius: float, world: World) -> np.ndarray:
    """(T, n) each body's clearance (m) at each sample: World.clearance of its centre minus
    ``radius``. trajectories: (T, n, 2) m, NaN where a robot is unknown (NaN out); inf in a
    world with neither obstacles nor workspace."""
    xy = np.asarray(trajectories, dtype=float)
    if xy.ndim != 3 or xy.shape[2] != 2:
        raise ValueError(f"trajectories must be (T, n, 2), got {xy.shape}")
    flat = xy.reshape(-1, 2)
    known = np.all(np.isfinite(flat), axis=1)
    out = np.full(len(flat), np.nan)
    out[known] = world.clearance(flat[known]) - radius
    return out.reshape(xy.shape[:2])


def obstacle_contacts(
    t: np.ndarray,
    trajectories: np.ndarray,
    radius: float,
    world: World,
    ids: Sequence[int] | None = None,
    tolerance: float = CONTACT_TOLERANCE,
) -> list[Contact]:
    """The contact episodes of a run, by start time then robot.

    t: (T,) s; trajectories: (T, n, 2) m (NaN: unknown, which ends an episode); ids: each
    column's robot id (default 0..n-1). An episode's duration sums the sample intervals that
    begin in contact (the last sample counts for nothing), as covswarm.mission.physical
    counts close approaches.
    """
    t = np.asarray(t, dtype=float)
    gap = clearances(trajectories, radius, world)
    ids = list(range(gap.shape[1])) if ids is None else list(ids)
    steps = np.diff(t, append=t[-1]) if t.size else t
    touching = gap <= tolerance  # NaN compares False: unknown is not touching
    episodes: list[Contact] = []
    for i in range(gap.shape[1]):
        column = np.concatenate([[False], touching[:, i], [False]])
        starts = np.flatnonzero(column[1:] & ~column[:-1])
        ends = np.flatnonzero(~column[1:] & column[:-1])  # first sample back out
        for a, b in zip(starts, ends, strict=True):
            k = a + int(np.argmin(gap[a:b, i]))
            point = np.asarray(trajectories, dtype=float)[k, i]
            episodes.append(
                Contact(
                    robot=ids[i],
                    start=float(t[a]),
                    duration=float(steps[a:b].sum()),
                    closest=float(gap[k, i]),
                    what=nearest_thing(point, world),
                )
            )
    episodes.sort(key=lambda c: (c.start, c.robot))
    return episodes


def nearest_thing(point: np.ndarray, world: World) -> str:
    """The name of the obstacle nearest ``point`` (2,) m, or "workspace" when a wall is
    nearer (or there are no obstacles)."""
    p = np.asarray(point, dtype=float).reshape(1, 2)
    best, name = np.inf, "workspace"
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = world.workspace
        best = float(min(p[0, 0] - xmin, xmax - p[0, 0], p[0, 1] - ymin, ymax - p[0, 1]))
    for obstacle in world.obstacles:
        _, distance, inside = nearest_points(p, obstacle.vertices)
        d = -np.inf if inside[0] else float(distance[0])
        if d < best:
            best, name = d, obstacle.name
    return name


def min_obstacle_clearance(
    t: np.ndarray, trajectories: np.ndarray, radius: float, world: World
) -> tuple[float | None, float | None]:
    """(smallest body clearance over the run in m, when in s); (None, None) when there is
    nothing to touch or no robot was ever known."""
    gap = clearances(trajectories, radius, world)
    finite = np.where(np.isfinite(gap), gap, np.inf)
    if not np.isfinite(finite).any():
        return None, None
    k, _ = np.unravel_index(int(np.argmin(finite)), finite.shape)
    return float(finite.min()), float(np.asarray(t, dtype=float)[k])


def domain_obstacle_overlap(polygons: Sequence[np.ndarray], world: World) -> tuple[float, int]:
    """(largest area of S ∩ obstacles over the samples in m^2, the sample index; -1 if 0)."""
    largest, when = 0.0, -1
    for k, polygon in enumerate(polygons):
        overlap = world.overlap_area(polygon)
        if overlap > largest:
            largest, when = overlap, k
    return largest, when


def polygon_centroid(polygon: np.ndarray) -> np.ndarray:
    """(2,) area centroid of a simple polygon (k, 2) m, either orientation (shoelace); the
    vertex mean of a degenerate one (zero area). Not in covswarm.tvd.geometry, so here."""
    p = np.asarray(polygon, dtype=float).reshape(-1, 2)
    q = np.roll(p, -1, axis=0)
    cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
    twice_area = cross.sum()
    if abs(twice_area) <= 1e-15 * max(1.0, float(np.abs(p).max()) ** 2):
        return p.mean(axis=0)
    return ((p + q) * cross[:, None]).sum(axis=0) / (3.0 * twice_area)


def goal_times(
    t: np.ndarray,
    polygons: Sequence[np.ndarray],
    goals: Sequence[Sequence[float]],
    tolerance: float = GOAL_TOLERANCE,
) -> list[float | None]:
    """When S's centroid reached each goal (s), None for goals not reached.

    goals: [(x, y), ...] m, in the order to visit: goal k counts from the moment goal k - 1
    was reached. Between samples the centroid moves straight (and time runs evenly), so S
    passing a goal between two samples reaches it, at the time of its closest point.
    """
    t = np.asarray(t, dtype=float)
    centres = np.array([polygon_centroid(p) for p in polygons]).reshape(-1, 2)
    targets = np.asarray(goals, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(targets)):
        raise ValueError("goals must be finite (x, y) pairs")
    times: list[float | None] = []
    k = 0  # search from the sample at which the previous goal was reached
    for goal in targets:
        found = None
        if len(centres):
            a = centres[k:]
            seg = np.vstack([centres[k + 1 :], centres[-1:]]) - a  # to the next sample
            length2 = np.einsum("ij,ij->i", seg, seg)
            s = np.clip(
                np.einsum("ij,ij->i", goal - a, seg) / np.where(length2 > 0, length2, 1.0), 0, 1
            )
            miss = np.linalg.norm(a + s[:, None] * seg - goal, axis=1)
            hits = np.flatnonzero(miss <= tolerance)
            if len(hits):
                i = int(hits[0])
                k += i
                later = t[min(k + 1, len(t) - 1)]
                found = float(t[k] + s[i] * (later - t[k]))
        times.append(found)
        if found is None:
            break
    return times + [None] * (len(targets) - len(times))


def world_summary(
    t: np.ndarray,
    trajectories: np.ndarray,
    polygons: Sequence[np.ndarray],
    radius: float,
    world: World,
    goals: Sequence[Sequence[float]] = (),
    ids: Sequence[int] | None = None,
) -> dict:
    """summary.json keys: ``obstacle_contacts`` (episodes), ``obstacle_contact_list`` (the
    first LISTED_CONTACTS), ``min_obstacle_clearance`` (m, null with nothing to touch) and
    ``min_obstacle_clearance_t`` (s), ``domain_obstacle_overlap`` (m^2) and its time
    ``domain_obstacle_overlap_t`` (null when 0), ``goals``, ``goals_reached``,
    ``goal_times`` (s, null if not reached) and ``goal_list`` (the goals, [x, y] m).

    t: (T,) s; trajectories: (T, n, 2) m; polygons: T arrays (k, 2), S at each sample;
    radius: the robots' body radius, m; goals: [(x, y), ...] m in order.
    """
    contacts = obstacle_contacts(t, trajectories, radius, world, ids)
    clearance, when = min_obstacle_clearance(t, trajectories, radius, world)
    overlap, k = domain_obstacle_overlap(polygons, world)
    reached = goal_times(t, polygons, goals)
    return {
        "obstacle_contacts": len(contacts),
        "obstacle_contact_list": [
            {
                "robot": c.robot,
                "start": c.start,
                "duration": c.duration,
                "closest": c.closest,
                "what": c.what,
            }
            for c in contacts[:LISTED_CONTACTS]
        ],
        "min_obstacle_clearance": clearance,
        "min_obstacle_clearance_t": when,
        "domain_obstacle_overlap": overlap,
        "domain_obstacle_overlap_t": None if k < 0 else float(np.asarray(t)[k]),
        "goals": len(reached),
        "goals_reached": sum(r is not None for r in reached),
        "goal_times": reached,
        "goal_list": [[float(x), float(y)] for x, y in goals],
    }


def write_domain_csv(path: str | Path, t: np.ndarray, polygons: Sequence[np.ndarray]) -> Path:
    """domain.csv: S's vertices at each recorded instant, one row ``t, vertex, x, y`` per
    vertex (vertex 0..k-1 in S's order), t in s (4 decimals), x, y in m (5 decimals, as
    trajectories.csv). Load it with ``numpy.loadtxt(path, delimiter=",", skiprows=1)``."""
    path = Path(path)
    t = np.asarray(t, dtype=float)
    if len(t) != len(polygons):
        raise ValueError(f"{len(t)} times but {len(polygons)} polygons")
    with path.open("w", newline="", encoding="utf-8") as handle:
        handle.write("t,vertex,x,y\n")
        for when, polygon in zip(t.tolist(), polygons, strict=True):
            vertices = np.asarray(polygon, dtype=float).reshape(-1, 2).tolist()
            handle.write(
                "".join(f"{when:.4f},{j},{x:.5f},{y:.5f}\n" for j, (x, y) in enumerate(vertices))
            )
    return path
