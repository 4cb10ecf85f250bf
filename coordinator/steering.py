"""Steering S live: from an accepted SteerRequest to a smooth, always-convex S(t).

Pure (numpy, no I/O): :class:`Steering` is the coordinator's sans-IO state machine. It owns
the domain once a request is accepted (the scenario's script is abandoned from that instant,
S then holds wherever the last motion left it), refuses with a reason anything infeasible
without moving S, and records every request for summary.json.

Motions. Every motion runs a smooth progress s(t) = 10u^3 - 15u^4 + 6u^5, u = (t - t0)/T
(quintic smoothstep: s' = s'' = 0 at both ends, so S starts and stops without a jerk in the
feedforward), and the vertex velocities are the exact time derivatives, which the agents'
feedforward term (paper Eq. 9's boundary integral) needs:

- translate / rotate / scale (:class:`Similarity`): V(s) = c + sigma(s) R(s a)(A - c) + s d,
  sigma(s) = 1 + s (f - 1): a similarity of the convex start polygon A, convex at every
  instant with A's vertex count;
- polygon (:class:`Morph`): the Minkowski interpolation (1 - s) A + s B of two convex
  polygons, convex for every s in [0, 1] with any vertex counts. Its vertices are pairs of
  support points: for each direction strictly between consecutive edge normals of A and B
  (merged), V = (1 - s) a_i + s b_j with a_i, b_j the points of A and B furthest along it,
  so dV/dt = s'(t) (b_j - a_i) exactly; the pairing is the same for every s in (0, 1).

Pre-emption. A new request pre-empts the motion in progress (or the scenario's script)
without a jump in S's position, velocity or acceleration. A moving S first brakes along the
path it was on (:class:`Brake`): V(t) = M(tau(t)) with M the motion being left and the warped
time tau(t) = t0 + T g(u), g(u) = u - u^2 + u^3 / 3, u = (t - t0) / T, so tau' = (1 - u)^2
runs from 1 down to 0 with tau'' = 0 at the end. S then only revisits shapes M passed
through (convex, inside the workspace, never faster than M: |dV/dt| = |M'| tau' <= |M'|) and
stops at M(t0 + T/3); T = 2 v / BRAKE_DECELERATION for its fastest vertex speed v, so that
vertex slows at most BRAKE_DECELERATION beyond M's own acceleration. The new motion is
planned from where S stops and starts then, its velocity from zero (s'(0) = 0). A request
that arrives while S brakes replaces what follows that brake (brakes never nest); an S at
rest (the default still S, a motion that ended) does not brake: the new motion starts at
once.

Speed. The fastest vertex of a motion moves at max_u s'(u) max_s |dV/ds| =
(15/8 T) max_s |dV/ds|, so T is chosen (or a requested duration stretched) to keep it at or
under the limit: ``max_domain_speed`` (default :func:`default_max_domain_speed`).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from covswarm.mission.crowding import least_domain, robot_room
from covswarm.protocol.messages import MAX_VERTICES, ProtocolError
from covswarm.protocol.steering import (
    MAX_DURATION,
    MAX_FACTOR,
    MAX_REASON,
    MAX_ROUTE,
    SteerReply,
    SteerRequest,
)
from covswarm.tvd.coverage import signed_area, validate_polygon
from covswarm.tvd.drive import KHEPERA_IV
from covswarm.tvd.safety import DEFAULT_MARGIN
from covswarm.world.model import World
from covswarm.world.planner import NoPath, plan_route
from covswarm.world.route import (
    PEAK_RATE,
    RouteMotion,
    centroid,
    merge_coincident,
    smoothstep,
    support_pairs,
)
from covswarm.world.sweep import first_contact

Box = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax
DomainAt = Callable[[float], tuple[np.ndarray, np.ndarray]]
# A veto on a planned motion of S: called with the motion (S at mission time t is
# motion(t)), its start and its end (s of mission time); raises Refusal to refuse the request
# (e.g. S would sweep an obstacle). Steering.checks holds them.
MotionCheck = Callable[[DomainAt, float, float], None]

# Refusal codes (the first word of a refused SteerReply's reason), counted per code.
REFUSALS = (
    "undecodable",  # the payload is not a valid SteerRequest (oversize, schema, types, ...)
    "nonfinite",  # NaN or inf in it
    "non-convex",
    "self-intersecting",
    "degenerate",  # zero area, repeated vertices
    "outside-workspace",
    "too-small",  # less area per robot than MIN_ROOMS robot rooms
    "too-slow",  # the motion would take longer than protocol.steering.MAX_DURATION
    "not-running",  # before the mission starts or after it ended
    "rate-limited",  # the requester's token bucket is empty (RequestLimiter)
    "obstacle",  # S would touch an obstacle or leave the workspace during the motion
    "no-path",  # goto: no route for S (covswarm.world.planner.NoPath's code and why)
)
# Least area of S per robot, in robot rooms (covswarm.mission.crowding.robot_room: hexagonal
# packing at the safety filter's distance, the limit below which the crowding warning says a
# uniform team cannot reach its CVT): a target is refused at twice that, well before robots
# could not fit at all (2 rooms are 2.9 footprints pi r^2 of a Khepera IV).
MIN_ROOMS = 2.0
FOLLOW_GAP = 0.14  # m (a Khepera IV's diameter): the gap the robots must still close
WORKSPACE_SLACK = 1e-9  # m: vertices on the workspace's edge are inside
# m: S within this of an obstacle touches it (the scenario's check at load,
# covswarm.mission.scenarios.CONTACT_TOLERANCE).
CONTACT_TOLERANCE = 1e-4
_ROTATION_SAMPLES = 65  # instants at which a rotating motion is checked against the walls
# m/s^2: the most a pre-empted S's fastest vertex is slowed by its brake (module docstring).
# About what the quintic asks when starting a 0.5 m move at the default 0.52 m/s
# (10 / sqrt(3) x 0.5 m / (1.8 s)^2 = 0.89 m/s^2): a brake is no harsher than a start.
BRAKE_DECELERATION = 1.0
# Steering requests per requester (RequestLimiter): a token bucket of STEER_BURST requests
# refilled at STEER_RATE per second. An operator clicks a few times a second at most; a
# flood (10 893 valid queries in 5 s, issue 21) costs a count, not the records or the disk.
STEER_RATE = 2.0  # 1/s
STEER_BURST = 10
MAX_REQUESTERS = 64  # distinct requester keys tracked; the rest share one bucket
UNKNOWN_REQUESTER = "(unknown)"
# summary.json and the recorder keep the first and the last this many requests, and count
# those omitted between (SteeringRecords).
RECORDS_HEAD = 100
RECORDS_TAIL = 100


def default_max_domain_speed(robot_speed: float, kappa: float) -> float:
    """Fastest S vertex (m/s) the team can follow: what is left of the robots' top speed
    ``robot_speed`` (m/s) after closing a FOLLOW_GAP lag at gain ``kappa`` (1/s), and at least
    a quarter of the top speed (the circle scenario's 0.19 m/s at kappa = 8, 0.8 m/s robots).
    """
    return max(robot_speed - kappa * FOLLOW_GAP, 0.25 * robot_speed)


@dataclass(frozen=True, eq=False)
class Hold:
    """S standing still at ``polygon`` (k, 2)."""

    polygon: np.ndarray

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.polygon.copy(), np.zeros_like(self.polygon)


@dataclass(frozen=True, eq=False)
class Similarity:
    """V(t) = c + sigma R(theta)(A - c) + s d with s = smoothstep((t - t0)/T),
    theta = s angle, sigma = 1 + s (factor - 1). start: (k, 2) CCW; about, shift: (2,) m."""

    start: np.ndarray
    t0: float
    span: float  # T, s (> 0)
    about: np.ndarray
    shift: np.ndarray
    angle: float  # rad
    factor: float

    def at_progress(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Vertices at progress s and their derivative dV/ds."""
        theta, sigma = s * self.angle, 1.0 + s * (self.factor - 1.0)
        cos, sin = math.cos(theta), math.sin(theta)
        arm = (self.start - self.about) @ np.array([[cos, sin], [-sin, cos]])  # R (A - c)
        turned = np.stack([-arm[:, 1], arm[:, 0]], axis=1)  # J R (A - c)
        vertices = self.about + sigma * arm + s * self.shift
        rate = (self.factor - 1.0) * arm + sigma * self.angle * turned + self.shift
        return vertices, rate

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s, ds_du = smoothstep((t - self.t0) / self.span)
        vertices, rate = self.at_progress(s)
        return vertices, rate * (ds_du / self.span)

    def peak_rate(self) -> float:
        """A bound on max_s max_i |dV_i/ds| (m per unit progress)."""
        radius = float(np.linalg.norm(self.start - self.about, axis=1).max())
        sigma = max(1.0, self.factor)
        return (
            abs(self.factor - 1.0) * radius
            + sigma * abs(self.angle) * radius
            + float(np.linalg.norm(self.shift))
        )


@dataclass(frozen=True, eq=False)
class Morph:
    """(1 - s) A + s B for convex CCW polygons A (n, 2) and B (m, 2), s = smoothstep.

    ``pairs`` (p, 2) int: the support-point pairs (module docstring); at u >= 1 S is B
    itself (the same set as the last combination, without its zero-length edges).
    """

    start: np.ndarray
    target: np.ndarray
    t0: float
    span: float
    pairs: np.ndarray

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        u = (t - self.t0) / self.span
        if u >= 1.0:
            return self.target.copy(), np.zeros_like(self.target)
        s, ds_du = smoothstep(u)
        a, b = self.start[self.pairs[:, 0]], self.target[self.pairs[:, 1]]
        vertices = (1.0 - s) * a + s * b
        velocities = (b - a) * (ds_du / self.span)
        return merge_coincident(vertices, velocities)

    def peak_rate(self) -> float:
        """max_i |dV_i/ds| = max |b_j - a_i| over the pairs (m per unit progress)."""
        a, b = self.start[self.pairs[:, 0]], self.target[self.pairs[:, 1]]
        return float(np.linalg.norm(b - a, axis=1).max())


@dataclass(frozen=True, eq=False)
class Brake:
    """S slowing to a stop along ``motion`` from ``t0`` for ``span`` s, then ``then``.

    V(t) = motion(tau(t)) with tau(t) = t0 + span g(u), g(u) = u - u^2 + u^3 / 3, u = (t - t0)
    / span (module docstring); velocities motion's times tau'(t) = (1 - u)^2. ``then`` (the
    pre-empting motion, planned from motion(:attr:`stop_time`)) takes over at t0 + span.
    """

    motion: DomainAt
    t0: float
    span: float  # s (> 0)
    then: DomainAt

    @property
    def end(self) -> float:
        return self.t0 + self.span

    @property
    def stop_time(self) -> float:
        """The time of ``motion`` at which S stops: tau at the brake's end."""
        return self.t0 + self.span / 3.0

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        if t >= self.end:
            return self.then(t)
        u = max(t - self.t0, 0.0) / self.span
        vertices, velocities = self.motion(self.t0 + self.span * u * (1.0 - u + u * u / 3.0))
        return vertices, velocities * (1.0 - u) ** 2


def brake_span(speed: float) -> float:
    """Seconds a brake takes from a fastest vertex speed ``speed`` (m/s) at
    BRAKE_DECELERATION (the brake's tau'' = -2 / T at its start)."""
    return 2.0 * speed / BRAKE_DECELERATION


def simplify(polygon: np.ndarray, count: int) -> tuple[np.ndarray, float]:
    """Remove vertices of a convex CCW polygon (k, 2) until at most ``count`` are left.

    Each step drops the vertex whose triangle with its neighbours is the smallest
    (Visvalingam); returns the polygon and how far S jumped: the largest distance from a
    dropped vertex to the edge that replaced it (m). Used only when a pre-empted Morph's
    S plus the new target would exceed the wire's MAX_VERTICES.
    """
    points = [np.asarray(p, dtype=float) for p in polygon]
    jump = 0.0
    while len(points) > count:
        areas, heights = [], []
        for i, p in enumerate(points):
            prev, nxt = points[i - 1], points[(i + 1) % len(points)]
            (ux, uy), (vx, vy) = p - prev, nxt - prev
            cross = abs(float(ux * vy - uy * vx))
            areas.append(cross)
            heights.append(cross / max(float(np.linalg.norm(nxt - prev)), 1e-300))
        drop = int(np.argmin(areas))
        jump = max(jump, heights[drop])
        del points[drop]
    return np.array(points), jump


@dataclass(frozen=True)
class Limits:
    """Feasibility of steering requests.

    max_speed: fastest vertex, m/s; workspace: box S must stay in (None: anywhere);
    min_area: least area of S, m^2 (team size x MIN_ROOMS robot rooms); min_width: least
    width a goto's route may shrink S to, m (a robot body with its clearance either side:
    covswarm.mission.crowding.least_domain).
    """

    max_speed: float
    workspace: Box | None
    min_area: float
    min_width: float = 0.0

    @classmethod
    def for_team(
        cls,
        agents: int,
        max_speed: float,
        workspace: Box | None,
        robot_diameter: float = KHEPERA_IV.body_diameter,
    ) -> Limits:
        room = robot_room(robot_diameter, DEFAULT_MARGIN)
        _, min_width = least_domain(agents, robot_diameter, DEFAULT_MARGIN)
        return cls(max_speed, workspace, agents * MIN_ROOMS * room, min_width)


class Refusal(ValueError):
    """A request that must not move S: ``code`` (one of REFUSALS) and why."""

    def __init__(self, code: str, why: str) -> None:
        super().__init__(f"{code}: {why}")
        self.code = code


def check_target(
    polygon: np.ndarray, limits: Limits, current_area: float = math.inf, what: str = "target"
) -> np.ndarray:
    """The convex polygon ``polygon`` (k, 2) made CCW, or Refusal with the reason.

    Too small means under ``limits.min_area`` and smaller than S is now (``current_area``,
    m^2): a request never has to make a crowded S bigger to be accepted.
    """
    try:
        vertices = validate_polygon(np.asarray(polygon, dtype=float))
    except ValueError as exc:
        text = str(exc)
        if "NaN" in text:
            code = "nonfinite"
        elif "not convex" in text:
            code = "non-convex"
        elif "self-intersecting" in text:
            code = "self-intersecting"
        else:
            code = "degenerate"
        raise Refusal(code, text) from None
    _check_inside(vertices, limits, what)
    area = signed_area(vertices)
    if area < min(limits.min_area, current_area):
        raise Refusal(
            "too-small",
            f"{what} has {area:.3g} m^2, the team needs at least {limits.min_area:.3g} m^2",
        )
    return vertices


def _check_inside(vertices: np.ndarray, limits: Limits, what: str) -> None:
    if limits.workspace is None:
        return
    xmin, xmax, ymin, ymax = limits.workspace
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    slack = WORKSPACE_SLACK
    if (
        low[0] + slack < xmin
        or high[0] - slack > xmax
        or low[1] + slack < ymin
        or high[1] - slack > ymax
    ):
        # to the millimetre: 3 significant figures hid a 2 mm overshoot (2.59 against 2.591)
        reach = f"[{low[0]:.3f}, {high[0]:.3f}] x [{low[1]:.3f}, {high[1]:.3f}] m"
        over = max(xmin - low[0], high[0] - xmax, ymin - low[1], high[1] - ymax)
        raise Refusal(
            "outside-workspace",
            f"{what} reaches {reach}, {over * 1e3:.0f} mm outside the workspace "
            f"[{xmin:g}, {xmax:g}] x [{ymin:g}, {ymax:g}] m",
        )


def motion_speed(motion: DomainAt) -> float | None:
    """A proven bound on every vertex's speed (m/s) over a planned motion, or None if its
    kind has none (first_contact then samples the speeds)."""
    if isinstance(motion, Hold):
        return 0.0
    if isinstance(motion, (Similarity, Morph)):
        return PEAK_RATE * motion.peak_rate() / motion.span
    if isinstance(motion, RouteMotion):
        return motion.peak_speed()
    return None


def motion_span(motion: DomainAt, start: float) -> float:
    """Seconds from ``start`` until a planned motion ends (S at rest at its target)."""
    if isinstance(motion, RouteMotion):
        return motion.end - start
    return getattr(motion, "span", 0.0)


def world_check(world: World, tolerance: float = CONTACT_TOLERANCE) -> MotionCheck:
    """The MotionCheck that refuses ("obstacle") a motion whose S comes within
    ``tolerance`` m of one of ``world``'s obstacles, or leaves its workspace, at any instant
    from its start to its end: covswarm.world.sweep.first_contact over the whole motion,
    with the motion's exact speed bound (motion_speed), so no instant is skipped."""

    def check(motion: DomainAt, begin: float, end: float) -> None:
        contact = first_contact(
            motion, begin, end, world, tolerance=tolerance, speed=motion_speed(motion)
        )
        if contact is None:
            return
        what = (
            "leave the workspace"
            if contact.obstacle == "workspace"
            else f"touch obstacle {world.describe(contact.obstacle)}"
        )
        raise Refusal("obstacle", f"S would {what} at t = {contact.time:.2f} s")

    return check


def plan_goto(
    request: SteerRequest, t: float, current: np.ndarray, limits: Limits, world: World
) -> tuple[RouteMotion, str, tuple[tuple[float, ...], ...]]:
    """A goto's route from S = ``current`` (k, 2, CCW) at mission time ``t`` through
    ``world`` (covswarm.world.planner.plan_route): (motion, note, stops for the reply).
    Refusal "no-path" (with the planner's code and why) when there is none."""
    note = ""
    speed = limits.max_speed if request.speed is None else request.speed
    if speed > limits.max_speed:
        note = f"speed clipped to {limits.max_speed:.3g} m/s"
        speed = limits.max_speed
    goal_polygon = None
    if request.polygon is not None:
        # S's shape at the goal, placed there (centroid on the goal) before it is held to
        # the workspace: where it was typed says nothing.
        shape = check_target(
            np.array(request.polygon),
            replace(limits, workspace=None),
            signed_area(current),
            "goal polygon",
        )
        goal_polygon = shape - centroid(shape) + np.asarray(request.goal, dtype=float)
        _check_inside(goal_polygon, limits, "the goal polygon at the goal")
    try:
        route = plan_route(
            world,
            current,
            request.goal,
            goal_polygon=goal_polygon,
            min_area=min(limits.min_area, signed_area(current)),
            min_width=limits.min_width,
            max_speed=speed,
            t0=t,
        )
    except NoPath as exc:
        raise Refusal("no-path", str(exc)) from None
    except ValueError as exc:  # a goal or polygon the planner cannot take
        raise Refusal("degenerate", str(exc)) from None
    if route.duration > MAX_DURATION:
        raise Refusal("too-slow", f"the route takes {route.duration:.3g} s (> {MAX_DURATION:g} s)")
    # (x, y, scale), and the angle S is turned by where it is (SteerReply.route).
    stops = tuple(
        (w.centroid[0], w.centroid[1], min(max(w.scale, 1e-9), MAX_FACTOR))
        + ((w.angle,) if w.angle != 0.0 else ())
        for w in route.waypoints
    )
    if len(stops) > MAX_ROUTE:  # the reply shows the first stops and the goal
        stops = stops[: MAX_ROUTE - 1] + stops[-1:]
    return route.motion, note, stops


def plan(
    request: SteerRequest, t: float, current: np.ndarray, limits: Limits
) -> tuple[Hold | Similarity | Morph, str, float]:
    """The motion that carries out ``request`` (any kind but goto: :func:`plan_goto`) from
    S = ``current`` (k, 2, CCW) at mission time ``t``: (motion, note, jump). Raises Refusal
    when it is infeasible.

    note: "" or why the duration differs from the one asked for; jump: how far S had to
    jump to fit the wire's vertex limit (simplify), 0 almost always.
    """
    jump = 0.0
    if request.kind == "polygon":
        target = check_target(np.array(request.polygon), limits, signed_area(current))
        start = current
        if len(start) + len(target) > MAX_VERTICES:
            start, jump = simplify(start, MAX_VERTICES - len(target))
        motion: Any = Morph(start, target, t, 1.0, support_pairs(start, target))
    else:
        about = centroid(current) if request.about is None else np.array(request.about, dtype=float)
        motion = Similarity(
            start=current,
            t0=t,
            span=1.0,
            about=about,
            shift=np.array([request.dx, request.dy]),
            angle=request.angle,
            factor=request.factor,
        )
        final, _ = motion.at_progress(1.0)
        check_target(final, limits, signed_area(current))
        if request.angle != 0.0:  # vertices sweep arcs that may leave the walls midway
            for s in np.linspace(0.0, 1.0, _ROTATION_SAMPLES)[1:-1]:
                _check_inside(motion.at_progress(float(s))[0], limits, f"S at {s:.0%} of the way")
    rate = motion.peak_rate()
    if rate <= 0.0:  # nothing to move: stop where S is
        return Hold(current.copy()), "", jump
    fastest = PEAK_RATE * rate / limits.max_speed
    note = ""
    if request.duration is not None:
        span = max(request.duration, fastest)
        if span > request.duration:
            note = (
                f"duration stretched to {span:.3g} s (max domain speed {limits.max_speed:.3g} m/s)"
            )
    else:
        speed = limits.max_speed if request.speed is None else request.speed
        if speed > limits.max_speed:
            note = f"speed clipped to {limits.max_speed:.3g} m/s"
            speed = limits.max_speed
        span = PEAK_RATE * rate / speed
    if span > MAX_DURATION:
        raise Refusal("too-slow", f"the motion would take {span:.3g} s (> {MAX_DURATION:g} s)")
    return replace(motion, span=span), note, jump


@dataclass
class SteeringRecord:
    """One request as summary.json lists it."""

    t: float  # mission time of arrival, s
    wall: float  # s since the epoch
    request: dict[str, Any] | None  # SteerRequest.to_dict(), None when undecodable
    accepted: bool
    reason: str
    duration: float  # s until S arrives, a brake included (0 if refused)

    def to_dict(self) -> dict[str, Any]:
        return {
            "t": self.t,
            "wall": self.wall,
            "request": self.request,
            "accepted": self.accepted,
            "reason": self.reason,
            "duration": self.duration,
        }


def requester_key(source_info: Any) -> str:
    """The requester a steering query came from, as a key for RequestLimiter: the Zenoh
    source (session id and entity) when the querier attached one (``query.source_info``:
    zenoh 1.x fills it only if the querier passes it), else UNKNOWN_REQUESTER. In open mode
    a source can be forged like everything else: only secure mode ties it to a role."""
    source = getattr(source_info, "source_id", None)
    if source is None:
        return UNKNOWN_REQUESTER
    return f"{getattr(source, 'zid', '?')}/{getattr(source, 'eid', '?')}"


class RequestLimiter:
    """A token bucket per requester key: ``burst`` requests at once, ``rate`` per second
    sustained. At most ``max_keys`` keys are tracked (a flood of forged sources must not
    grow the table): beyond, new keys share one bucket. ``now``: monotonic or wall seconds,
    one clock throughout (a clock stepping back refills nothing)."""

    def __init__(
        self, rate: float = STEER_RATE, burst: int = STEER_BURST, max_keys: int = MAX_REQUESTERS
    ) -> None:
        if not (rate > 0.0 and burst >= 1 and max_keys >= 1):
            raise ValueError(f"RequestLimiter: rate {rate} > 0 and burst {burst} >= 1 needed")
        self.rate, self.burst, self.max_keys = rate, burst, max_keys
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, when)

    def allow(self, key: str, now: float) -> bool:
        """Take one token of ``key``'s bucket at ``now`` s; False when it is empty."""
        if key not in self._buckets and len(self._buckets) >= self.max_keys:
            self._forget_full(now)
            if len(self._buckets) >= self.max_keys:
                key = "(overflow)"
        tokens, when = self._buckets.get(key, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + max(now - when, 0.0) * self.rate)
        if tokens < 1.0:
            self._buckets[key] = (tokens, max(now, when))
            return False
        self._buckets[key] = (tokens - 1.0, max(now, when))
        return True

    def _forget_full(self, now: float) -> None:
        """Drop the buckets that have refilled (they are as good as new)."""
        for key in [
            k
            for k, (tokens, when) in self._buckets.items()
            if tokens + max(now - when, 0.0) * self.rate >= self.burst
        ]:
            del self._buckets[key]


