"""S(t) along a planned route: chained smooth motions between convex waypoint polygons.

A route visits polygons S_0, S_1, ..., S_n. Segment i carries S_i to S_{i+1} in ``spans[i]``
seconds along the Minkowski interpolation V(s) = (1 - s) A + s B with the quintic
smoothstep progress s(u) = 10u^3 - 15u^4 + 6u^5, u = (t - t_i) / T_i (the same time scaling
as covswarm.coordinator.steering, which imports it from here). s' = s'' = 0 at both ends, so
S stops at every waypoint with zero velocity and acceleration and the chained motion is C2;
the vertex velocities dV/dt = (B - A) s'(u)/T are exact, as the agents' feedforward (paper
Eq. 9's boundary integral) needs.

Pairing. When A and B have the same edge directions in the same order (a homothet of one
another: the planner's translate-and-scale waypoints) vertex i of A moves to vertex i of B
and every intermediate polygon has those edge directions, hence is convex. Otherwise (a
goal polygon of another shape) the vertices are pairs of support points (a_i, b_j) of A and
B for each direction between consecutive merged edge normals, which is the Minkowski
combination (1 - s) A + s B, convex for every s.

Rotation. A segment with a turn phi != 0 (``turns[i]``, rad, counter-clockwise) carries a
polygon A to B = c_B + k R(phi) (A - c_A), a similarity of it (c the area centroids, k > 0
the scale, R(phi) the rotation), along V(s) = c_A + s (c_B - c_A) + sigma(s) R(s phi) Q with
Q = A - c_A and sigma(s) = 1 - s + s k: centroid, scale and angle all follow the same
quintic progress s(u), and every V(s) is a similarity of A, hence convex. Its exact vertex
velocities are dV/dt = (s'(u) / T) [(c_B - c_A) + (k - 1) R(s phi) Q + sigma phi J R(s phi) Q]
(J the rotation by 90 degrees). With phi = 0 this is the paired interpolation above.

Speed. The fastest vertex of segment i peaks at (15/8) max_j |B_j - A_j| / T_i, so
:meth:`RouteMotion.timed` picks T_i to put that at the speed limit (the convention of
coordinator.steering's PEAK_RATE and default_max_domain_speed). A turning segment's |dV/ds|
is at most |c_B - c_A| + (|k - 1| + max(1, k) |phi|) |Q_j| (the triangle inequality on the
velocity above), its ``reach``; T_i puts (15/8) reach / T_i at the limit, so the limit is a
bound there, not reached exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from covswarm.tvd.geometry import validate_convex

PEAK_RATE = 15.0 / 8.0  # max over u of d/du of the quintic smoothstep
# Vertices of an interpolated polygon closer than this x its half perimeter are one vertex
# (a support-point pairing has zero-length edges at s = 0 and s = 1).
_MERGE_TOL = 1e-9
_SAMPLES = 8  # instants per segment returned by sample_times (besides the waypoints)


def smoothstep(u: float) -> tuple[float, float]:
    """Quintic progress s(u) and ds/du for u in [0, 1] (clamped outside)."""
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u)), 30.0 * u * u * (1.0 - u) ** 2


def centroid(polygon: np.ndarray) -> np.ndarray:
    """Area centroid (2,) of a simple CCW polygon (k, 2), m."""
    x, y = polygon[:, 0], polygon[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def width(polygon: np.ndarray) -> float:
    """Least width (m) of a convex CCW polygon (k, 2): the smallest extent across an edge
    normal (for a convex polygon the minimum over all directions is at one of them)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    extent = polygon @ normals.T  # (k vertices, k normals)
    return float((extent.max(axis=0) - extent.min(axis=0)).min())


def _edge_angles(polygon: np.ndarray) -> np.ndarray:
    edges = np.roll(polygon, -1, axis=0) - polygon
    return np.arctan2(edges[:, 1], edges[:, 0])


