"""Scenario files: a Scenario from TOML, and any scenario by name or path (load_scenario).

TOML format (every top-level key but ``name`` and ``[domain]`` has a default)::

    name = "zigzag"            # used in output folder names
    agents = 10                # default team size
    kappa = 2.0                # control gain, 1/s
    duration = 40.0            # s
    dt = 0.02                  # default simulator step, s
    dynamics = "unicycle"      # "single" (integrator) or "unicycle" (Khepera IV wheels)
    workspace = [-2.591, 2.591, -1.829, 1.829]        # xmin, xmax, ymin, ymax (plots)
    obstacles = [[-0.3, 0.3, 0.45, 1.829]]            # rectangles xmin, xmax, ymin, ymax
    robot_diameter = 0.14      # m: bodies start at least this far apart (and the
                               # summary's close approaches are closer than it)

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

from pathlib import Path
from typing import Any

from covswarm.mission.motion import DomainMotion, Keyframes, Rigid
from covswarm.mission.scenarios import BUILTINS, Box, Scenario, check_box

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


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
    return read_scenario_file(path)


def read_scenario_file(path: Path) -> Scenario:
    """The scenario in the .toml file at ``path``; ValueError naming the file and the
    problem for anything malformed."""
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


_TOP_KEYS = {
    "name", "agents", "kappa", "duration", "dt", "dynamics", "workspace", "obstacles",
    "robot_diameter",
    "initial", "domain", "density",
}  # fmt: skip


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
        key: data[key]
        for key in ("agents", "kappa", "duration", "dt", "dynamics", "robot_diameter")
        if key in data
    }
    for key in ("kappa", "duration", "dt", "robot_diameter"):
        if key in options and isinstance(options[key], int):
            options[key] = float(options[key])
    if "density" in data:
        from covswarm.mission.motion import DensityPath

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
    check_box(box)
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
