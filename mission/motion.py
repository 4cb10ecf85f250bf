"""How the covered subdomain S(t) and the density move over a mission, exactly at any t.

A motion returns the CCW vertices of S(t) and their time derivatives (not finite
differences), which the feedforward term of the control law needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from covswarm.mission.toml_text import toml_float, toml_list, toml_points
from covswarm.tvd.coverage import signed_area
from covswarm.tvd.density import BUMP_KEYS, Density

# Samples per keyframe segment / over a rigid mission checked for convexity: linear
# interpolation of two convex polygons is not always convex.
_CHECK_SAMPLES = 8


class DomainMotion(Protocol):
    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]: ...

    def sample_times(self, duration: float) -> np.ndarray: ...

    def to_toml(self) -> str: ...


def as_polygon(value: Any, what: str) -> np.ndarray:
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
        polygons = [as_polygon(v, f"keyframes: polygon {i}") for i, v in enumerate(self.vertices)]
        if len({len(v) for v in polygons}) > 1:
            raise ValueError("keyframes: every polygon needs the same number of vertices")
        vertices = np.array(polygons)
        if vertices.shape[0] != times.size:
            raise ValueError(f"keyframes: {times.size} times but {vertices.shape[0]} polygons")
        signs = {np.sign(signed_area(v)) for v in vertices}
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
        rows = ",\n".join(f"  {toml_points(v)}" for v in self.vertices)
        return (
            '[domain]\nkind = "keyframes"\n'
            f"times = {toml_list(self.times)}\nvertices = [\n{rows},\n]\n"
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
        polygon = as_polygon(self.polygon, "rigid: polygon")
        if signed_area(polygon) < 0.0:
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
            f"polygon = {toml_points(self.polygon)}\n"
            f"center = {toml_list(self.center)}\n"
            f"radius = {toml_float(self.radius)}\n"
            f"period = {toml_float(self.period)}\n"
            f"phase = {toml_float(self.phase)}\n"
            f"velocity = {toml_list(self.velocity)}\n"
            f"rotation_rate = {toml_float(self.rotation_rate)}\n"
            f"scale_rate = {toml_float(self.scale_rate)}\n"
        )


@dataclass(frozen=True, eq=False)
class DensityPath:
    """A mission's exact density law: ``base`` at t = 0, each bump also turning.

    Bump b at time t: mean mu + t mu_dot, weight w + t w_dot, covariance
    R(omega_b t) (Sigma + t Sigma_dot) R(omega_b t)^T with turn_rates omega_b (B,) in rad/s,
    so an elongated bump can turn for ever and stay positive definite. ``self(t)`` is the
    snapshot at t with the exact rates (what the coordinator broadcasts).
    """

    base: Density
    turn_rates: np.ndarray

    def __post_init__(self) -> None:
        try:
            rates = np.array(self.turn_rates, dtype=np.float64).reshape(len(self.base.weights))
        except (TypeError, ValueError):
            raise ValueError("invalid density: turn_rates must be one number per bump") from None
        if not np.all(np.isfinite(rates)):
            raise ValueError("invalid density: turn_rates contain NaN or inf")
        object.__setattr__(self, "turn_rates", rates)

    def __call__(self, t: float) -> Density:
        # Rates too large for the time overflow to inf, which Density refuses by name.
        with np.errstate(over="ignore", invalid="ignore"):
            return self._at(float(t))

    def _at(self, t: float) -> Density:
        base = self.base
        angle = self.turn_rates * t
        cos, sin = np.cos(angle), np.sin(angle)
        rotation = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)
        body = base.covariances + t * base.covariance_rates
        # d/dt (R B R^T) = R (B_dot + omega (J B - B J)) R^T, J the +90 degree rotation.
        turn = np.array([[0.0, -1.0], [1.0, 0.0]])
        body_rate = base.covariance_rates + self.turn_rates[:, None, None] * (
            turn @ body - body @ turn
        )
        spin = rotation.transpose(0, 2, 1)
        return Density(
            floor=base.floor,
            means=base.means + t * base.mean_rates,
            covariances=rotation @ body @ spin,
            weights=base.weights + t * base.weight_rates,
            mean_rates=base.mean_rates,
            covariance_rates=rotation @ body_rate @ spin,
            weight_rates=base.weight_rates,
            time=t,
        )

    @classmethod
    def from_table(cls, table: Any) -> DensityPath:
        """From a TOML ``[density]`` table: Density.from_dict keys, bumps may add turn_rate."""
        if not isinstance(table, dict) or "t" in table:
            raise ValueError("[density] must be a table of floor and bumps (no 't': t = 0)")
        bumps = table.get("bumps", [])
        if not isinstance(bumps, list) or not all(isinstance(b, dict) for b in bumps):
            raise ValueError("[density] bumps must be an array of tables ([[density.bumps]])")
        for i, bump in enumerate(bumps):
            if unknown := set(bump) - {*BUMP_KEYS, "turn_rate"}:
                raise ValueError(
                    f"density: bump {i}: unknown keys {sorted(map(str, unknown))}; the keys are "
                    f"{', '.join(BUMP_KEYS)}, turn_rate"
                )
        if unknown := set(table) - {"floor", "bumps"}:
            raise ValueError(
                f"[density]: unknown keys {sorted(map(str, unknown))}; the keys are floor, bumps"
            )
        turns = [b.get("turn_rate", 0.0) for b in bumps]
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in turns):
            raise ValueError(f"density: turn_rate must be a number, got {turns!r}")
        plain = [{k: v for k, v in b.items() if k != "turn_rate"} for b in bumps]
        return cls(Density.from_dict({**table, "bumps": plain}), np.array(turns))

    def to_table(self) -> dict[str, Any]:
        """Inverse of ``from_table`` (plain data)."""
        table = self.base.to_dict()
        del table["t"]
        for bump, turn in zip(table["bumps"], self.turn_rates.tolist(), strict=True):
            bump["turn_rate"] = turn
        return table

    def to_toml(self) -> str:
        """The ``[density]`` table and its ``[[density.bumps]]`` as TOML text."""
        table = self.to_table()
        lines = [f"\n[density]\nfloor = {toml_float(table['floor'])}"]
        for bump in table["bumps"]:
            lines.append("\n[[density.bumps]]")
            for key, value in bump.items():
                text = toml_points(value) if key in ("cov", "cov_rate") else (
                    toml_list(value) if isinstance(value, list) else toml_float(value)
                )  # fmt: skip
                lines.append(f"{key} = {text}")
        return "\n".join(lines) + "\n"
