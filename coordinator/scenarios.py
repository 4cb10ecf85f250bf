"""Missions: how the covered subdomain S(t) moves, and where the robots start.

A :class:`Scenario` knows its domain motion exactly: ``domain(t)`` returns the CCW vertices of
S(t) and their time derivatives (not finite differences), which the feedforward term of the
control law needs. Built-in scenarios are ``circle`` (paper Section 5) and ``passage`` (paper
Section 6); others are read from TOML files.

TOML format (every top-level key but ``name`` and ``[domain]`` has a default)::

    name = "zigzag"            # used in output folder names
    agents = 10                # default team size
    kappa = 2.0                # control gain, 1/s
    duration = 40.0            # s
    dt = 0.02                  # default simulator step, s
    dynamics = "unicycle"      # "single" (integrator) or "unicycle" (Khepera IV wheels)
    workspace = [-2.591, 2.591, -1.829, 1.829]        # xmin, xmax, ymin, ymax (plots)
    obstacles = [[-0.3, 0.3, 0.45, 1.829]]            # rectangles xmin, xmax, ymin, ymax

    [initial]                  # optional; default: uniform at random inside S(0)
    box = [-2.4, -1.2, -0.8, 0.8]                     # uniform at random in this box

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

An optional density phi(q, t) = floor + sum_b w_b exp(-1/2 (q - mu_b)^T Sigma_b^-1 (q - mu_b))
(agent/density.py; absent: uniform)::

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

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from covswarm.tvd.density import Density, DensityPath

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

Box = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax

# Samples per keyframe segment / over a rigid mission checked for convexity: linear
# interpolation of two convex polygons is not always convex.
_CHECK_SAMPLES = 8


class DomainMotion(Protocol):
    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]: ...

    def sample_times(self, duration: float) -> np.ndarray: ...

    def to_toml(self) -> str: ...


def _signed_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _as_polygon(value: Any, what: str) -> np.ndarray:
    try:
        polygon = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what}: not a list of [x, y] points ({exc})") from None
    if polygon.ndim != 2 or polygon.shape[1] != 2 or polygon.shape[0] < 3:
        raise ValueError(f"{what}: need at least 3 [x, y] points, got shape {polygon.shape}")
    return polygon


@dataclass(frozen=True, eq=False)
class Keyframes:
    """S(t) interpolated linearly between polygons: piecewise-constant vertex velocities.

    times: (K,) strictly increasing; vertices: (K, k, 2), all CCW after construction (a CW
    input is reversed as a whole so vertex correspondence between keyframes is kept).
    Before times[0] and after times[-1] the domain stands still.
    """

    times: np.ndarray
    vertices: np.ndarray

    def __post_init__(self) -> None:
        times = np.array(self.times, dtype=float).reshape(-1)
        if times.size == 0 or not np.all(np.isfinite(times)):
            raise ValueError("keyframes: times must be a non-empty list of finite numbers")
        if np.any(np.diff(times) <= 0.0):
            raise ValueError("keyframes: times must be strictly increasing")
        polygons = [_as_polygon(v, f"keyframes: polygon {i}") for i, v in enumerate(self.vertices)]
        if len({len(v) for v in polygons}) > 1:
            raise ValueError("keyframes: every polygon needs the same number of vertices")
        vertices = np.array(polygons)
        if vertices.shape[0] != times.size:
            raise ValueError(f"keyframes: {times.size} times but {vertices.shape[0]} polygons")
        signs = {np.sign(_signed_area(v)) for v in vertices}
        if len(signs) > 1:
            raise ValueError("keyframes: polygons must all have the same orientation")
        if signs == {-1.0}:
            vertices = vertices[:, ::-1]
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "vertices", np.ascontiguousarray(vertices))

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        times, vertices = self.times, self.vertices
        if t < times[0] or t >= times[-1] or times.size == 1:
            return vertices[0 if t < times[0] else -1].copy(), np.zeros_like(vertices[0])
        # Right-continuous: at a keyframe time the velocity of the segment starting there.
        i = int(np.searchsorted(times, t, side="right")) - 1
        span = times[i + 1] - times[i]
        velocity = (vertices[i + 1] - vertices[i]) / span
        return vertices[i] + (t - times[i]) * velocity, velocity

    def sample_times(self, duration: float) -> np.ndarray:
        fractions = np.linspace(0.0, 1.0, _CHECK_SAMPLES + 1)
        segments = [
            a + (b - a) * fractions for a, b in zip(self.times[:-1], self.times[1:], strict=True)
        ]
        return np.unique(np.concatenate([self.times, *segments]))

    def to_toml(self) -> str:
        rows = ",\n".join(f"  {_toml_points(v)}" for v in self.vertices)
        return (
            '[domain]\nkind = "keyframes"\n'
            f"times = {_toml_list(self.times)}\nvertices = [\n{rows},\n]\n"
        )


@dataclass(frozen=True, eq=False)
class Rigid:
    """A base polygon moved rigidly along a circle (plus drift), rotated and scaled.

    polygon: (k, 2) about its own origin, made CCW. Vertex i at time t is
    o(t) + s(t) R(rotation_rate t) polygon[i], with o(t) = center + velocity t +
    radius (cos(phase + w t), sin(phase + w t)), w = 2 pi / period, s(t) = 1 + scale_rate t.
    """

    polygon: np.ndarray
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0
    period: float = math.inf
    phase: float = 0.0
    velocity: tuple[float, float] = (0.0, 0.0)
    rotation_rate: float = 0.0
    scale_rate: float = 0.0

    def __post_init__(self) -> None:
        polygon = _as_polygon(self.polygon, "rigid: polygon")
        if _signed_area(polygon) < 0.0:
            polygon = polygon[::-1].copy()
        object.__setattr__(self, "polygon", polygon)
        for name in ("radius", "phase", "rotation_rate", "scale_rate"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"rigid: {name} must be finite")
        if self.period == 0.0 or math.isnan(self.period):
            raise ValueError("rigid: period must be non-zero (inf for no circling)")

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        rate = 2.0 * math.pi / self.period
        angle = self.phase + rate * t
        origin = np.array(self.center) + np.array(self.velocity) * t
        origin = origin + self.radius * np.array([math.cos(angle), math.sin(angle)])
        origin_velocity = np.array(self.velocity) + self.radius * rate * np.array(
            [-math.sin(angle), math.cos(angle)]
        )
        a = self.rotation_rate * t
        rotation = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        scale = 1.0 + self.scale_rate * t
        body = self.polygon @ rotation.T  # R q_i, one row per vertex
        # d/dt [s R q] = s' R q + s w J R q, with J the +90 degree rotation.
        turned = np.stack([-body[:, 1], body[:, 0]], axis=1)
        vertices = origin + scale * body
        velocities = origin_velocity + self.scale_rate * body + scale * self.rotation_rate * turned
        return vertices, velocities

    def sample_times(self, duration: float) -> np.ndarray:
        return np.linspace(0.0, duration, 16 * _CHECK_SAMPLES + 1)

    def to_toml(self) -> str:
        return (
            '[domain]\nkind = "rigid"\n'
            f"polygon = {_toml_points(self.polygon)}\n"
            f"center = {_toml_list(self.center)}\n"
            f"radius = {_toml_float(self.radius)}\n"
            f"period = {_toml_float(self.period)}\n"
            f"phase = {_toml_float(self.phase)}\n"
            f"velocity = {_toml_list(self.velocity)}\n"
            f"rotation_rate = {_toml_float(self.rotation_rate)}\n"
            f"scale_rate = {_toml_float(self.scale_rate)}\n"
        )


@dataclass(frozen=True, eq=False)
class Scenario:
    """A mission: the moving domain, default run parameters and the map (for plots)."""

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
    density_path: DensityPath | None = None  # None: uniform density

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise ValueError("scenario: name must be a non-empty string")
        if self.dynamics not in ("single", "unicycle"):
            raise ValueError(
                f"scenario: dynamics must be single or unicycle, not {self.dynamics!r}"
            )
        if not (isinstance(self.agents, int) and self.agents >= 1):
            raise ValueError(f"scenario: agents must be a positive integer, not {self.agents!r}")
        for key in ("kappa", "duration", "dt"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"scenario: {key} must be a positive number, not {value!r}")
        for box in (self.workspace, self.initial_box, *self.obstacles):
            if box is not None:
                _check_box(box)
        _check_motion(self.motion, self.duration)
        if self.density_path is not None:
            for t in self.motion.sample_times(self.duration):
                try:
                    self.density_path(float(t))
                except ValueError as exc:
                    raise ValueError(f"density at t = {t:g} s: {exc}") from None

    def density(self, t: float) -> Density | None:
        """phi at time t with its exact rates (covswarm.tvd.density.Density), None when uniform."""
        return None if self.density_path is None else self.density_path(float(t))

    def domain(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """S(t): CCW vertices (k, 2) and their exact velocities d/dt (k, 2)."""
        return self.motion(float(t))

    def initial_positions(self, n: int, seed: int) -> np.ndarray:
        """(n, 2) start positions, uniform at random (deterministic in seed)."""
        rng = np.random.default_rng(seed)
        if self.initial_box is not None:
            xmin, xmax, ymin, ymax = self.initial_box
            return rng.uniform([xmin, ymin], [xmax, ymax], size=(n, 2))
        return _uniform_in_polygon(self.domain(0.0)[0], n, rng)

    def to_toml(self) -> str:
        """This scenario in the TOML format of the module docstring."""
        lines = [
            f"name = {_toml_str(self.name)}",
            f"agents = {self.agents}",
            f"kappa = {_toml_float(self.kappa)}",
            f"duration = {_toml_float(self.duration)}",
            f"dt = {_toml_float(self.dt)}",
            f"dynamics = {_toml_str(self.dynamics)}",
        ]
        if self.workspace is not None:
            lines.append(f"workspace = {_toml_list(self.workspace)}")
        lines.append(f"obstacles = [{', '.join(_toml_list(o) for o in self.obstacles)}]")
        if self.initial_box is not None:
            lines.append(f"\n[initial]\nbox = {_toml_list(self.initial_box)}")
        text = "\n".join(lines) + "\n\n" + self.motion.to_toml()
        return text if self.density_path is None else text + _density_toml(self.density_path)


def _check_box(box: Box) -> None:
    if len(box) != 4 or not all(math.isfinite(v) for v in box):
        raise ValueError(f"box {box!r}: need 4 finite numbers xmin, xmax, ymin, ymax")
    if not (box[0] < box[1] and box[2] < box[3]):
        raise ValueError(f"box {box!r}: need xmin < xmax and ymin < ymax")


def _check_motion(motion: DomainMotion, duration: float) -> None:
    """Raise ValueError unless S(t) is a valid convex polygon at the sampled times."""
    from covswarm.tvd.coverage import validate_polygon

    for t in motion.sample_times(duration):
        vertices, velocities = motion(float(t))
        try:
            validate_polygon(vertices)
        except ValueError as exc:
            raise ValueError(f"domain at t = {t:g} s: {exc}") from None
        if _signed_area(vertices) <= 0.0 or not np.all(np.isfinite(velocities)):
            raise ValueError(f"domain at t = {t:g} s: turned inside out or non-finite velocity")


def _uniform_in_polygon(polygon: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) points uniform in a convex CCW polygon, by rejection from its bounding box."""
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    edges = np.roll(polygon, -1, axis=0) - polygon
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


