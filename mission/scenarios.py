"""Missions: how the covered subdomain S(t) moves, and where the robots start.

A :class:`Scenario` knows its domain motion exactly (covswarm.mission.motion). Built-in
scenarios are ``circle`` (paper Section 5), ``passage`` (paper Section 6) and
``formation``; others are read from TOML files (covswarm.mission.scenario_files).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from covswarm.mission.motion import DensityPath, DomainMotion, Keyframes, Rigid
from covswarm.mission.toml_text import toml_float, toml_list, toml_points, toml_str
from covswarm.tvd.coverage import signed_area
from covswarm.tvd.density import Density
from covswarm.world.maps import OccupancyMap
from covswarm.world.model import World, box_vertices
from covswarm.world.route import RouteMotion
from covswarm.world.sweep import SAMPLES, first_contact

Box = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax

MAX_AGENTS = 100_000
MAX_DURATION = 86_400.0  # s: a day; S's path is checked against the world over all of it
CONTACT_TOLERANCE = 1e-4  # m: S within this of an obstacle touches it (world.sweep)
SETTLE = 10.0  # s a planned route's mission lasts past its end, for the team to settle


@dataclass(frozen=True, eq=False)
class Scenario:
    """A mission: the moving domain, default run parameters and the world it moves in.

    ``world`` (covswarm.world.model.World): the workspace and every obstacle (boxes, convex
    polygons, a map's pieces). Without it, the world is built from ``workspace`` and the
    boxes ``obstacles``; with it, ``workspace`` is the world's and ``obstacles`` becomes the
    world's axis-aligned boxes (plots and recordings draw every obstacle of ``world``).
    S(t) must stay clear of the obstacles and inside the workspace over [0, duration]
    (refused otherwise).
    """

    name: str
    motion: DomainMotion
    agents: int = 10
    kappa: float = 2.0
    duration: float = 40.0
    dt: float = 0.02
    dynamics: str = "single"
    workspace: Box | None = None
    obstacles: tuple[Box, ...] = ()
    initial_box: Box | None = None  # None: uniform inside S(0)
    robot_diameter: float = 0.14  # m, the robots' bodies (Khepera IV): starts and metrics
    density_path: DensityPath | None = None  # None: uniform density
    world: World | None = None  # None: built from workspace and obstacles
    # The occupancy map the world's pieces came from (a scenario file's ``map``), kept for
    # its picture (covswarm.world.map_image, drawn by the console); None: no map.
    map: OccupancyMap | None = None

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise ValueError("scenario: name must be a non-empty string")
        if self.dynamics not in ("single", "unicycle"):
            raise ValueError(
                f"scenario: dynamics must be single or unicycle, not {self.dynamics!r}"
            )
        agents = self.agents
        if isinstance(agents, bool) or not (isinstance(agents, int) and 1 <= agents <= MAX_AGENTS):
            raise ValueError(
                f"scenario: agents must be an integer from 1 to {MAX_AGENTS}, not {agents!r}"
            )
        for key in ("kappa", "duration", "dt", "robot_diameter"):
            value = getattr(self, key)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"scenario: {key} must be a positive number, not {value!r}")
        if self.duration > MAX_DURATION:
            raise ValueError(
                f"scenario: duration must be at most {MAX_DURATION:g} s, not {self.duration!r}"
            )
        if self.dt > self.duration:
            raise ValueError(f"scenario: dt {self.dt!r} s is longer than the duration")
        for box in (self.workspace, self.initial_box, *self.obstacles):
            if box is not None:
                check_box(box)
        self._build_world()
        if self.initial_box is not None:
            _check_start_box(self.initial_box, self.world)
        check_route_duration(self.motion, self.duration)
        check_motion(self.motion, self.duration)
        _check_clear(self.motion, self.duration, self.world)
        if self.density_path is not None:
            for t in self.motion.sample_times(self.duration):
                try:
                    self.density_path(float(t))
                except ValueError as exc:
                    raise ValueError(f"density at t = {t:g} s: {exc}") from None

    def _build_world(self) -> None:
        boxes = tuple(tuple(float(v) for v in box) for box in self.obstacles)
        world = self.world
        if world is None:
            world = World.from_boxes_and_polygons(self.workspace, boxes)
        elif not isinstance(world, World):
            raise ValueError(f"scenario: world must be a World, not {type(world).__name__}")
        elif self.workspace is not None and tuple(self.workspace) != world.workspace:
            raise ValueError("scenario: workspace differs from the world's")
        own = tuple(o.box for o in world.obstacles if o.is_box)
        if self.world is not None and boxes and boxes != own:
            raise ValueError("scenario: give obstacles or a world, not both")
        object.__setattr__(self, "world", world)
        object.__setattr__(self, "workspace", world.workspace)
        object.__setattr__(self, "obstacles", own)

    @property
    def goals(self) -> tuple[tuple[float, float], ...]:
        """Where S's centroid is sent, in order (m): a planned route's goals, else none."""
        return tuple(getattr(self.motion, "goals", ()))

    def density(self, t: float) -> Density | None:
        """phi at time t with its exact rates (covswarm.tvd.density.Density), None when uniform."""
        return None if self.density_path is None else self.density_path(float(t))

    def domain(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """S(t): CCW vertices (k, 2) and their exact velocities d/dt (k, 2)."""
        return self.motion(float(t))

    def initial_positions(self, n: int, seed: int) -> np.ndarray:
        """(n, 2) start positions, uniform at random (deterministic in seed), at least
        :meth:`start_separation` apart: bodies do not start overlapping.

        Drawn as before, then each robot in turn that is too close to one placed before it
        is drawn again from the same stream (random sequential placement), so a layout that
        was already apart is unchanged. The robots placed so far are binned in a grid of
        cells one separation wide, so a draw is checked against the robots of its own and
        the 8 neighbouring cells only: O(n) for n robots instead of O(n^2).
        """
        rng = np.random.default_rng(seed)
        if self.initial_box is not None:
            xmin, xmax, ymin, ymax = self.initial_box

            def draw(k: int) -> np.ndarray:
                return rng.uniform([xmin, ymin], [xmax, ymax], size=(k, 2))

        else:
            in_polygon = _polygon_sampler(self.domain(0.0)[0])

            def draw(k: int) -> np.ndarray:
                return in_polygon(k, rng)

        positions = draw(n)
        separation = self.start_separation(n)
        placed = _Placed(positions, separation)
        for i in range(n):
            for _ in range(START_ATTEMPTS):
                if placed.clear(positions[i]):
                    break
                positions[i] = draw(1)[0]
            else:
                raise ValueError(
                    f"scenario {self.name}: cannot place {n} robots {separation:g} m apart"
                )
            placed.add(i)
        return positions

    def start_separation(self, n: int) -> float:
        """Smallest distance between two start positions of a team of ``n``, m: one body
        diameter, unless the start area is too small for n bodies at a random-placement
        packing of START_PACKING (then the largest that fits: the 1000-robot circle of point
        robots, say, in its 2 m square)."""
        if self.initial_box is not None:
            xmin, xmax, ymin, ymax = self.initial_box
            area = (xmax - xmin) * (ymax - ymin)
        else:
            area = abs(signed_area(self.domain(0.0)[0]))
        fits = 2.0 * math.sqrt(START_PACKING * area / (math.pi * max(n, 1)))
        return min(self.robot_diameter, fits)

    def to_toml(self) -> str:
        """This scenario in the TOML format of the module docstring."""
        lines = [
            f"name = {toml_str(self.name)}",
            f"agents = {self.agents}",
            f"kappa = {toml_float(self.kappa)}",
            f"duration = {toml_float(self.duration)}",
            f"dt = {toml_float(self.dt)}",
            f"dynamics = {toml_str(self.dynamics)}",
        ]
        if self.workspace is not None:
            lines.append(f"workspace = {toml_list(self.workspace)}")
        entries = [
            toml_list(o.box) if o.is_box else toml_points(o.vertices) for o in self.world.obstacles
        ]
        lines.append(f"obstacles = [{', '.join(entries)}]")
        if self.robot_diameter != Scenario.robot_diameter:
            lines.append(f"robot_diameter = {toml_float(self.robot_diameter)}")
        if self.initial_box is not None:
            lines.append(f"\n[initial]\nbox = {toml_list(self.initial_box)}")
        text = "\n".join(lines) + "\n\n" + self.motion.to_toml()
        return text if self.density_path is None else text + self.density_path.to_toml()


# Start positions: draws per robot before giving up, and the share of the start area the
# bodies may cover (random sequential placement jams at 0.547; 0.4 still places quickly).
START_ATTEMPTS = 1000
START_PACKING = 0.4


def check_box(box: Box) -> None:
    """ValueError unless ``box`` is (xmin, xmax, ymin, ymax), finite, xmin < xmax, ymin < ymax."""
    if len(box) != 4:
        raise ValueError(f"box {box!r}: need 4 numbers xmin, xmax, ymin, ymax")
    box_vertices(box)


def route_duration(motion: RouteMotion) -> float:
    """A planned route's mission length when none is given, s: its end (whole seconds, up)
    plus SETTLE."""
    return math.ceil(motion.end) + SETTLE


def route_lines(motion: DomainMotion) -> list[str]:
    """What ``covswarm sim`` and ``covswarm run`` say of a planned route before the mission,
    one line per goal, from the plan itself (RouteMotion.legs, covswarm.world.planner's
    figures; nothing is planned again): the plan's stops (start and goal included), the
    length of S's centroid path, the mission time S arrives, and on the last goal's line the
    mission the route needs (:func:`route_duration`: its end, holds included, plus SETTLE).
    [] for a motion that is no planned tour."""
    legs = getattr(motion, "legs", ())
    lines = []
    for k, leg in enumerate(legs):
        x, y = leg.goal
        line = (
            f"route to goal ({x!r}, {y!r}): {leg.waypoints} waypoints, {leg.length:.1f} m, "
            f"arrives at {leg.arrival:.1f} s"
        )
        if k == len(legs) - 1:
            line += f" (mission {route_duration(motion):g} s)"
        lines.append(line)
    return lines


def check_route_duration(motion: DomainMotion, duration: float, option: str = "duration") -> None:
    """ValueError unless a planned route (world.route.RouteMotion) ends within a mission of
    ``duration`` s, the effective one (a scenario's, or ``covswarm sim/run --duration``,
    named ``option`` in the message): cut short, S stops mid-way and goals go unreached
    without a word. Other motions may be run for any length (S stays put past its end)."""
    if not isinstance(motion, RouteMotion) or motion.end <= duration:
        return
    need = math.ceil(motion.end * 10.0) / 10.0
    raise ValueError(
        f"the route ends at {motion.end:.1f} s, after the mission's {duration:g} s: "
        f"give {option} >= {need:g} or fewer goals"
    )


def _check_start_box(box: Box, world: World) -> None:
    """ValueError unless the start box lies inside the workspace and clear of every obstacle
    (as S must: World.contact within CONTACT_TOLERANCE), naming what it reaches."""
    hit = world.contact(box_vertices(box), tolerance=CONTACT_TOLERANCE)
    if hit is None:
        return
    where = "[" + ", ".join(f"{v:g}" for v in box) + "]"
    what = "leaves " if hit == "workspace" else "touches "
    raise ValueError(
        f"the initial box {where} (where the robots start) {what}{world.describe(hit)}: "
        "move it clear, or drop it to start the robots inside S(0)"
    )


def _check_clear(motion: DomainMotion, duration: float, world: World) -> None:
    """ValueError naming the mission time and the obstacle if S(t) touches an obstacle or
    leaves the workspace for some t in [0, duration] (covswarm.world.sweep)."""
    # With an exact speed bound, a few samples suffice: they only bound the swept box.
    speed = _speed_bound(motion, duration)
    contact = first_contact(
        motion,
        0.0,
        duration,
        world,
        tolerance=CONTACT_TOLERANCE,
        speed=speed,
        samples=64 if speed is not None else SAMPLES,
    )
    if contact is None:
        return
    if contact.obstacle == "workspace":
        raise ValueError(f"the domain S leaves the workspace at t = {contact.time:.3f} s")
    raise ValueError(
        f"the domain S touches {world.describe(contact.obstacle)} at t = {contact.time:.3f} s"
    )


def _speed_bound(motion: DomainMotion, duration: float) -> float | None:
    """A bound (m/s) on every vertex speed of S over [0, duration], exact for the motions of
    covswarm.mission.motion (None: first_contact samples it)."""
    if isinstance(motion, Keyframes):
        if motion.times.size == 1:
            return 0.0
        steps = np.diff(motion.vertices, axis=0)  # (K - 1, k, 2)
        speeds = np.linalg.norm(steps, axis=2) / np.diff(motion.times)[:, None]
        return float(speeds.max())
    if isinstance(motion, Rigid):
        reach = float(np.linalg.norm(motion.polygon, axis=1).max())
        scale = max(abs(1.0 + motion.scale_rate * t) for t in (0.0, duration))
        return (
            float(np.hypot(*motion.velocity))
            + abs(motion.radius * 2.0 * math.pi / motion.period)
            + reach * (abs(motion.scale_rate) + scale * abs(motion.rotation_rate))
        )
    return None


def check_motion(motion: DomainMotion, duration: float) -> None:
    """Raise ValueError unless S(t) is a valid convex polygon at the sampled times of
    [0, ``duration``] s, and a rigid motion's scale stays positive throughout (past 0 the
    polygon is S turned half a turn about its centre, which the samples alone, orientation
    and all, take for a valid one)."""
    from covswarm.tvd.coverage import validate_polygon

    if isinstance(motion, Rigid) and 1.0 + motion.scale_rate * duration <= 0.0:
        raise ValueError(
            f"domain: its scale 1 + scale_rate t reaches 0 at t = {-1.0 / motion.scale_rate:g} s"
            f", within the {duration:g} s mission (scale_rate = {motion.scale_rate:g})"
        )
    for t in motion.sample_times(duration):
        vertices, velocities = motion(float(t))
        try:
            validate_polygon(vertices)
        except ValueError as exc:
            raise ValueError(f"domain at t = {t:g} s: {exc}") from None
        if signed_area(vertices) <= 0.0 or not np.all(np.isfinite(velocities)):
            raise ValueError(f"domain at t = {t:g} s: turned inside out or non-finite velocity")


class _Placed:
    """The robots placed so far by :meth:`Scenario.initial_positions`, binned in square cells
    a little over ``separation`` wide (m), keyed by their integer (column, row).

    A robot two cells or more away in x or y is more than ``separation`` away whatever the
    rounding of the cell index (hence the margin), so :meth:`clear` decides exactly as a
    comparison with every placed robot would, with the same np.hypot on the same numbers.
    """

    MARGIN = 1e-6  # relative: far above the rounding of x / cell

    def __init__(self, positions: np.ndarray, separation: float) -> None:
        self.positions = positions  # (n, 2) m, shared: row i is final once added
        self.separation = separation
        self.cell = separation * (1.0 + self.MARGIN)
        self.cells: dict[tuple[int, int], list[int]] = {}

    def _key(self, point: np.ndarray) -> tuple[int, int]:
        return math.floor(point[0] / self.cell), math.floor(point[1] / self.cell)

    def clear(self, point: np.ndarray) -> bool:
        """Whether ``point`` (2,) m is at least ``separation`` from every placed robot."""
        column, row = self._key(point)
        near = [
            i
            for dc in (-1, 0, 1)
            for dr in (-1, 0, 1)
            for i in self.cells.get((column + dc, row + dr), ())
        ]
        if not near:
            return True
        gaps = np.hypot(*(self.positions[near] - point).T)
        return bool(gaps.min() >= self.separation)

    def add(self, i: int) -> None:
        """Robot ``i`` is placed at ``positions[i]``."""
        self.cells.setdefault(self._key(self.positions[i]), []).append(i)


def _polygon_sampler(polygon: np.ndarray) -> Callable[[int, np.random.Generator], np.ndarray]:
    """``sample(n, rng)``: (n, 2) points uniform in the convex CCW ``polygon`` (k, 2), by
    rejection from its bounding box; its bounds and edges computed once, for the many
    one-point redraws of :meth:`Scenario.initial_positions`."""
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    edges = np.roll(polygon, -1, axis=0) - polygon

    def sample(n: int, rng: np.random.Generator) -> np.ndarray:
        accepted: list[np.ndarray] = []
        count = 0
        while count < n:
            batch = rng.uniform(low, high, size=(2 * n + 8, 2))
            rel = batch[:, None, :] - polygon[None, :, :]
            cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
            inside = batch[(cross > 0.0).all(axis=1)]
            accepted.append(inside)
            count += len(inside)
        return np.concatenate(accepted)[:n]

    return sample


# ---------------------------------------------------------------------------- built-ins


def circle() -> Scenario:
    """Paper Section 5: 100 robots cover a 2 m square whose centre circles counter-clockwise.

    Centre speed 2 pi 1.5 / 50 = 0.19 m/s, well inside a Khepera IV's 0.8 m/s. kappa = 8:
    with kappa = 3 TVD-D1 cannot keep up at this speed (robots at the trailing edge are
    squeezed together and swept out of S, the team stops being a CVT); kappa = 8 keeps it
    one (README, "Reproducing the paper").
    """
    half = 1.0
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    return Scenario(
        name="circle",
        motion=Rigid(polygon=square, radius=1.5, period=50.0),
        agents=100,
        kappa=8.0,
        duration=50.0,
        dt=0.02,
        dynamics="single",
        workspace=(-2.75, 2.75, -2.75, 2.75),
    )


# The paper's arena: 5.182 m x 3.658 m (17 ft x 12 ft), centred on the origin.
_ARENA: Box = (-2.591, 2.591, -1.829, 1.829)
_GAP = 0.45  # half-height of the passage between the two obstacles, m
_OBSTACLES: tuple[Box, ...] = ((-0.3, 0.3, _GAP, _ARENA[3]), (-0.3, 0.3, _ARENA[2], -_GAP))


def _rectangle(xmin: float, xmax: float, ymin: float, ymax: float) -> list[list[float]]:
    return [[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]]


def passage() -> Scenario:
    """Paper Section 6: 10 Khepera IV cross the arena through a gap between two obstacles.

    The rectangle translates right while shrinking to fit the gap, crosses it, then grows
    into the goal box; each side moves with constant velocity within each segment.
    """
    keyframes = [
        (0.0, _rectangle(-2.4, -1.2, -0.8, 0.8)),  # start box
        (5.0, _rectangle(-2.4, -1.2, -0.8, 0.8)),
        (17.0, _rectangle(-1.5, -0.4, -0.3, 0.3)),  # squeezed to the gap's height
        (29.0, _rectangle(0.4, 1.5, -0.3, 0.3)),  # through the passage
        (41.0, _rectangle(1.2, 2.4, -0.8, 0.8)),  # goal box
    ]
    times, vertices = zip(*keyframes, strict=True)
    return Scenario(
        name="passage",
        motion=Keyframes(times=np.array(times), vertices=np.array(vertices)),
        agents=10,
        kappa=2.0,
        duration=45.0,
        dt=0.02,
        dynamics="unicycle",
        workspace=_ARENA,
        obstacles=_OBSTACLES,
    )


def formation() -> Scenario:
    """A square that drifts right and shrinks while a turning bump herds the team to one side.

    The bump (peak 8x the floor, 0.5 m x 0.18 m) starts in the upper half of S, drifts with
    S and slides to its lower half while its long axis turns a quarter turn every 20 s.
    """
    bump = Density(
        floor=1.0,
        means=[[-1.0, 0.5]],
        covariances=[[[0.25, 0.0], [0.0, 0.0324]]],
        weights=[8.0],
        mean_rates=[[0.05, -0.025]],
    )
    return Scenario(
        name="formation",
        motion=Rigid(
            polygon=_rectangle(-1.0, 1.0, -1.0, 1.0),
            center=(-1.0, 0.0),
            velocity=(0.05, 0.0),
            scale_rate=-0.01,
        ),  # fmt: skip
        agents=20,
        kappa=2.0,
        duration=40.0,
        dt=0.02,
        dynamics="single",
        workspace=(-2.5, 2.5, -1.5, 1.5),
        density_path=DensityPath(bump, np.array([math.pi / 40.0])),
    )


def live() -> Scenario:
    """An operator's mission: a still 1.6 m x 0.8 m rectangle in the middle of the passage
    arena (between the obstacles) until someone steers it (coordinator.steering: the
    console, ``covswarm steer`` or a planner); 10 Khepera IV, 30 minutes or Ctrl-C.
    """
    return Scenario(
        name="live",
        motion=Keyframes(
            times=np.array([0.0]), vertices=np.array([_rectangle(-0.8, 0.8, -0.4, 0.4)])
        ),
        agents=10,
        kappa=2.0,
        duration=1800.0,
        dt=0.02,
        dynamics="unicycle",
        workspace=_ARENA,
        obstacles=_OBSTACLES,
    )


def pinwheel() -> Scenario:
    """A pentagon that turns, orbits and shrinks at once: rotation and scaling of S.

    30 Khepera IV. The pentagon (circumradius 1.4 m) turns at 0.15 rad/s about its centre,
    its centre circles 1 m around the origin every 60 s, and it shrinks to 0.6 of its size
    over the 40 s (scale 1 - 0.01 t); its vertices move at up to 0.33 m/s. TVD-D1 lags
    such a domain by 0.11 m, the domain-motion feedforward by under 1 cm (docs/tracking.md).
    """
    angles = 2.0 * math.pi * np.arange(5) / 5
    pentagon = 1.4 * np.column_stack([np.cos(angles), np.sin(angles)])
    return Scenario(
        name="pinwheel",
        motion=Rigid(
            polygon=pentagon, radius=1.0, period=60.0, rotation_rate=0.15, scale_rate=-0.01
        ),
        agents=30,
        kappa=2.0,
        duration=40.0,
        dt=0.02,
        dynamics="unicycle",
        workspace=(-3.0, 3.0, -3.0, 3.0),
    )


# The warehouse: an 8 m x 5 m hall cut by a 0.2 m wall at x = 0 with a 1.1 m door, shelves
# along the walls (boxes xmin, xmax, ymin, ymax, m).
_HALL: Box = (-4.0, 4.0, -2.5, 2.5)
_DOOR = (-0.2, 0.9)  # y extent of the door, m
_WAREHOUSE = {
    "wall south": (-0.1, 0.1, -2.5, _DOOR[0]),
    "wall north": (-0.1, 0.1, _DOOR[1], 2.5),
    "shelf 1": (-3.8, -1.4, 1.7, 2.2),
    "shelf 2": (-3.8, -1.4, -2.3, -1.8),
    "shelf 3": (1.0, 1.4, -2.3, -0.9),
    "shelf 4": (2.2, 3.8, 1.8, 2.3),
    "shelf 5": (2.4, 3.8, -2.3, -1.8),
}


def warehouse(agents: int = 20) -> Scenario:
    """20 Khepera IV (or ``agents``) taken from one room of a warehouse to the other by the
    route planner.

    S, a 2.4 m x 1.6 m rectangle, cannot pass the 1.1 m door: the planner
    (covswarm.world.planner) shrinks it on the way to the door, never below the team's least
    S (covswarm.mission.crowding.least_domain: 0.89 m^2, 0.18 m wide for 20), takes it through and
    grows it back at the goal beyond shelf 3. Fastest vertex 0.25 m/s; SETTLE (10 s) at the
    end for the team to settle.
    """
    from covswarm.mission.crowding import least_domain
    from covswarm.world.model import Obstacle
    from covswarm.world.planner import plan_tour

    world = World(_HALL, tuple(Obstacle(n, box_vertices(b)) for n, b in _WAREHOUSE.items()))
    min_area, min_width = least_domain(agents, Scenario.robot_diameter)
    route = plan_tour(
        world,
        np.array(_rectangle(-3.7, -1.3, -1.1, 0.5)),
        [(2.7, 0.1)],
        min_area=min_area,
        min_width=min_width,
        max_speed=0.25,
    )
    return Scenario(
        name="warehouse",
        motion=route.motion,
        agents=agents,
        kappa=2.0,
        duration=route_duration(route.motion),
        dt=0.02,
        dynamics="unicycle",
        world=world,
    )


BUILTINS = {
    "circle": circle,
    "passage": passage,
    "formation": formation,
    "pinwheel": pinwheel,
    "live": live,
    "warehouse": warehouse,
}
# The built-ins whose S is planned for their team (a factory of the team size).
PLANNED: dict[str, Callable[[int], Scenario]] = {"warehouse": warehouse}


def builtin(name: str, agents: int | None = None) -> Scenario:
    """The built-in scenario ``name`` for a team of ``agents`` (default: its own); a planned
    one's route is planned for that team."""
    if agents is None:
        return BUILTINS[name]()
    if name in PLANNED:
        return PLANNED[name](agents)
    return replace(BUILTINS[name](), agents=agents)


# The --scenario help of every command that takes one, built from BUILTINS so that it
# names every built-in there is.
SCENARIO_HELP = (
    f"Built-in scenario ({', '.join(BUILTINS)}) or a .toml file (format: "
    "covswarm.mission.scenario_files)."
)
