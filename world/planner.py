"""Routes for S through free space: translate with clearance, shrink through doors, grow back.

The planner searches over the centroid c and the scale s of S(c, s) = c + s (P - c_P), the
current polygon P scaled about its centroid, and where that helps over S's orientation too
("Turning" below). Scales run geometrically from 1 down to
s_min = max(sqrt(min_area / area(P)), min_width / width(P)), the least S the team may
take, so the plan never asks for an S the steering would call too small.

Certified grid. The plane is cut into square cells of side h, centred so that P's centroid
is a cell centre. A cell is *free at scale s* when S(p, s) lies in the workspace and meets
no obstacle for every centroid p anywhere in the cell's square, not only at its centre:
obstacles are rasterised conservatively (every cell an obstacle touches is occupied) and
each level's footprint is S's shape grown by a whole cell, {d : (d + [-h, h]^2) meets
s Q}, so occupied cell j blocks cell i when x_j - x_i is in it (a correlation, done by FFT).
Scaling about the centroid nests the S (s < s' gives S(c, s) inside S(c, s')), so a cell
free at s is free at every smaller scale and one number per cell, its *capacity* (the
largest free scale), says it all. Moves between neighbouring free cells (8 directions) at a
scale both allow, and scale changes in place, keep S in free space by construction. The
price is a margin of one to two cells: a way narrower than S plus that is not found at a
cell, so the cell (by default a tenth of the least S's width, CELLS_PER_WIDTH) is halved up
to REFINE times before the planner refuses.

Search. Dijkstra over the cells free at s_min, a step costing its length times
1 + SMALL_COST (1 - s) / (1 - s_min) for the scale s it is taken at (the smaller of the two
capacities): S keeps its size where it can, and no path is longer than (1 + SMALL_COST)
times the shortest (on the grid). Along the path S takes the largest scale that is within
every cell's capacity and changes by at most 1 / (S's radius) per metre (the vertices move
no faster than the centroid to shrink), so it shrinks gradually ahead of a door and grows
after it, shrinking in place before a step into a narrower cell and growing after one
into a wider (so every step is certified).

Shortcuts and verification. Runs of that path are replaced by straight segments (centroid
and scale both linear in the progress) where the grid allows them, and the path of the
resulting :class:`~covswarm.world.route.RouteMotion` is verified end to end with
covswarm.world.sweep.first_contact (a shortcut that touches is split at the middle of the
run it replaced, and verified again); a route that fails verification is never returned.
S stops (zero velocity and acceleration) at every waypoint: the route's segments are
chained quintics.

Turning. When no way keeping S's orientation lets it stay above ROTATE_BELOW of its size
(the largest scale at which the fixed grid joins S to the goal), or there is none, the
same grid is certified for S turned by k 45 degrees (TURNS_PER_HALF per half turn: 4
orientations for a centrally symmetric S, for which a half turn changes nothing, else 8),
and for the set S sweeps turning from one to the next about its centroid: the convex hull
of _TURN_SAMPLES + 1 turned copies pushed out by 1 / cos(half the angle between them),
which holds every arc a vertex describes (so the sweep is certified, not sampled), and
which nests under scaling like S. The search first finds the largest scale at which any
way joins S to the goal (bisection over the levels; labels of each orientation's free
cells joined where a turn is free), then runs Dijkstra over the cells free at that scale
in every orientation, a turn in place between neighbouring orientations costing
ROTATE_COST times the farthest vertex's arc, so S turns only where it needs to. The
route ends as S was (orientation 0) and is used when S stays larger along it than along
the fixed-orientation route. Turns are in place (shortcuts join turns in one place, never
a turn with a move) and verified, like every segment, with first_contact on the actual
turning motion (RouteMotion's turns: angle, scale and centroid on one quintic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import fft, ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import ConvexHull

from covswarm.tvd.geometry import area, validate_convex
from covswarm.world.model import World
from covswarm.world.route import Leg, RouteMotion, centroid, merge_coincident, width
from covswarm.world.sweep import first_contact

# Least ratio between consecutive scale levels (geometric ladder from 1 to s_min).
LEVEL_RATIO = 0.85
# Extra cost per metre of a step taken at the smallest scale (module docstring, "Search").
SMALL_COST = 0.1
# Default grid: a tenth of the smallest allowed S's width, but no more than MAX_CELLS cells.
CELLS_PER_WIDTH = 10
MAX_CELLS = 250_000
MIN_CELL = 0.01  # m: never finer
# Times the cell is halved when no route is found (the grid's conservative margin is a cell
# or two: a way tighter than that needs a finer grid before the planner refuses).
REFINE = 2
# m: the grid keeps S this far from obstacles and walls, above first_contact's tolerance, so
# a certified step is never a touch.
CLEARANCE = 1e-3
# Instants first_contact samples for a route's swept box (its speed bound is exact).
_SWEEP_SAMPLES = 16
# Samples per cell along a shortcut checked on the grid.
_SHORTCUT_SAMPLES = 4
# S turns (module docstring, "Turning") when no way keeping its orientation lets it stay
# larger than ROTATE_BELOW of its size, or there is no such way at all; by steps of 180 degrees /
# TURNS_PER_HALF, a step in place costing ROTATE_COST times the farthest vertex's arc (m).
ROTATE_BELOW = 0.5
TURNS_PER_HALF = 4
ROTATE_COST = 1.0
_TURN_SAMPLES = 8  # orientations per turning step whose hull bounds its sweep
State = tuple[np.ndarray, float, float]  # centroid (2,) m, scale, angle rad
NOPATH_CODES = (
    "outside-workspace",  # the goal (or S there) leaves the workspace
    "goal-blocked",  # S at the goal would overlap an obstacle
    "start-blocked",  # S already touches an obstacle
    "enclosed",  # no opening at all joins the start and the goal
    "too-narrow",  # every way is narrower than the least S the team can take
    "too-small",  # the goal polygon is below the team's least area or width
    "unverified",  # the grid's route failed the exact check (a planner fault)
)


class NoPath(ValueError):
    """No route: ``code`` (one of NOPATH_CODES) and why, in words."""

    def __init__(self, code: str, why: str) -> None:
        super().__init__(f"{code}: {why}")
        self.code = code
        self.why = why


@dataclass(frozen=True)
class Waypoint:
    """S = centroid + scale R(angle) (P - c_P) at a stop of the route (centroid (2,), m;
    angle, rad CCW, S turned about its centroid); a route to a goal polygon of its own
    shape ends by taking that shape at the last stop."""

    centroid: tuple[float, float]
    scale: float
    angle: float = 0.0


@dataclass(frozen=True, eq=False)
class Route:
    """A planned route: its stops, the motion (exact vertex velocities), duration (s, from
    the motion's t0 to the last arrival and hold) and length (m, of the centroid's path)."""

    waypoints: tuple[Waypoint, ...]
    motion: RouteMotion
    duration: float
    length: float
    resolution: float  # m, the grid it was planned on (a tour: its legs' coarsest)


@dataclass(frozen=True, eq=False)
class _Grid:
    """Cells of side h; cell (i, j) is centred at origin + h (i, j). cap: (layers, nx, ny)
    int, the index in ``scales`` of the largest scale free there, -1 where none is; layer 0
    is S as it is, and when S may turn (by steps of ``turn`` rad) layer o < n is S turned
    by o turn and layer n + o the sweep from o turn to (o + 1) turn (n orientations)."""

    origin: np.ndarray
    h: float
    scales: np.ndarray
    cap: np.ndarray
    open: np.ndarray  # (nx, ny) bool: cells no obstacle meets (where a point could go)
    turn: float = 0.0

    @property
    def orientations(self) -> int:
        return max(len(self.cap) // 2, 1)

    def layer(self, angle: float) -> int:
        """The orientation layer of S turned by ``angle`` rad (a multiple of turn)."""
        return 0 if self.turn == 0.0 else round(angle / self.turn) % self.orientations

    def cell(self, point: np.ndarray) -> tuple[int, int]:
        i, j = np.rint((np.asarray(point) - self.origin) / self.h).astype(int)
        return int(i), int(j)

    def centre(self, cell: tuple[int, int]) -> np.ndarray:
        return self.origin + self.h * np.array(cell, dtype=float)

    def capacity(self, cells: np.ndarray, layer: int) -> np.ndarray:
        """Largest free scale (0 where blocked or off the grid) of cells (n, 2) int."""
        _, nx, ny = self.cap.shape
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < nx) & (cells[:, 1] >= 0) & (cells[:, 1] < ny)
        out = np.zeros(len(cells))
        c = cells[inside]
        level = self.cap[layer, c[:, 0], c[:, 1]]
        out[inside] = np.where(level >= 0, self.scales[np.maximum(level, 0)], 0.0)
        return out


def plan_route(
    world: World,
    polygon: np.ndarray,
    goal: tuple[float, float] | np.ndarray,
    *,
    goal_polygon: np.ndarray | None = None,
    min_area: float,
    min_width: float,
    max_speed: float,
    t0: float = 0.0,
    hold: float = 0.0,
    resolution: float | None = None,
    rotate: bool = True,
) -> Route:
    """A route for S from ``polygon`` (k, 2, convex, m) to the goal, or NoPath.

    goal: where S's centroid ends (m). goal_polygon: S's shape there (translated so that
    its centroid is the goal); default ``polygon``'s own shape and size. min_area (m^2),
    min_width (m): the least S the team can take (the steering's too-small area; a robot
    body's width with its clearance). max_speed: fastest vertex (m/s). t0: mission time the
    motion starts (s); hold: s to rest at the goal. resolution: grid cell (m), default from
    S's size (CELLS_PER_WIDTH). rotate: whether S may turn where that lets it stay larger
    (module docstring, "Turning"). Raises ValueError for malformed input.
    """
    start = validate_convex(polygon)
    target = np.asarray(goal, dtype=float).reshape(-1)
    if target.shape != (2,) or not np.all(np.isfinite(target)):
        raise ValueError(f"goal must be a finite point [x, y], got {goal!r}")
    for name, value in (("min_area", min_area), ("min_width", min_width)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    if not (math.isfinite(max_speed) and max_speed > 0.0):
        raise ValueError(f"max_speed must be positive, got {max_speed!r}")
    c0 = centroid(start)
    shape = start - c0  # Q: S(c, s) = c + s Q
    s_min = max(math.sqrt(min_area / area(start)), min_width / width(start))
    # An S already at or below the limit may keep its size but not shrink.
    scales = _levels(min(s_min, 1.0))
    touched = world.contact(start)  # the start first: a goal said blocked hid it
    if touched == "workspace":
        raise NoPath("start-blocked", f"S already leaves {world.describe(touched)}")
    if touched is not None:
        raise NoPath("start-blocked", f"S already touches {world.describe(touched)}")
    final = _goal_polygon(world, shape, target, goal_polygon, min_area, min_width)
    if resolution is not None and not (math.isfinite(resolution) and resolution > 0.0):
        raise ValueError(f"resolution must be positive, got {resolution!r}")
    tries = [resolution] if resolution is not None else _cells(world, start, final, scales)
    rate = 1.0 / float(np.linalg.norm(shape, axis=1).max())
    turn = math.pi / TURNS_PER_HALF  # S turns where that lets it stay larger
    period = math.pi if _symmetric(shape) else 2.0 * math.pi
    best = refusal = None
    # Each grid in turn: S keeping its orientation, then turning if that found no way or
    # none keeping S above ROTATE_BELOW (before a finer grid: a turn may spare it).
    for h in tries:
        fixed = None
        try:
            fixed = _plan_at(world, shape, c0, target, final, scales, h, rate, turn=None)
        except NoPath as exc:  # a finer grid may find one (an opening under a cell)
            refusal = exc
        best = fixed
        narrow = fixed is None and refusal is not None and refusal.code == "too-narrow"
        if rotate and (narrow or (fixed is not None and fixed[2] < ROTATE_BELOW)):
            try:
                turning = _plan_at(world, shape, c0, target, final, scales, h, rate, turn, period)
                least = min(scale for _, scale, _ in turning[0])
                if fixed is None or least > min(scale for _, scale, _ in fixed[0]) + 1e-9:
                    best = turning
            except NoPath:
                pass
        if best is not None:
            break
    if best is None:
        assert refusal is not None
        if rotate and refusal.code == "too-narrow":
            raise NoPath(refusal.code, f"{refusal.why}; turning S opens none either")
        raise refusal
    states, grid, _ = best
    polygons, turns, kept, length = _shortcut(world, grid, shape, states, final)
    holds = [0.0] * (len(polygons) - 1) + [hold]
    # The path verified above.
    motion = RouteMotion.timed(polygons, max_speed, holds, t0, turns=turns)
    waypoints = [
        Waypoint((float(c[0]), float(c[1])), float(s), float(a))
        for c, s, a in (states[k] for k in kept)
    ]
    if goal_polygon is None and waypoints[-1].scale != 1.0:  # grown back at the goal
        waypoints.append(Waypoint(waypoints[-1].centroid, 1.0, waypoints[-1].angle))
    elif goal_polygon is not None:  # the given polygon: its size relative to S at the start
        waypoints.append(Waypoint(waypoints[-1].centroid, math.sqrt(area(final) / area(start))))
    return Route(tuple(waypoints), motion, motion.end - t0, length, grid.h)


def _plan_at(
    world: World,
    shape: np.ndarray,
    c0: np.ndarray,
    target: np.ndarray,
    final: np.ndarray,
    scales: np.ndarray,
    h: float,
    rate: float,
    turn: float | None,
    period: float = 2.0 * math.pi,
) -> tuple[list[State], _Grid, float]:
    """The grid path's states on a grid of cell h (m): S keeping its orientation (turn None)
    or turning by steps of ``turn`` rad (orientations k turn, k < period / turn), the grid
    and the largest scale at which any way joins S to the goal there. NoPath."""
    if turn is None:
        grid = _certify(world, [shape], c0, final, scales, h)
        level = _bottleneck(grid, c0, target)  # NoPath before a search through it all
        cells = _search(grid, c0, target, len(scales) - 1, 0.0)
    else:
        count = round(period / turn)
        angles = turn * np.arange(count)
        shapes = [shape @ _rotation(a).T for a in angles]
        sweeps = [_turn_hull(shape, a, turn) for a in angles]
        grid = replace(_certify(world, shapes + sweeps, c0, final, scales, h), turn=turn)
        level = _bottleneck(grid, c0, target)
        radius = float(np.linalg.norm(shape, axis=1).max())
        cells = _search(grid, c0, target, level, ROTATE_COST * radius * turn)
    return _states(grid, cells, c0, target, rate, turn or 0.0), grid, float(scales[level])


def plan_tour(
    world: World,
    polygon: np.ndarray,
    goals: list[tuple[float, float]],
    *,
    min_area: float,
    min_width: float,
    max_speed: float,
    hold: float = 0.0,
    speed: float | None = None,
) -> Route:
    """One route visiting ``goals`` in order from ``polygon`` at t = 0, resting ``hold`` s at
    each, S back to ``polygon``'s shape and size at every goal (plan_route for each leg).
    speed: the scenario file's fastest-vertex speed, recorded for to_toml (defaults to
    max_speed)."""
    if not goals:
        raise ValueError("route: need at least one goal")
    current = validate_convex(polygon)
    polygons: list[np.ndarray] = [current]
    spans: list[float] = []
    holds: list[float] = [0.0]
    turns: list[float] = []
    waypoints: list[Waypoint] = []
    legs: list[Leg] = []  # each goal's figures, as its plan gave them
    length, t, cell = 0.0, 0.0, 0.0
    for k, goal in enumerate(goals):
        try:
            leg = plan_route(
                world, current, goal, min_area=min_area, min_width=min_width,
                max_speed=max_speed, t0=t, hold=hold,
            )  # fmt: skip
        except NoPath as exc:
            if exc.code == "start-blocked":  # S at t = 0, before any goal
                raise NoPath(exc.code, f"at t = 0: {exc.why}") from None
            raise NoPath(exc.code, f"goal {k + 1} {list(goal)}: {exc.why}") from None
        polygons += list(leg.motion.polygons[1:])
        spans += list(leg.motion.spans)
        turns += list(leg.motion.turns)
        holds[-1] += leg.motion.holds[0]
        holds += list(leg.motion.holds[1:])
        waypoints += list(leg.waypoints if not waypoints else leg.waypoints[1:])
        length += leg.length
        end = leg.motion.end
        goal_xy = (float(goal[0]), float(goal[1]))
        legs.append(Leg(goal_xy, len(leg.waypoints), leg.length, end - hold, end))
        cell = max(cell, leg.resolution)
        t = leg.motion.end
        current = leg.motion.polygons[-1]
    motion = RouteMotion(
        tuple(polygons),
        tuple(spans),
        tuple(holds),
        0.0,
        goals=tuple((float(x), float(y)) for x, y in goals),
        speed=max_speed if speed is None else speed,
        hold=hold,
        turns=tuple(turns),
        legs=tuple(legs),
    )
    return Route(tuple(waypoints), motion, motion.end, length, cell)


def _levels(s_min: float) -> np.ndarray:
    """Scales from 1 down to s_min, geometric, consecutive ratio at least LEVEL_RATIO."""
    if s_min >= 1.0:
        return np.array([1.0])
    n = math.ceil(math.log(s_min) / math.log(LEVEL_RATIO))
    return s_min ** (np.arange(n + 1) / n)


def _goal_polygon(
    world: World,
    shape: np.ndarray,
    goal: np.ndarray,
    goal_polygon: np.ndarray | None,
    min_area: float,
    min_width: float,
) -> np.ndarray:
    """S at the goal (k, 2) CCW, or NoPath when it is outside, blocked or too small."""
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = world.workspace
        if not (xmin <= goal[0] <= xmax and ymin <= goal[1] <= ymax):
            raise NoPath(
                "outside-workspace",
                f"the goal {goal.tolist()} is outside the workspace {list(world.workspace)}",
            )
    if goal_polygon is None:
        final = goal + shape
    else:
        given = validate_convex(goal_polygon)
        final = given - centroid(given) + goal
        if area(final) < min_area or width(final) < min_width:
            raise NoPath(
                "too-small",
                f"the goal polygon has {area(final):.3g} m^2 and is {width(final):.3g} m wide; "
                f"the team needs {min_area:.3g} m^2 and {min_width:.3g} m",
            )
    touched = world.contact(final)
    # S's own size at the goal is only the default: a smaller goal polygon may fit there
    hint = "" if goal_polygon is not None else "; a smaller goal polygon may fit"
    if touched == "workspace":
        raise NoPath(
            "outside-workspace", f"S at the goal would leave {world.describe(touched)}{hint}"
        )
    if touched is not None:
        raise NoPath("goal-blocked", f"S at the goal would overlap {world.describe(touched)}{hint}")
    return final


def _cells(world: World, start: np.ndarray, final: np.ndarray, scales: np.ndarray) -> list[float]:
    """Cell sides (m) to try in turn: CELLS_PER_WIDTH across the smallest S, then halved
    REFINE times while no route is found, never finer than _finest."""
    finest = _finest(world, start, final)
    cells = [max(scales[-1] * width(start) / CELLS_PER_WIDTH, finest)]
    while len(cells) <= REFINE and cells[-1] > finest:
        cells.append(max(cells[-1] / 2.0, finest))
    return cells


def _finest(world: World, start: np.ndarray, final: np.ndarray) -> float:
    """The finest cell (m): MIN_CELL, or coarser to stay within MAX_CELLS cells."""
    low, high = _extent(world, start, final)
    return max(MIN_CELL, math.sqrt(float(np.prod(high - low)) / MAX_CELLS))


def _extent(world: World, start: np.ndarray, final: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box the centroids may roam (low (2,), high (2,)): the workspace, or without one
    everything (obstacles, S now and at the goal) padded by S's size to go round it."""
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = world.workspace
        return np.array([xmin, ymin]), np.array([xmax, ymax])
    points = [start, final] + [o.vertices for o in world.obstacles]
    stacked = np.concatenate(points)
    pad = float(np.ptp(start, axis=0).max())
    return stacked.min(axis=0) - pad, stacked.max(axis=0) + pad