def pairing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(p, 2) int vertex pairs (i, j) such that (1 - s) a[i] + s b[j] are the vertices of the
    Minkowski combination (1 - s) A + s B for 0 < s < 1 (module docstring, "Pairing").
    a: (n, 2), b: (m, 2) convex CCW."""
    if len(a) == len(b):
        turn = np.mod(_edge_angles(b) - _edge_angles(a) + math.pi, 2.0 * math.pi) - math.pi
        if np.all(np.abs(turn) < 1e-9):
            return np.stack([np.arange(len(a)), np.arange(len(a))], axis=1)
    return support_pairs(a, b)


def support_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Vertex pairs (i, j) of the Minkowski combinations (1 - s) A + s B, 0 < s < 1.

    a: (n, 2), b: (m, 2) convex CCW polygons. For each direction strictly between
    consecutive (merged) outward edge normals of A and B, in CCW order, the indices of
    the vertices of A and of B furthest along it: (p, 2) int, p <= n + m.
    """
    angles = np.concatenate([_normal_angles(a), _normal_angles(b)])
    angles = np.sort(np.mod(angles, 2.0 * math.pi))
    keep = np.concatenate([[True], np.diff(angles) > 1e-12])
    if angles[-1] - angles[0] > 2.0 * math.pi - 1e-12:  # the last wraps onto the first
        keep[-1] = False
    angles = angles[keep]
    following = np.concatenate([angles[1:], angles[:1] + 2.0 * math.pi])
    middle = 0.5 * (angles + following)
    directions = np.stack([np.cos(middle), np.sin(middle)], axis=1)  # (p, 2)
    pairs = np.stack([np.argmax(directions @ a.T, axis=1), np.argmax(directions @ b.T, axis=1)], 1)
    repeated = np.all(pairs == np.roll(pairs, 1, axis=0), axis=1)
    return pairs[~repeated] if not repeated.all() else pairs[:1]


