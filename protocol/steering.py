"""Steering messages: an operator's (or a planner's) request to move S, and the answer.

A client sends a :class:`SteerRequest` as the payload of a Zenoh query on
``protocol.steer_key(swarm)``; the coordinator's queryable answers with one
:class:`SteerReply` (accepted, or refused with the reason). Both are strict wire messages like
the others (protocol.messages): versioned msgpack maps, size-limited, unknown fields refused,
ProtocolError with the reason. Pure: no zenoh.

Request kinds (``about`` defaults to S's centroid; ``duration`` xor ``speed`` is optional,
absent means "as fast as the swarm can follow", see coordinator.steering):

- ``translate``: move S by (dx, dy) m;
- ``rotate``: turn S by ``angle`` rad (counter-clockwise positive) about ``about``;
- ``scale``: scale S by ``factor`` (> 0) about ``about``;
- ``polygon``: morph S into the convex polygon ``polygon`` (any vertex count, either
  orientation; convexity is checked by the coordinator, which can say why it refuses);
- ``goto``: take S's centroid to ``goal`` (x, y) m through free space, S shrinking for
  doors and growing back (the coordinator plans the route: covswarm.world.planner), with
  S's shape there ``polygon`` (optional; placed with its centroid on the goal). The reply
  carries the planned ``route``. A goto takes a ``speed``, not a ``duration``.

Fields a kind does not use must keep their neutral value (dx = dy = 0, angle = 0,
factor = 1, polygon, about and goal absent), so a request cannot mean two things.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from covswarm.protocol.messages import (
    MAX_ANGLE,
    MAX_COORD,
    MAX_VERTICES,
    Checker,
    Message,
    ProtocolError,
    _choice,
    _optional,
    _points,
    _positive,
    _real,
    route_stops,
)

KINDS = ("translate", "rotate", "scale", "polygon", "goto")
MAX_FACTOR = 100.0  # scale factors in (0, MAX_FACTOR]
MAX_DURATION = 3600.0  # s
MAX_STEER_SPEED = 100.0  # m/s (the coordinator clips to --max-domain-speed anyway)
MAX_REASON = 300  # characters of a refusal reason
MAX_ROUTE = 128  # waypoints in a SteerReply's route


def _point(value: Any, name: str) -> tuple[float, float]:
    """One [x, y] pair within MAX_COORD, returned as a float pair."""
    return _points(1, 1, MAX_COORD)([value], name)[0]


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        raise ProtocolError(f"{name}: expected true or false, got {type(value).__name__}")
    return value


def _text(max_len: int) -> Checker:
    def check(value: Any, name: str) -> str:
        if not isinstance(value, str):
            raise ProtocolError(f"{name}: expected a string, got {type(value).__name__}")
        if len(value) > max_len:
            raise ProtocolError(f"{name}: {len(value)} characters, at most {max_len}")
        return value

    return check


@dataclass(frozen=True, slots=True)
class SteerRequest(Message):
    """Client -> coordinator: move S (module docstring for the kinds).

    dx, dy: m (translate); angle: rad, CCW positive (rotate); factor: > 0 (scale);
    polygon: (k, 2) target vertices, m (polygon; goto: S's shape at the goal, optional);
    about: (x, y) m, the fixed point of a rotation or scaling (None: S's centroid); goal:
    (x, y) m where S's centroid should end (goto); duration: s the motion should take, or
    speed: m/s of the fastest vertex (both None: the coordinator's fastest).
    """

    kind: str
    dx: float = 0.0
    dy: float = 0.0
    angle: float = 0.0
    factor: float = 1.0
    polygon: tuple[tuple[float, float], ...] | None = None
    about: tuple[float, float] | None = None
    duration: float | None = None
    speed: float | None = None
    goal: tuple[float, float] | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "kind": _choice(KINDS),
        "dx": _real(-MAX_COORD, MAX_COORD),
        "dy": _real(-MAX_COORD, MAX_COORD),
        "angle": _real(-MAX_ANGLE, MAX_ANGLE),
        "factor": _positive(MAX_FACTOR),
        "polygon": _optional(_points(3, MAX_VERTICES, MAX_COORD)),
        "about": _optional(_point),
        "duration": _optional(_positive(MAX_DURATION)),
        "speed": _optional(_positive(MAX_STEER_SPEED)),
        "goal": _optional(_point),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset(
        {"polygon", "about", "duration", "speed", "goal"}
    )

    def _check_fields(self) -> None:
        kind = self.kind
        unused = []
        if kind != "translate" and (self.dx != 0.0 or self.dy != 0.0):
            unused.append("dx/dy")
        if kind != "rotate" and self.angle != 0.0:
            unused.append("angle")
        if kind != "scale" and self.factor != 1.0:
            unused.append("factor")
        if kind not in ("polygon", "goto") and self.polygon is not None:
            unused.append("polygon")
        if kind in ("translate", "polygon", "goto") and self.about is not None:
            unused.append("about")
        if kind != "goto" and self.goal is not None:
            unused.append("goal")
        if kind == "goto" and self.duration is not None:
            unused.append("duration (a goto takes a speed: its length is planned)")
        if unused:
            raise ProtocolError(f"SteerRequest: {kind} does not use {', '.join(unused)}")
        if kind == "polygon" and self.polygon is None:
            raise ProtocolError("SteerRequest: polygon needs its vertices", "schema")
        if kind == "goto" and self.goal is None:
            raise ProtocolError("SteerRequest: goto needs its goal", "schema")
        if self.duration is not None and self.speed is not None:
            raise ProtocolError("give a duration or a speed, not both")

    def describe(self) -> str:
        """One line for logs and summaries, e.g. "translate (1, 0) m in 4 s"."""
        if self.kind == "translate":
            what = f"translate ({self.dx:g}, {self.dy:g}) m"
        elif self.kind == "rotate":
            what = f"rotate {math.degrees(self.angle):g} deg"
        elif self.kind == "scale":
            what = f"scale x{self.factor:g}"
        elif self.kind == "goto":
            what = f"goto ({self.goal[0]:g}, {self.goal[1]:g})"
            if self.polygon is not None:
                what += f" as a polygon of {len(self.polygon)} vertices"
        else:
            what = f"polygon of {len(self.polygon or ())} vertices"
        if self.about is not None:
            what += f" about ({self.about[0]:g}, {self.about[1]:g})"
        if self.duration is not None:
            what += f" in {self.duration:g} s"
        if self.speed is not None:
            what += f" at {self.speed:g} m/s"
        return what

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (summary.json): the wire fields, absent optionals left out."""
        out: dict[str, Any] = {}
        for name in self._SPEC:
            value = getattr(self, name)
            if value is None:
                continue
            if name == "polygon":
                value = [list(p) for p in value]
            elif name in ("about", "goal"):
                value = list(value)
            out[name] = value
        return out


@dataclass(frozen=True, slots=True)
class SteerReply(Message):
    """Coordinator -> client: whether S will move, why not, and how long the motion takes.

    reason: "" or a note when accepted (e.g. the speed was clipped), "<code>: <why>" when
    refused (coordinator.steering.REFUSALS); duration: s until S arrives, including the
    brake of a moving S it pre-empts (0 when refused). route: an accepted goto's stops,
    (x, y, scale) each: S's centroid (m) and its size relative to S when the route starts
    (S stops at each; the first is where S starts, the last the goal), with a 4th value,
    the angle (rad, CCW) S is turned by about its centroid, at stops where it is turned
    (optional: absent means 0, so older readers of (x, y, scale) stay right elsewhere),
    else absent.
    """

    accepted: bool
    reason: str
    duration: float
    route: tuple[tuple[float, ...], ...] | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "accepted": _flag,
        "reason": _text(MAX_REASON),
        "duration": _real(0.0, MAX_DURATION),
        "route": _optional(route_stops(MAX_ROUTE, MAX_FACTOR)),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"route"})

    def _check_fields(self) -> None:
        if self.route is not None and not self.accepted:
            raise ProtocolError("SteerReply: a refusal carries no route")