def _certify(
    world: World,
    shapes: list[np.ndarray],
    c0: np.ndarray,
    final: np.ndarray,
    scales: np.ndarray,
    h: float,
) -> _Grid:
    """The certified grid (module docstring): each cell's largest free scale for each of
    ``shapes`` (convex CCW about the centroid, m; shapes[0] is S's own Q), one layer each."""
    low, high = _extent(world, c0 + shapes[0], final)
    lo = np.floor((low - c0) / h).astype(int)
    hi = np.ceil((high - c0) / h).astype(int)
    origin = c0 + h * lo
    nx, ny = (hi - lo + 1).tolist()
    # Footprint offsets: every shape at scale 1 grown by a cell, in whole cells either side.
    extent = np.abs(np.concatenate(shapes)).max(axis=0)
    reach = np.ceil(extent / h).astype(int) + 1
    ax, ay = reach.tolist()
    occupied = _rasterise(world, origin - h * reach, h, (nx + 2 * ax, ny + 2 * ay))
    size = (fft.next_fast_len(nx + 4 * ax, real=True), fft.next_fast_len(ny + 4 * ay, real=True))
    occupied_hat = fft.rfft2(occupied, s=size)
    du, dv = np.meshgrid(np.arange(-ax, ax + 1), np.arange(-ay, ay + 1), indexing="ij")
    offsets = h * np.stack([du.ravel(), dv.ravel()], axis=1)
    xs = origin[0] + h * np.arange(nx)
    ys = origin[1] + h * np.arange(ny)
    caps = []
    for shape in shapes:
        free_count = np.zeros((nx, ny), dtype=int)
        for s in scales:
            footprint = _meets_squares(s * shape, offsets, h + CLEARANCE).reshape(
                2 * ax + 1, 2 * ay + 1
            )
            # blocked[i] = OR_d occupied[i + d] footprint[d]: a convolution with the flipped
            # footprint, its "valid" part.
            kernel = footprint[::-1, ::-1].astype(float)
            full = fft.irfft2(occupied_hat * fft.rfft2(kernel, s=size), s=size)
            blocked = full[2 * ax : 2 * ax + nx, 2 * ay : 2 * ay + ny] > 0.5
            free = ~blocked
            if world.workspace is not None:
                xmin, xmax, ymin, ymax = world.workspace
                qlow, qhigh = s * shape.min(axis=0), s * shape.max(axis=0)
                half = 0.5 * h + CLEARANCE
                fx = (xs - half + qlow[0] >= xmin) & (xs + half + qhigh[0] <= xmax)
                fy = (ys - half + qlow[1] >= ymin) & (ys + half + qhigh[1] <= ymax)
                free &= fx[:, None] & fy[None, :]
            free_count += free
        caps.append(np.where(free_count > 0, len(scales) - free_count, -1))
    cap = np.stack(caps)
    cap[(0, *(-lo))] = 0  # S's own cell: S(c0, 1) is free (checked exactly), the route's start
    # Where a point could be: no obstacle in the cell, its centre in the workspace.
    open_ = occupied[ax : ax + nx, ay : ay + ny] == 0.0
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = world.workspace
        open_ &= ((xs >= xmin) & (xs <= xmax))[:, None] & ((ys >= ymin) & (ys <= ymax))[None, :]
    return _Grid(origin, h, scales, cap, open_)