def _toml_float(value: float) -> str:
    value = float(value)
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)


def _toml_list(values: Any) -> str:
    return "[" + ", ".join(_toml_float(v) for v in values) + "]"


def _toml_points(points: np.ndarray) -> str:
    return "[" + ", ".join(_toml_list(p) for p in points) + "]"


def _density_toml(path: DensityPath) -> str:
    table = path.to_table()
    lines = [f"\n[density]\nfloor = {_toml_float(table['floor'])}"]
    for bump in table["bumps"]:
        lines.append("\n[[density.bumps]]")
        for key, value in bump.items():
            text = _toml_points(value) if key in ("cov", "cov_rate") else (
                _toml_list(value) if isinstance(value, list) else _toml_float(value)
            )  # fmt: skip
            lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def _toml_str(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


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
    from covswarm.tvd.density import Density, DensityPath

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


BUILTINS = {"circle": circle, "passage": passage, "formation": formation}


# ---------------------------------------------------------------------------- loading

_TOP_KEYS = {
    "name", "agents", "kappa", "duration", "dt", "dynamics", "workspace", "obstacles",
    "initial", "domain", "density",
}  # fmt: skip


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name, or a scenario read from a .toml file.

    Raises ValueError naming the file and the problem for anything malformed.
    """
    if str(name_or_path) in BUILTINS:
        return BUILTINS[str(name_or_path)]()
    path = Path(name_or_path)
    if path.suffix != ".toml":
        known = ", ".join(sorted(BUILTINS))
        raise ValueError(
            f"unknown scenario {str(name_or_path)!r}: use one of {known} or a .toml file"
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from None
    try:
        return scenario_from_dict(data)
    except (ValueError, TypeError, KeyError) as exc:
        raise ValueError(f"{path}: {exc}") from None


def scenario_from_dict(data: dict[str, Any]) -> Scenario:
    """Build a Scenario from parsed TOML (see the module docstring for the keys)."""
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ValueError(f"unknown keys {sorted(unknown)}")
    if "name" not in data or "domain" not in data:
        raise ValueError("'name' and a [domain] table are required")
    initial = data.get("initial", {})
    if set(initial) - {"box"}:
        raise ValueError(f"[initial]: unknown keys {sorted(set(initial) - {'box'})}")
    options: dict[str, Any] = {
        key: data[key] for key in ("agents", "kappa", "duration", "dt", "dynamics") if key in data
    }
    for key in ("kappa", "duration", "dt"):
        if key in options and isinstance(options[key], int):
            options[key] = float(options[key])
    if "density" in data:
        from covswarm.tvd.density import DensityPath

        options["density_path"] = DensityPath.from_table(data["density"])
    return Scenario(
        name=data["name"],
        motion=_motion_from_dict(data["domain"]),
        workspace=_box(data["workspace"]) if "workspace" in data else None,
        obstacles=tuple(_box(o) for o in data.get("obstacles", [])),
        initial_box=_box(initial["box"]) if "box" in initial else None,
        **options,
    )


def _box(value: Any) -> Box:
    if not isinstance(value, list) or len(value) != 4:
        raise ValueError(f"box {value!r}: need [xmin, xmax, ymin, ymax]")
    box = tuple(float(v) for v in value)
    _check_box(box)
    return box  # type: ignore[return-value]


def _motion_from_dict(domain: dict[str, Any]) -> DomainMotion:
    kind = domain.get("kind")
    if kind == "keyframes":
        expected = {"kind", "times", "vertices"}
        _require_keys(domain, expected, expected)
        return Keyframes(times=domain["times"], vertices=domain["vertices"])
    if kind == "rigid":
        optional = {
            "center",
            "radius",
            "period",
            "phase",
            "velocity",
            "rotation_rate",
            "scale_rate",
        }
        _require_keys(domain, {"kind", "polygon"}, {"kind", "polygon"} | optional)
        values: dict[str, Any] = {}
        for key in optional & set(domain):
            if key in ("center", "velocity"):
                pair = tuple(float(v) for v in domain[key])
                if len(pair) != 2:
                    raise ValueError(f"[domain] {key}: need [x, y]")
                values[key] = pair
            else:
                values[key] = float(domain[key])
        return Rigid(polygon=domain["polygon"], **values)
    raise ValueError(f"[domain] kind must be 'keyframes' or 'rigid', not {kind!r}")


def _require_keys(table: dict[str, Any], required: set[str], allowed: set[str]) -> None:
    missing, unknown = required - set(table), set(table) - allowed
    if missing:
        raise ValueError(f"[domain]: missing {sorted(missing)}")
    if unknown:
        raise ValueError(f"[domain]: unknown keys {sorted(unknown)}")
