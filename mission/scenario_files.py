"""Scenario files: a Scenario from TOML, and any scenario by name or path (load_scenario).

TOML format (every top-level key but ``name`` and ``[domain]`` has a default). The file must
be a regular file of at most 1 MB. S must stay clear of every obstacle and inside the
workspace for the whole duration: a file whose S touches one is refused with the mission time
and the obstacle's name ("obstacle 2" for the second entry of ``obstacles``, "map piece 7"
for a map's)::

    name = "zigzag"            # used in output folder names
    agents = 10                # default team size
    kappa = 2.0                # control gain, 1/s
    duration = 40.0            # s (a route's default: its end + 10 s; shorter is refused)
    dt = 0.02                  # default simulator step, s
    dynamics = "unicycle"      # "single" (integrator) or "unicycle" (Khepera IV wheels)
    workspace = [-2.591, 2.591, -1.829, 1.829]        # xmin, xmax, ymin, ymax: S stays in
    obstacles = [[-0.3, 0.3, 0.45, 1.829],            # boxes xmin, xmax, ymin, ymax
                 [[1.0, 1.0], [1.5, 1.0], [1.2, 1.4]]]  # or convex polygons [[x, y], ...]
                               # (one wholly outside the workspace is refused: a typo)
    map = "lab.yaml"           # optional: a ROS map_server / Nav2 map, relative to this
                               # file; its occupied and unknown cells become obstacles
                               # (covswarm.world.maps), its extent the default workspace
                               # (a workspace reaching beyond it is refused)
    robot_diameter = 0.14      # m: bodies start at least this far apart (and the
                               # summary's close approaches are closer than it)

    [initial]                  # optional; default: uniform at random inside S(0)
    box = [-2.4, -1.2, -0.8, 0.8]                     # uniform at random in this box, which
                               # must lie in the workspace, clear of every obstacle

    [domain]                   # kind = "keyframes": S is linearly interpolated between
    kind = "keyframes"         # polygons, so every vertex moves with constant velocity
    times = [0.0, 10.0, 20.0]  # per segment; S stays put before the first / after the last
    vertices = [               # one convex polygon per time, same vertex count and order
      [[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]],
      [[-0.6, -0.3], [0.6, -0.3], [0.6, 0.3], [-0.6, 0.3]],
      [[1.2, -0.8], [2.4, -0.8], [2.4, 0.8], [1.2, 0.8]],
    ]

A rigid motion (plus uniform scaling) of a base polygon instead::

    [domain]
    kind = "rigid"
    polygon = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]  # about its own origin
    center = [0.0, 0.0]        # centre of the circle that the polygon's origin travels
    radius = 1.5               # m; 0 keeps the origin at center (+ velocity t)
    period = 50.0              # s per counter-clockwise turn (negative: clockwise)
    phase = 0.0                # rad, position on the circle at t = 0
    velocity = [0.0, 0.0]      # m/s drift of the circle's centre
    rotation_rate = 0.0        # rad/s, about the polygon's origin
    scale_rate = 0.0           # 1/s: scale(t) = 1 + scale_rate t, must stay positive

Vertex i of a rigid domain is ``o(t) + s(t) R(a(t)) q_i`` with o the origin's path, s the
scale and a = rotation_rate t.

A planned route (covswarm.world.planner): S goes from ``polygon`` to each goal in turn
through free space, shrinking (never below the team's least S) where a door needs it and
growing back at each goal; planned at load, deterministically. Without ``duration`` the
mission lasts the route's end plus mission.scenarios.SETTLE (10 s); a ``duration`` ending
before the route is refused::

    [domain]
    kind = "route"
    polygon = [[-2.4, -0.8], [-1.2, -0.8], [-1.2, 0.8], [-2.4, 0.8]]  # S at t = 0
    goals = [[1.8, 0.0], [-1.8, 0.0]]  # where S's centroid goes, visited in order
    speed = 0.25               # m/s, the fastest vertex (default 0.25)
    hold = 2.0                 # s at each goal (default 0)

An optional density phi(q, t) = floor + sum_b w_b exp(-1/2 (q - mu_b)^T Sigma_b^-1 (q - mu_b))
(tvd/density.py; absent: uniform)::

    [density]
    floor = 1.0                # > 0, plus the negative weights
    [[density.bumps]]          # up to 16; every *_rate and turn_rate defaults to 0
    mean = [0.0, 0.5]          # m, at t = 0
    cov = [[0.09, 0.0], [0.0, 0.01]]                  # m^2, symmetric positive definite
    weight = 8.0               # peak height above the floor
    mean_rate = [0.05, 0.0]    # m/s
    cov_rate = [[0.0, 0.0], [0.0, 0.0]]               # m^2/s
    weight_rate = 0.0          # 1/s
    turn_rate = 0.1            # rad/s: the covariance turns, R(turn_rate t) cov R^T
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from covswarm.mission.motion import DensityPath, DomainMotion, Keyframes, Rigid
from covswarm.mission.scenarios import (
    BUILTINS,
    Box,
    Scenario,
    builtin,
    check_box,
    route_duration,
)
from covswarm.tvd.geometry import polygons_intersect
from covswarm.world.maps import (
    MAX_OBSTACLES,
    OccupancyMap,
    finite_number,
    read_map,
    read_regular_file,
)
from covswarm.world.model import Obstacle, World, box_vertices, make_obstacle
from covswarm.world.route import RouteMotion

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

MAX_FILE_BYTES = 1 << 20  # a scenario file is text a person writes


def load_scenario(name_or_path: str | Path, agents: int | None = None) -> Scenario:
    """A built-in scenario by name, or a scenario read from a .toml file, for a team of
    ``agents`` robots (default: the scenario's own ``agents``; ``--agents`` of sim and run):
    a route is planned for that team, S never smaller than it may take.

    Raises ValueError naming the file and the problem for anything malformed.
    """
    if agents is not None and (isinstance(agents, bool) or not isinstance(agents, int)):
        raise ValueError(f"agents must be an integer, not {agents!r}")
    if agents is not None and agents < 1:
        raise ValueError(f"agents must be at least 1, not {agents}")
    if str(name_or_path) in BUILTINS:
        return builtin(str(name_or_path), agents)
    path = Path(name_or_path)
    if path.suffix != ".toml":
        known = ", ".join(sorted(BUILTINS))
        raise ValueError(
            f"unknown scenario {str(name_or_path)!r}: use one of {known} or a .toml file"
        )
    return read_scenario_file(path, agents)


def read_scenario_file(path: Path, agents: int | None = None) -> Scenario:
    """The scenario in the .toml file at ``path`` for a team of ``agents`` (default: the
    file's); ValueError naming the file and the problem for anything malformed."""
    path = Path(path)
    raw = read_regular_file(path, MAX_FILE_BYTES)
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from None
    try:
        return scenario_from_dict(data, base=path.parent, agents=agents)
    except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
        raise ValueError(f"{path}: {exc}") from None


_TOP_KEYS = {
    "name", "agents", "kappa", "duration", "dt", "dynamics", "workspace", "obstacles", "map",
    "robot_diameter",
    "initial", "domain", "density",
}  # fmt: skip


def scenario_from_dict(
    data: dict[str, Any], base: Path | None = None, agents: int | None = None
) -> Scenario:
    """Build a Scenario from parsed TOML (see the module docstring for the keys); ``base``:
    the folder a ``map`` path is relative to (default: the current one); ``agents``: the
    team, in place of the file's (a route is planned for it)."""
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ValueError(f"unknown keys {sorted(unknown)}")
    if "name" not in data or "domain" not in data:
        raise ValueError("'name' and a [domain] table are required")
    initial = _table(data.get("initial", {}), "[initial]")
    if set(initial) - {"box"}:
        raise ValueError(f"[initial]: unknown keys {sorted(set(initial) - {'box'})}")
    options: dict[str, Any] = {}
    if "agents" in data:
        if isinstance(data["agents"], bool) or not isinstance(data["agents"], int):
            raise ValueError(f"agents must be an integer, not {data['agents']!r}")
        options["agents"] = data["agents"]
    if agents is not None:
        options["agents"] = agents
    for key in ("kappa", "duration", "dt", "robot_diameter"):
        if key in data:
            options[key] = finite_number(data[key], key)
    for key in ("name", "dynamics"):
        if key in data and not isinstance(data[key], str):
            raise ValueError(f"{key} must be a string, not {data[key]!r}")
    if "dynamics" in data:
        options["dynamics"] = data["dynamics"]
    if "density" in data:
        options["density_path"] = _keyed("[density]", DensityPath.from_table, data["density"])
    world, grid = _world(data, base)
    motion = _motion_from_dict(
        _table(data["domain"], "[domain]"),
        world,
        (
            options.get("agents", Scenario.agents),
            options.get("robot_diameter", Scenario.robot_diameter),
        ),
    )
    if isinstance(motion, RouteMotion) and "duration" not in options:
        options["duration"] = route_duration(motion)  # not the default 40 s: S cut short
    return Scenario(
        name=data["name"],
        motion=motion,
        initial_box=_keyed("[initial] box", _box, initial["box"]) if "box" in initial else None,
        world=world,
        map=grid,
        **options,
    )


def _world(data: dict[str, Any], base: Path | None) -> tuple[World, OccupancyMap | None]:
    """The workspace, the ``obstacles`` entries and the ``map``'s pieces; the map (or None)."""
    workspace = _keyed("workspace", _box, data["workspace"]) if "workspace" in data else None
    entries = data.get("obstacles", [])
    if not isinstance(entries, list):
        raise ValueError(f"obstacles must be a list of boxes and polygons, not {entries!r}")
    obstacles = [
        _keyed("obstacles", make_obstacle, f"obstacle {i + 1}", entry)
        for i, entry in enumerate(entries)
    ]
    grid = None
    if "map" in data:
        name = data["map"]
        if not isinstance(name, str) or not name:
            raise ValueError(f"map must be the path of a map's YAML file, not {name!r}")
        path = Path(name) if base is None or Path(name).is_absolute() else base / name
        grid = _keyed("map", read_map, path)
        if workspace is None:
            workspace = grid.extent
        else:
            grid.check_workspace(workspace)
    if workspace is not None:
        _check_inside(obstacles, workspace)
    if grid is not None:  # the file's obstacles and the map's pieces share one World message
        obstacles += _keyed("map", grid.obstacles, "map piece", 1, MAX_OBSTACLES, len(obstacles))
    elif len(obstacles) > MAX_OBSTACLES:
        raise ValueError(
            f"obstacles: {len(obstacles)} entries, at most {MAX_OBSTACLES} fit a World message: "
            "give fewer obstacles (merge neighbouring boxes)"
        )
    return World(workspace, tuple(obstacles)), grid


def _check_inside(obstacles: list[Obstacle], workspace: Box) -> None:
    """ValueError naming the first of the file's ``obstacles`` that lies wholly outside the
    workspace (not even touching it): it can only be a typo in its coordinates. One that
    crosses the workspace's edge (a wall running out of it) is fine."""
    room = box_vertices(workspace)
    for obstacle in obstacles:
        if not polygons_intersect(obstacle.vertices, room):
            x0, x1, y0, y1 = obstacle.box
            w = ", ".join(f"{v:g}" for v in workspace)
            raise ValueError(
                f"{obstacle.name} ([{x0:g}, {x1:g}] x [{y0:g}, {y1:g}] m) lies wholly outside "
                f"the workspace [{w}]: check its coordinates"
            )


def _keyed(key: str, build: Callable[..., Any], *args: Any) -> Any:
    """build(*args), its errors prefixed with the key they come from."""
    try:
        return build(*args)
    except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
        message, bare = str(exc), key.strip("[]")
        if message.startswith(f"{bare}: "):  # "density: ..." under "[density]"
            message = key + message[len(bare) :]
        raise ValueError(message if message.startswith(key) else f"{key}: {message}") from None


def _table(value: Any, key: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{key} must be a table, not {value!r}")
    return value


def _box(value: Any) -> Box:
    if not isinstance(value, list) or len(value) != 4:
        raise ValueError(f"box {value!r}: need [xmin, xmax, ymin, ymax]")
    box = tuple(finite_number(v, "box") for v in value)
    check_box(box)  # type: ignore[arg-type]
    return box  # type: ignore[return-value]


def _pair(value: Any, key: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise ValueError(f"[domain] {key}: need [x, y], not {value!r}")
    return (finite_number(value[0], f"[domain] {key}"), finite_number(value[1], f"[domain] {key}"))


def _points(value: Any, key: str) -> list[list[float]]:
    """A list of [x, y] number pairs (a polygon), every type error naming ``key``."""
    if not isinstance(value, list):
        raise ValueError(f"{key}: need a list of [x, y] points, not {value!r}")
    return [list(_pair(p, key.removeprefix("[domain] "))) for p in value]


def _keyframes(domain: dict[str, Any], world: World) -> DomainMotion:
    expected = {"kind", "times", "vertices"}
    _require_keys(domain, expected, expected)
    times, vertices = domain["times"], domain["vertices"]
    if not isinstance(times, list) or not isinstance(vertices, list):
        raise ValueError("[domain] times and vertices must be lists")
    return Keyframes(
        times=[finite_number(t, "[domain] times") for t in times],
        vertices=[_points(v, "[domain] vertices") for v in vertices],
    )


_RIGID_OPTIONAL = {"center", "radius", "period", "phase", "velocity", "rotation_rate", "scale_rate"}


def _rigid(domain: dict[str, Any], world: World) -> DomainMotion:
    _require_keys(domain, {"kind", "polygon"}, {"kind", "polygon"} | _RIGID_OPTIONAL)
    values: dict[str, Any] = {}
    for key in _RIGID_OPTIONAL & set(domain):
        if key in ("center", "velocity"):
            values[key] = _pair(domain[key], key)
        elif key == "period":  # inf (no circling) is allowed here
            value = domain[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"[domain] period must be a number, not {value!r}")
            values[key] = float(value)
        else:
            values[key] = finite_number(domain[key], f"[domain] {key}")
    return Rigid(polygon=_points(domain["polygon"], "[domain] polygon"), **values)


# [domain] kind -> its builder from the table and the world (a planned kind needs the world).
MOTION_KINDS: dict[str, Callable[[dict[str, Any], World], DomainMotion]] = {
    "keyframes": _keyframes,
    "rigid": _rigid,
}
ROUTE_SPEED = 0.25  # m/s: a route's fastest vertex unless the file says ``speed``


def _route(domain: dict[str, Any], world: World, team: tuple[int, float]) -> DomainMotion:
    """S planned from ``polygon`` through ``goals`` (covswarm.world.planner.plan_tour), never
    smaller than the team of ``team`` = (agents, robot diameter in m) may take."""
    from covswarm.mission.crowding import least_domain
    from covswarm.world.planner import plan_tour

    _require_keys(
        domain, {"kind", "polygon", "goals"}, {"kind", "polygon", "goals", "speed", "hold"}
    )
    goals = domain["goals"]
    if not isinstance(goals, list) or not goals:
        raise ValueError(f"[domain] goals: need a list of [x, y] points, not {goals!r}")
    speed = finite_number(domain.get("speed", ROUTE_SPEED), "[domain] speed")
    hold = finite_number(domain.get("hold", 0.0), "[domain] hold")
    if speed <= 0.0 or hold < 0.0:
        raise ValueError(f"[domain] speed must be > 0 and hold >= 0, not {speed!r}, {hold!r}")
    min_area, min_width = least_domain(*team)
    route = plan_tour(
        world,
        _points(domain["polygon"], "[domain] polygon"),
        [_pair(g, "goals") for g in goals],
        min_area=min_area,
        min_width=min_width,
        max_speed=speed,
        hold=hold,
    )
    return route.motion


def _motion_from_dict(
    domain: dict[str, Any], world: World, team: tuple[int, float]
) -> DomainMotion:
    kind = domain.get("kind")
    if kind == "route":
        return _keyed("[domain] route", _route, domain, world, team)
    if not isinstance(kind, str) or kind not in MOTION_KINDS:
        kinds = " or ".join(repr(k) for k in [*MOTION_KINDS, "route"])
        raise ValueError(f"[domain] kind must be {kinds}, not {kind!r}")
    return MOTION_KINDS[kind](domain, world)


def _require_keys(table: dict[str, Any], required: set[str], allowed: set[str]) -> None:
    missing, unknown = required - set(table), set(table) - allowed
    if missing and unknown:  # most likely a typo: name both
        raise ValueError(f"[domain]: missing {sorted(missing)}, unknown {sorted(unknown)}")
    if missing:
        raise ValueError(f"[domain]: missing {sorted(missing)}")
    if unknown:
        raise ValueError(f"[domain]: unknown keys {sorted(unknown)}")