def _rotation(angle: float) -> np.ndarray:
    """(2, 2) the rotation by ``angle`` rad, CCW."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def _symmetric(shape: np.ndarray) -> bool:
    """Whether Q (k, 2, about its centroid) is centrally symmetric (Q = -Q: a half turn
    leaves S as it is, so orientations need only cover half a turn)."""
    ours = shape[np.lexsort(shape.T[::-1])]
    flipped = -shape
    flipped = flipped[np.lexsort(flipped.T[::-1])]
    return bool(np.allclose(ours, flipped, rtol=0.0, atol=1e-9 * np.abs(shape).max()))


def _turn_hull(shape: np.ndarray, angle: float, turn: float) -> np.ndarray:
    """(m, 2) CCW: a convex polygon holding every R(a) Q for a in [angle, angle + turn], the
    set S sweeps turning about its centroid (module docstring, "Turning")."""
    count = _TURN_SAMPLES
    step = turn / count
    # A point at radius r turning by ``step`` stays in the triangle of the centroid and its
    # two end positions pushed out to r / cos(step / 2); Q holds the centroid.
    points = np.concatenate(
        [shape @ _rotation(angle + k * step).T for k in range(count + 1)]
    ) / math.cos(0.5 * step)
    return points[ConvexHull(points).vertices]


def _meets_squares(polygon: np.ndarray, centres: np.ndarray, half: float) -> np.ndarray:
    """(n,) bool: whether the square of half-side ``half`` about each of ``centres`` (n, 2)
    meets the convex CCW ``polygon`` (closed sets: touching counts). Separating axes: the
    two coordinate axes and the polygon's edge normals."""
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    meets = np.all((centres + half >= low) & (centres - half <= high), axis=1)
    edges = np.roll(polygon, -1, axis=0) - polygon
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)  # outward for CCW
    reach = half * np.abs(normals).sum(axis=1)  # the square's support along each normal
    offset = np.einsum("kj,kj->k", normals, polygon)
    return meets & np.all(centres @ normals.T - reach <= offset, axis=1)