def _normal_angles(polygon: np.ndarray) -> np.ndarray:
    """Angles (k,) of the outward normals of a CCW polygon's edges (edge turned -90 deg)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    return np.arctan2(-edges[:, 0], edges[:, 1])


@dataclass(frozen=True)
class Leg:
    """A planned tour's way to one of its goals, as its plan (covswarm.world.planner's
    Route for that goal) gave it: the goal (m), the plan's stops (``len(Route.waypoints)``,
    the start and the goal included), the length of the centroid's path (m,
    ``Route.length``), the mission time S arrives at the goal (s) and the time its hold there
    ends (s, the time the next leg starts)."""

    goal: tuple[float, float]
    waypoints: int
    length: float
    arrival: float
    end: float


@dataclass(frozen=True, eq=False)
class RouteMotion:
    """S(t) through waypoint polygons (module docstring); a DomainMotion.

    polygons: n + 1 convex polygons (each (k_i, 2), made CCW); spans: n segment durations (s,
    > 0); holds: n + 1 rests (s, >= 0), holds[0] before leaving polygons[0] and holds[i]
    after arriving at polygons[i]; t0: mission time the route starts (s). Before t0 + holds[0]
    and after the last arrival S stands still. goals, speed, hold: the scenario-file form of
    the route (``[domain] kind = "route"``) that :meth:`to_toml` writes, when it has one.
    turns: n angles (rad, CCW), S turning by turns[i] about its centroid on segment i
    (module docstring, "Rotation"; polygons[i + 1] must then be a similarity of
    polygons[i], vertex for vertex); default none turns. legs: a planned tour's figures per
    goal (:class:`Leg`, covswarm.world.planner.plan_tour), what ``covswarm sim`` and ``run``
    print before the mission; () for a route not planned from goals.
    """

    polygons: tuple[np.ndarray, ...]
    spans: tuple[float, ...]
    holds: tuple[float, ...]
    t0: float = 0.0
    goals: tuple[tuple[float, float], ...] = ()
    speed: float | None = None
    hold: float = 0.0
    turns: tuple[float, ...] = ()
    legs: tuple[Leg, ...] = ()
    starts: np.ndarray = field(init=False, repr=False)  # (n,) segment start times, s
    _pairs: tuple[np.ndarray, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        polygons = []
        for i, p in enumerate(self.polygons):
            try:
                polygons.append(validate_convex(p))
            except ValueError as exc:
                raise ValueError(f"route: waypoint {i}: {exc}") from None
        spans = np.array(self.spans, dtype=float).reshape(-1)
        holds = np.array(self.holds, dtype=float).reshape(-1)
        if not polygons:
            raise ValueError("route: needs at least one polygon")
        if len(spans) != len(polygons) - 1 or len(holds) != len(polygons):
            raise ValueError(
                f"route: {len(polygons)} polygons need {len(polygons) - 1} spans and "
                f"{len(polygons)} holds, got {len(spans)} and {len(holds)}"
            )
        if not (np.all(np.isfinite(spans)) and np.all(spans > 0.0)):
            raise ValueError("route: spans must be positive and finite")
        if not (np.all(np.isfinite(holds)) and np.all(holds >= 0.0)) or not math.isfinite(self.t0):
            raise ValueError("route: holds must be finite and >= 0, t0 finite")
        turns = np.zeros(len(spans)) if len(self.turns) == 0 else np.array(self.turns, float)
        if turns.shape != spans.shape or not np.all(np.isfinite(turns)):
            raise ValueError(f"route: need {len(spans)} finite turns, got {self.turns!r}")
        for i in np.flatnonzero(turns):
            _similarity(polygons[i], polygons[i + 1], float(turns[i]), i)
        object.__setattr__(self, "turns", tuple(turns.tolist()))
        starts = self.t0 + np.cumsum(holds[:-1]) + np.concatenate([[0.0], np.cumsum(spans[:-1])])
        object.__setattr__(self, "polygons", tuple(polygons))
        object.__setattr__(self, "spans", tuple(spans.tolist()))
        object.__setattr__(self, "holds", tuple(holds.tolist()))
        object.__setattr__(self, "starts", starts)
        pairs = tuple(
            pairing(a, b) if turn == 0.0 else np.stack([np.arange(len(a))] * 2, axis=1)
            for a, b, turn in zip(polygons[:-1], polygons[1:], turns, strict=True)
        )
        object.__setattr__(self, "_pairs", pairs)

    @classmethod
    def timed(
        cls,
        polygons: list[np.ndarray],
        max_speed: float,
        holds: list[float] | None = None,
        t0: float = 0.0,
        turns: list[float] | None = None,
        **form: Any,
    ) -> RouteMotion:
        """The route through ``polygons`` with each segment as short as the speed limit
        ``max_speed`` (fastest vertex, m/s) allows; consecutive equal polygons are merged
        (unless S turns between them). turns: per segment, rad (default none)."""
        if not (math.isfinite(max_speed) and max_speed > 0.0):
            raise ValueError(f"route: max_speed must be positive, got {max_speed!r}")
        polygons = [validate_convex(p) for p in polygons]
        holds = [0.0] * len(polygons) if holds is None else list(holds)
        turns = [0.0] * (len(polygons) - 1) if turns is None else list(turns)
        if len(turns) != len(polygons) - 1:
            raise ValueError(f"route: {len(polygons)} polygons need {len(polygons) - 1} turns")
        kept, kept_holds, spans, kept_turns = [polygons[0]], [holds[0]], [], []
        for polygon, rest, turn in zip(polygons[1:], holds[1:], turns, strict=True):
            reach = _reach(kept[-1], polygon, float(turn), len(kept) - 1)
            if reach <= 1e-12:  # the same polygon: one waypoint, the rests add up
                kept_holds[-1] += rest
                continue
            kept.append(polygon)
            kept_holds.append(rest)
            kept_turns.append(float(turn))
            spans.append(PEAK_RATE * reach / max_speed)
        return cls(
            tuple(kept), tuple(spans), tuple(kept_holds), t0, turns=tuple(kept_turns), **form
        )

    @property
    def end(self) -> float:
        """Mission time S arrives at the last polygon and its hold ends, s."""
        return self.t0 + sum(self.holds) + sum(self.spans)

    @property
    def arrivals(self) -> np.ndarray:
        """(n,) mission times S arrives at polygons[1:], s."""
        return self.starts + np.array(self.spans)

    def segment(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Segment i's paired vertices (p, 2) at its start A and end B: V = (1 - s) A + s B
        when it does not turn (turns[i] == 0)."""
        pairs = self._pairs[i]
        return self.polygons[i][pairs[:, 0]], self.polygons[i + 1][pairs[:, 1]]

    def along(self, i: int, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Segment i at progress s in [0, 1]: its vertices V(s) (p, 2, m) and dV/ds (p, 2, m)
        (module docstring: paired interpolation, or "Rotation" when it turns)."""
        a, b = self.segment(i)
        turn = self.turns[i]
        if turn == 0.0:
            return (1.0 - s) * a + s * b, b - a
        ca, cb = centroid(a), centroid(b)
        k = _similarity(a, b, turn, i)
        rotated = (a - ca) @ _rotation(s * turn).T  # R(s phi) Q
        sigma = 1.0 - s + s * k
        normal = np.stack([-rotated[:, 1], rotated[:, 0]], axis=1)  # J R(s phi) Q
        return ca + s * (cb - ca) + sigma * rotated, (cb - ca) + (k - 1.0) * rotated + (
            sigma * turn
        ) * normal

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        t = float(t)
        i = int(np.searchsorted(self.starts, t, side="right")) - 1
        if i < 0:
            return self.polygons[0].copy(), np.zeros_like(self.polygons[0])
        span = self.spans[i]
        u = (t - self.starts[i]) / span
        if u >= 1.0:
            return self.polygons[i + 1].copy(), np.zeros_like(self.polygons[i + 1])
        s, ds_du = smoothstep(u)
        vertices, rate = self.along(i, s)
        velocities = rate * (ds_du / span)
        if len(vertices) == len(self.polygons[i]) == len(self.polygons[i + 1]):
            return vertices, velocities  # paired vertex for vertex: none coincide
        return merge_coincident(vertices, velocities)

    def peak_speed(self) -> float:
        """Fastest vertex speed over the route (m/s): (15/8) max |B_j - A_j| / T_i; a bound
        on turning segments (module docstring, "Speed")."""
        peaks = [
            PEAK_RATE * _reach(a, b, turn, i) / span
            for i, (a, b, turn, span) in enumerate(
                zip(self.polygons[:-1], self.polygons[1:], self.turns, self.spans, strict=True)
            )
        ]
        return max(peaks, default=0.0)

    def reach(self, i: int) -> float:
        """A bound (m) on every vertex's |dV/ds| over segment i (module docstring, "Speed")."""
        return _reach(self.polygons[i], self.polygons[i + 1], self.turns[i], i)

    def sample_times(self, duration: float) -> np.ndarray:
        fractions = np.linspace(0.0, 1.0, _SAMPLES + 1)
        segments = [a + span * fractions for a, span in zip(self.starts, self.spans, strict=True)]
        return np.unique(np.concatenate([[0.0, self.t0, self.end], *segments]))

    def to_toml(self) -> str:
        if not self.goals:
            raise ValueError("route: only a route planned from goals has a scenario-file form")
        lines = [
            '[domain]\nkind = "route"',
            f"polygon = {_points(self.polygons[0])}",
            f"goals = {_points(np.array(self.goals))}",
        ]
        if self.speed is not None:
            lines.append(f"speed = {self.speed!r}")
        if self.hold:
            lines.append(f"hold = {self.hold!r}")
        return "\n".join(lines) + "\n"


def _rotation(angle: float) -> np.ndarray:
    """(2, 2) the rotation by ``angle`` rad, CCW."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def _similarity(a: np.ndarray, b: np.ndarray, turn: float, i: int) -> float:
    """The scale k of b = c_b + k R(turn) (a - c_a) (a, b (n, 2), vertex for vertex);
    ValueError naming segment i when b is no such image of a."""
    if len(a) != len(b):
        raise ValueError(f"route: segment {i} turns, so its ends need the same vertex count")
    qa, qb = a - centroid(a), b - centroid(b)
    k = math.sqrt(float((qb**2).sum()) / float((qa**2).sum()))
    residual = float(np.abs(k * qa @ _rotation(turn).T - qb).max())
    if residual > 1e-9 * max(1.0, float(np.abs(qb).max())):
        raise ValueError(
            f"route: segment {i} turns by {turn!r} rad, but its end is not its start turned "
            "by that and scaled (vertex for vertex)"
        )
    return k


def _reach(a: np.ndarray, b: np.ndarray, turn: float, i: int) -> float:
    """A bound (m) on every vertex's |dV/ds| from a to b turning by ``turn`` rad (exact,
    max |B_j - A_j|, when it does not turn; module docstring, "Speed")."""
    if turn == 0.0:
        pairs = pairing(a, b)
        return float(np.linalg.norm(b[pairs[:, 1]] - a[pairs[:, 0]], axis=1).max())
    k = _similarity(a, b, turn, i)
    radius = float(np.linalg.norm(a - centroid(a), axis=1).max())
    shift = float(np.linalg.norm(centroid(b) - centroid(a)))
    return shift + (abs(k - 1.0) + max(1.0, k) * abs(turn)) * radius


def _points(points: np.ndarray) -> str:
    return "[" + ", ".join(f"[{float(x)!r}, {float(y)!r}]" for x, y in points) + "]"


def merge_coincident(vertices: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop vertices equal to the previous one (a support-point pairing near s = 0 or 1 has
    edges of length s |e|); the dropped vertex's velocity differs from the kept one's by at
    most s'(t) |e|, vanishing there (s' = 30 u^2 where s = 10 u^3)."""
    size = 0.5 * float(np.linalg.norm(np.roll(vertices, -1, axis=0) - vertices, axis=1).sum())
    step = np.linalg.norm(vertices - np.roll(vertices, 1, axis=0), axis=1)
    keep = step > _MERGE_TOL * size
    if keep.all():
        return vertices, velocities
    if not keep.any():
        keep[0] = True
    return vertices[keep], velocities[keep]