class SteeringRecords:
    """The requests summary.json lists: the first ``head`` and the last ``tail`` kept,
    ``omitted`` counts those between. Iterates in order; ``[-1]`` is the last appended."""

    def __init__(self, head: int = RECORDS_HEAD, tail: int = RECORDS_TAIL) -> None:
        from collections import deque

        self.head: list[SteeringRecord] = []
        self.tail: deque[SteeringRecord] = deque(maxlen=max(tail, 1))
        self._head_size = head
        self.omitted = 0

    def append(self, record: SteeringRecord) -> None:
        if len(self.head) < self._head_size:
            self.head.append(record)
            return
        if len(self.tail) == self.tail.maxlen:
            self.omitted += 1
        self.tail.append(record)

    def __len__(self) -> int:
        return len(self.head) + len(self.tail)

    def __iter__(self) -> Any:
        yield from self.head
        yield from self.tail

    def __getitem__(self, index: int) -> SteeringRecord:
        return list(self)[index] if index != -1 else (self.tail or self.head)[-1]


@dataclass
class Steering:
    """Who moves S: the scenario's script until the first accepted request, then steering.

    ``script``: the scenario's S(t) (mission.scenarios.Scenario.domain); ``world``: the
    arena a goto is planned through (None: the limits' workspace, no obstacles).
    """

    script: DomainAt
    limits: Limits
    motion: Hold | Similarity | Morph | RouteMotion | Brake | None = None
    records: SteeringRecords = field(default_factory=SteeringRecords)
    refused: Counter = field(default_factory=Counter)  # refusals per code
    largest_jump: float = 0.0  # m, see simplify
    checks: tuple[MotionCheck, ...] = ()  # vetoes on a planned motion, in order
    limiter: RequestLimiter = field(default_factory=RequestLimiter)
    world: World | None = None
    # The stops of the accepted goto S follows (its reply's route) and the mission time S
    # arrives; None once another request is accepted (see active_route).
    route: tuple[tuple[float, ...], ...] | None = None
    route_end: float = 0.0
    # Script time the mission ends (s): a motion that arrives later is accepted (the operator
    # may mean to watch it start) with a note that S will not get there.
    end: float = math.inf

    def domain(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """S(t): CCW vertices (k, 2) and their exact velocities (k, 2)."""
        return self.script(t) if self.motion is None else self.motion(t)

    def handle(
        self, payload: Any, t: float, wall: float, running: bool, requester: str | None = None
    ) -> SteerReply:
        """Decode, check and (if feasible) start one request at mission time ``t``.

        A refused request changes nothing but the records and the refusal counts.
        ``requester`` (requester_key of the query; None: not rate-limited, as for a
        journal's replay): one whose bucket is empty is refused ("rate-limited") before
        the payload is even decoded.
        """
        if requester is not None and not self.limiter.allow(requester, wall):
            return self._refuse(
                Refusal("rate-limited", f"more than {self.limiter.rate:g} requests/s"),
                None,
                t,
                wall,
            )
        try:
            request = SteerRequest.decode(payload)
        except ProtocolError as exc:
            code = "nonfinite" if exc.reason == "nonfinite" else "undecodable"
            return self._refuse(Refusal(code, str(exc)), None, t, wall)
        if not running:
            return self._refuse(
                Refusal("not-running", "the mission is not running"), request, t, wall
            )
        current, velocity = self.domain(t)
        brake = self._brake_at(t, velocity)
        start, lead = t, 0.0  # when the new motion starts, s of braking before it
        if brake is not None:
            start, lead = brake.end, brake.end - t
            current, _ = brake.motion(brake.stop_time)  # where the brake stops S
        stops = None
        try:
            current = np.asarray(current, dtype=float)
            if request.kind == "goto":
                world = self.world if self.world is not None else World(self.limits.workspace)
                motion, note, stops = plan_goto(request, start, current, self.limits, world)
                jump = 0.0
            else:
                motion, note, jump = plan(request, start, current, self.limits)
            span = lead + motion_span(motion, start)
            if span > MAX_DURATION:  # plan() checked the motion alone
                raise Refusal(
                    "too-slow", f"braking {lead:.2g} s and the motion exceed {MAX_DURATION:g} s"
                )
            for check in self.checks:
                check(motion, start, start + span - lead)
        except Refusal as refusal:
            return self._refuse(refusal, request, t, wall)
        if brake is not None:
            motion = replace(brake, then=motion)
            if lead >= 1e-3:  # a brake under a millisecond is none to speak of
                note = "; ".join(filter(None, [f"braking {lead:.2g} s first", note]))
        if t + span > self.end:
            late = f"S arrives at t = {t + span:.1f} s, after the mission ends ({self.end:g} s)"
            note = "; ".join(filter(None, [note, late]))
        self.motion = motion
        self.route, self.route_end = stops, t + span
        self.largest_jump = max(self.largest_jump, jump)
        reply = SteerReply(True, note[:MAX_REASON], span, stops)
        self.records.append(SteeringRecord(t, wall, request.to_dict(), True, note, span))
        return reply

    def active_route(self, t: float) -> tuple[tuple[float, ...], ...] | None:
        """The stops of the goto S follows at mission time ``t`` (whoever asked for it), None
        when S follows no route: no goto accepted, another request accepted since, or S
        arrived."""
        return self.route if self.route is not None and t < self.route_end else None

    def _brake_at(self, t: float, velocity: np.ndarray) -> Brake | None:
        """How S comes to rest before a request at ``t`` takes over: the brake in progress (a
        later request only replaces what follows it, so brakes never nest), a new brake of
        whatever moves S at ``velocity`` (k, 2), or None when S is at rest."""
        if isinstance(self.motion, Brake) and t < self.motion.end:
            return self.motion
        speed = float(np.linalg.norm(velocity, axis=1).max()) if len(velocity) else 0.0
        if speed == 0.0:
            return None
        moving = self.motion.then if isinstance(self.motion, Brake) else self.motion
        leaving = self.script if moving is None else moving
        return Brake(leaving, t, brake_span(speed), leaving)

    def replay(self, lines: list[str]) -> int:
        """Carry out again the accepted requests of a journal (one :meth:`journal_line`
        each, in order): a restarted coordinator (``--resume``) puts S back where the
        steering took it. Motions depend only on the request, its time and S then, so the
        replay is exact. Returns how many lines were replayed; unreadable ones are skipped.
        """
        replayed = 0
        for line in lines:
            try:
                entry = json.loads(line)
                request = SteerRequest(**entry["request"])
                t, wall = float(entry["t"]), float(entry["wall"])
            except (ValueError, TypeError, KeyError):
                continue
            replayed += self.handle(request.encode(), t, wall, True).accepted
        return replayed

    def journal_line(self) -> str:
        """The last record as one JSON line of the journal that :meth:`replay` reads."""
        record = self.records[-1]
        return json.dumps({"t": record.t, "wall": record.wall, "request": record.request})

    def _refuse(
        self, refusal: Refusal, request: SteerRequest | None, t: float, wall: float
    ) -> SteerReply:
        self.refused[refusal.code] += 1
        reason = str(refusal)[:MAX_REASON]
        record = SteeringRecord(
            t, wall, None if request is None else request.to_dict(), False, reason, 0.0
        )
        self.records.append(record)
        return SteerReply(False, reason, 0.0)