def _rasterise(world: World, origin: np.ndarray, h: float, shape: tuple[int, int]) -> np.ndarray:
    """(nx, ny) float 0/1: the cells (centred at origin + h (i, j)) that an obstacle meets."""
    out = np.zeros(shape)
    for obstacle in world.obstacles:
        v = obstacle.vertices
        lo = np.maximum(np.floor((v.min(axis=0) - origin) / h - 0.5).astype(int), 0)
        hi = np.minimum(
            np.ceil((v.max(axis=0) - origin) / h + 0.5).astype(int), np.array(shape) - 1
        )
        if np.any(hi < lo):
            continue
        ii, jj = np.meshgrid(
            np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij"
        )
        centres = origin + h * np.stack([ii.ravel(), jj.ravel()], axis=1)
        hit = _meets_squares(v, centres, 0.5 * h)
        out[ii.ravel()[hit], jj.ravel()[hit]] = 1.0
    return out


def _bottleneck(grid: _Grid, c0: np.ndarray, goal: np.ndarray) -> int:
    """The least level index (largest scale) at which S, turning where it must (if the grid
    has turning layers), joins its cell to the goal's through cells and turns free at that
    scale (bisection: a way free at one scale is free at every smaller one); NoPath when
    none does."""
    start, end = grid.cell(c0), grid.cell(goal)
    _, nx, ny = grid.cap.shape
    if not (0 <= end[0] < nx and 0 <= end[1] < ny):
        _refuse(grid, start, end, "")
    n = grid.orientations
    eight = np.ones((3, 3), dtype=bool)

    def joined(level: int) -> bool:
        free = (grid.cap >= 0) & (grid.cap <= level)
        labels, offset = np.zeros((n, nx, ny), dtype=int), 0
        for o in range(n):
            labels[o], count = ndimage.label(free[o], structure=eight)
            labels[o][free[o]] += offset
            offset += count
        rows, cols = [np.zeros(0, dtype=int)], [np.zeros(0, dtype=int)]
        for o in range(n if len(grid.cap) > 1 else 0):  # none without turns
            turns = free[o] & free[(o + 1) % n] & free[n + o]
            rows.append(labels[o][turns])
            cols.append(labels[(o + 1) % n][turns])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(offset + 1, offset + 1))
        _, component = connected_components(graph, directed=False)
        a, b = labels[(0, *start)], labels[(0, *end)]
        return a > 0 and b > 0 and component[a] == component[b]

    low, high = 0, len(grid.scales) - 1
    if not joined(high):
        _refuse(grid, start, end, "")
    while low < high:
        middle = (low + high) // 2
        if joined(middle):
            high = middle
        else:
            low = middle + 1
    return high


def _search(
    grid: _Grid, c0: np.ndarray, goal: np.ndarray, level: int, turn_cost: float
) -> list[tuple[int, int, int]]:
    """The cheapest chain of (orientation, i, j) from S's cell to the goal's, both as S is
    (orientation 0), through cells free at scale index ``level`` (module docstring,
    "Search"; a turn in place costs ``turn_cost``, m), or NoPath saying whether no opening
    or only too narrow ones join them."""
    n = grid.orientations
    start, end = grid.cell(c0), grid.cell(goal)
    _, nx, ny = grid.cap.shape
    if not (0 <= end[0] < nx and 0 <= end[1] < ny) or not 0 <= grid.cap[(0, *end)] <= level:
        _refuse(grid, start, end, "S at the goal is hemmed in closer than the grid can certify")
    cap = grid.cap[:n]
    free = (cap >= 0) & (cap <= level)
    index = -np.ones(cap.shape, dtype=int)
    index[free] = np.arange(int(free.sum()))
    scale = np.where(free, grid.scales[np.maximum(cap, 0)], 0.0)
    s_min = grid.scales[-1]
    rows, cols, costs = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = (slice(None), slice(0, nx - di), slice(max(-dj, 0), ny - max(dj, 0)))
        b = (slice(None), slice(di, nx), slice(max(dj, 0), ny - max(-dj, 0)))
        both = free[a] & free[b]
        step = grid.h * math.hypot(di, dj)
        s = np.minimum(scale[a], scale[b])[both]
        small = (1.0 - s) / (1.0 - s_min) if s_min < 1.0 else 0.0 * s
        rows.append(index[a][both])
        cols.append(index[b][both])
        costs.append(step * (1.0 + SMALL_COST * small))
    if n > 1:  # turns in place, where the sweep is free too
        sweep = grid.cap[n:]
        for o in range(n):
            turns = free[o] & free[(o + 1) % n] & (sweep[o] >= 0) & (sweep[o] <= level)
            rows.append(index[o][turns])
            cols.append(index[(o + 1) % n][turns])
            costs.append(np.full(int(turns.sum()), turn_cost))
    count = int(free.sum())
    graph = coo_matrix(
        (np.concatenate(costs), (np.concatenate(rows), np.concatenate(cols))),
        shape=(count, count),
    ).tocsr()
    first, last = index[(0, *start)], index[(0, *end)]
    _, previous = dijkstra(graph, directed=False, indices=first, return_predecessors=True)
    if last != first and previous[last] < 0:
        _refuse(grid, start, end, "")
    flat = np.argwhere(free)
    chain = [last]
    while chain[-1] != first:
        chain.append(previous[chain[-1]])
    return [tuple(flat[k].tolist()) for k in reversed(chain)]


def _refuse(grid: _Grid, start: tuple[int, int], end: tuple[int, int], why: str) -> None:
    """NoPath: "enclosed" when even a point could not get from S's cell to the goal's
    through cells no obstacle meets, else "too-narrow" (a way exists, too narrow for S);
    ``why``: what else to say (may be empty)."""
    nx, ny = grid.open.shape
    if not (0 <= end[0] < nx and 0 <= end[1] < ny):
        raise NoPath("outside-workspace", "the goal is off the planning grid")
    labels, _ = ndimage.label(grid.open, structure=np.ones((3, 3), dtype=bool))
    if labels[start] == 0 or labels[start] != labels[end]:
        raise NoPath("enclosed", "the goal is enclosed: no opening joins it to S")
    raise NoPath(
        "too-narrow",
        why
        or "every way to the goal is narrower than the team can pass: S would have to "
        f"shrink below its least size (scale {grid.scales[-1]:.3g} of S now, the team's "
        f"least area or a robot's width with its clearance; grid {grid.h:.3g} m)",
    )


def _states(
    grid: _Grid,
    cells: list[tuple[int, int, int]],
    c0: np.ndarray,
    goal: np.ndarray,
    rate: float,
    turn: float,
) -> list[State]:
    """The grid path as (centroid (2,), scale, angle) states, then on to the goal itself
    (inside the goal cell's square, so at the same scale).

    Scale profile: the largest s_k <= each cell's capacity that changes by at most ``rate``
    per metre of path (1 / the farthest vertex's distance from the centroid: the vertices
    move no faster than the centroid to shrink), so S shrinks gradually ahead of a door and
    grows after it; two passes of a 1-D distance transform. Between cells S shrinks in
    place before a step and grows after it, so each step is taken at a scale both cells
    allow (certified); a turn (by ``turn`` rad, in place) is taken at a scale its sweep
    allows too."""
    n = grid.orientations
    centres = [c0] + [grid.centre(c[1:]) for c in cells[1:]]
    caps = np.array([grid.scales[grid.cap[c]] for c in cells])
    steps = [float(np.linalg.norm(b - a)) for a, b in zip(centres[:-1], centres[1:], strict=True)]
    profile = caps.copy()
    for k in range(1, len(profile)):
        profile[k] = min(profile[k], profile[k - 1] + rate * steps[k - 1])
    for k in range(len(profile) - 2, -1, -1):
        profile[k] = min(profile[k], profile[k + 1] + rate * steps[k])
    states: list[State] = [(c0.copy(), 1.0, 0.0)]
    if profile[0] < 1.0:
        states.append((c0.copy(), float(profile[0]), 0.0))
    angle = 0.0
    for k in range(len(cells) - 1):
        here, there = float(profile[k]), float(profile[k + 1])
        move, delta = min(here, there), 0.0
        (o, i, j), (p, _, _) = cells[k], cells[k + 1]
        if p != o:  # a turn in place, forward (o -> o + 1) or back
            sweep = n + (o if p == (o + 1) % n else p)
            move = min(move, float(grid.scales[grid.cap[sweep, i, j]]))
            delta = turn if p == (o + 1) % n else -turn
        if move < here:  # shrink in place, then step (or turn)
            states.append((centres[k], move, angle))
        angle += delta
        states.append((centres[k + 1], move, angle))
        if there > move:  # step, then grow in place
            states.append((centres[k + 1], there, angle))
    if np.any(states[-1][0] != goal):
        states.append((goal.copy(), states[-1][1], angle))
    return states


def _segment_fits(grid: _Grid, states: list[State], i: int, j: int) -> bool:
    """Whether S may go straight from state i to state j: at one orientation, the segment
    (centroid and scale linear) within the cells' capacities at _SHORTCUT_SAMPLES samples
    per cell crossed; or turning in place through states i..j all at one centroid and
    scale (each turn certified at that scale)."""
    (ca, sa, aa), (cb, sb, ab) = states[i], states[j]
    if aa != ab:
        return all(np.array_equal(c, ca) and scale == sa for c, scale, _ in states[i : j + 1])
    count = int(math.ceil(float(np.linalg.norm(cb - ca)) / grid.h * _SHORTCUT_SAMPLES)) + 2
    tau = np.linspace(0.0, 1.0, count)
    points = ca + tau[:, None] * (cb - ca)
    scales = sa + tau * (sb - sa)
    cells = np.rint((points - grid.origin) / grid.h).astype(int)
    return bool(np.all(grid.capacity(cells, grid.layer(aa)) >= scales - 1e-12))


def _shortcut(
    world: World,
    grid: _Grid,
    shape: np.ndarray,
    states: list[State],
    final: np.ndarray,
) -> tuple[list[np.ndarray], list[float], list[int], float]:
    """Straight segments over runs of ``states`` (greedy: the furthest state the grid
    allows, by doubling then bisection; then stops whose neighbours see each other are
    dropped), each verified with first_contact; a failed one
    is split at the middle state of the run it replaced. Returns the route's polygons
    (the kept states' S, then ``final``), the turns between them (rad), the kept state
    indices and the centroid path length (m)."""
    last = len(states) - 1
    kept = [0]
    while kept[-1] < last:
        i = kept[-1]
        good, step = i + 1, 1
        while good + step <= last and _segment_fits(grid, states, i, good + step):
            good += step
            step *= 2
        low, high = good, min(good + step, last + 1)
        while high - low > 1:
            middle = (low + high) // 2
            if _segment_fits(grid, states, i, middle):
                low = middle
            else:
                high = middle
        kept.append(low)
    # The greedy pass keeps a stop wherever the farthest reachable state happened to be;
    # drop every stop whose neighbours see each other (S stops at each one).
    k = 1
    while k < len(kept) - 1:
        if _segment_fits(grid, states, kept[k - 1], kept[k + 1]):
            del kept[k]
            k = max(k - 1, 1)
        else:
            k += 1

    def polygon(k: int) -> np.ndarray:
        centre, scale, angle = states[k]
        return centre + scale * shape @ _rotation(angle).T

    # Verify the whole route; a segment that touches is split at the middle state of the
    # run it replaced (a single grid step is certified: touching there is a fault).
    while True:
        stops = [(k, polygon(k), states[k][2]) for k in kept] + [(None, final, states[-1][2])]
        stops = [stops[0]] + [
            (k, p, a) for (_, q, b), (k, p, a) in zip(stops[:-1], stops[1:], strict=True)
            if a != b or len(p) != len(q) or not np.allclose(p, q, rtol=0.0, atol=1e-12)
        ]  # fmt: skip
        polygons = [p for _, p, _ in stops]
        turns = [b - a for (_, _, a), (_, _, b) in zip(stops[:-1], stops[1:], strict=True)]
        if len(polygons) == 1:
            break
        contact = _first_contact(polygons, turns, world)
        if contact is None:
            break
        segment, touched = contact
        a, b = stops[segment][0], stops[segment + 1][0]
        if b is None:
            raise NoPath(
                "goal-blocked",
                f"S cannot take the goal polygon there: it would touch {world.describe(touched)}",
            )
        if b == a + 1:
            raise NoPath(
                "unverified", f"the grid's step {a} -> {b} touches {world.describe(touched)}"
            )
        kept.insert(kept.index(b), (a + b) // 2)
    length = sum(
        float(np.linalg.norm(states[b][0] - states[a][0]))
        for a, b in zip(kept[:-1], kept[1:], strict=True)
    )
    return polygons, turns, kept, length


def _first_contact(
    polygons: list[np.ndarray], turns: list[float], world: World
) -> tuple[int, str] | None:
    """The first segment of the route through ``polygons`` (turning by ``turns``, rad) along
    which S touches something, and what it touches; None when S stays clear
    (covswarm.world.sweep.first_contact).

    It checks the route's path rather than its timing: the same polygons swept with each
    segment's progress linear in time at a rate that keeps every vertex within unit speed
    (RouteMotion.reach: exact without a turn, a bound with one), so the speed bound holds
    everywhere instead of at the quintic's peak: the same set of S, found in fewer steps.
    """
    path = RouteMotion.timed(polygons, 1.0, turns=turns)
    lengths = np.array([path.reach(i) for i in range(len(path.spans))])  # m per segment
    starts = np.concatenate([[0.0], np.cumsum(lengths)])

    def along(t: float) -> tuple[np.ndarray, np.ndarray]:
        i = min(int(np.searchsorted(starts, t, side="right")) - 1, len(lengths) - 1)
        u = min(max((t - starts[i]) / lengths[i], 0.0), 1.0)
        vertices, rate = path.along(i, u)
        velocities = rate / lengths[i]
        if len(vertices) == len(path.polygons[i]) == len(path.polygons[i + 1]):
            return vertices, velocities  # paired vertex for vertex: none coincide
        return merge_coincident(vertices, velocities)

    contact = first_contact(along, 0.0, float(starts[-1]), world, speed=1.0, samples=_SWEEP_SAMPLES)
    if contact is None:
        return None
    segment = min(int(np.searchsorted(starts, contact.time, side="right")) - 1, len(lengths) - 1)
    return segment, contact.obstacle
