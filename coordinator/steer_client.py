"""Steer a running swarm from Python: a small client of the coordinator's steering queryable.

For planners and scripts (``covswarm steer`` is a thin wrapper around it)::

    import zenoh
    from covswarm.protocol.session import session_config
    from covswarm.coordinator.steer_client import SteeringClient

    with zenoh.open(session_config(["tcp/127.0.0.1:7447"])) as session:
        steer = SteeringClient(session, "my-swarm")
        reply = steer.translate(1.0, 0.0, duration=5.0)   # S moves 1 m to the right in 5 s
        if not reply.accepted:
            print("refused:", reply.reason)
        steer.rotate(30.0)                                  # degrees, about S's centroid
        steer.polygon([(0, 0), (1, 0), (1, 1), (0, 1)])     # morph S into a unit square
        reply = steer.goto(4.0, 1.5)                        # S planned through the arena
        print(reply.route)                                  # its stops: (x, y, scale)

Every call sends one SteerRequest as a Zenoh query on ``covswarm/<swarm>/steer`` and returns
the coordinator's SteerReply; a new request pre-empts the motion in progress. Raises
:class:`SteerTimeout` when no coordinator answers within ``timeout`` s, and ProtocolError
(before sending anything) for a request that cannot be encoded (NaN, out-of-range values).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timezone
from typing import Any

import click

from covswarm.protocol.keys import check_swarm, steer_key
from covswarm.protocol.messages import MAX_ANGLE
from covswarm.protocol.security import SECURE_OPTION, credentials_end, expiry_warning
from covswarm.protocol.steering import MAX_DURATION, SteerReply, SteerRequest
from covswarm.runtime.options import FiniteFloat, connect_option


class SteerTimeout(TimeoutError):
    """No coordinator answered a steering request (wrong swarm, or none running)."""


class SteeringClient:
    """Steering requests to the coordinator of ``swarm`` over an open zenoh session."""

    def __init__(self, session: Any, swarm: str, timeout: float = 2.0) -> None:
        if not (timeout > 0.0 and math.isfinite(timeout)):
            raise ValueError(f"timeout must be positive and finite, got {timeout!r}")
        self.session = session
        self.swarm = check_swarm(swarm)
        self.timeout = float(timeout)
        self._key = steer_key(swarm)

    def request(self, request: SteerRequest) -> SteerReply:
        """Send ``request``; the coordinator's answer. SteerTimeout if there is none.

        A reply that does not decode raises ProtocolError: it cannot tell whether S moves.
        """
        replies = self.session.get(self._key, payload=request.encode(), timeout=self.timeout)
        errors = []
        for reply in replies:
            if reply.ok is not None:
                return SteerReply.decode(reply.ok.payload.to_bytes())
            errors.append(reply.err.payload.to_string())
        detail = f" ({'; '.join(errors)})" if errors else ""
        raise SteerTimeout(
            f"no coordinator of swarm {self.swarm!r} answered (waited up to {self.timeout:g} s: "
            f"none may be reachable at all){detail}"
        )

    def translate(self, dx: float, dy: float, duration: float | None = None) -> SteerReply:
        """Move S by (dx, dy) m, in ``duration`` s (None: as fast as the team can follow)."""
        return self.request(SteerRequest("translate", dx=dx, dy=dy, duration=duration))

    def rotate(
        self,
        degrees: float,
        about: tuple[float, float] | None = None,
        duration: float | None = None,
    ) -> SteerReply:
        """Turn S by ``degrees`` (CCW positive) about ``about`` (None: S's centroid)."""
        angle = math.radians(degrees)
        return self.request(SteerRequest("rotate", angle=angle, about=about, duration=duration))

    def scale(
        self,
        factor: float,
        about: tuple[float, float] | None = None,
        duration: float | None = None,
    ) -> SteerReply:
        """Scale S by ``factor`` (> 0) about ``about`` (None: S's centroid)."""
        return self.request(SteerRequest("scale", factor=factor, about=about, duration=duration))

    def polygon(
        self, vertices: Sequence[Sequence[float]], duration: float | None = None
    ) -> SteerReply:
        """Morph S into the convex polygon ``vertices`` ((k, 2) m, either orientation)."""
        points = [(float(x), float(y)) for x, y in vertices]
        return self.request(SteerRequest("polygon", polygon=points, duration=duration))

    def goto(
        self,
        x: float,
        y: float,
        polygon: Sequence[Sequence[float]] | None = None,
        speed: float | None = None,
    ) -> SteerReply:
        """Take S's centroid to (x, y) m through free space (the coordinator plans the route,
        shrinking S for doors and growing it back), S shaped ``polygon`` there ((k, 2) m,
        placed with its centroid on the goal; None: S's own shape). ``speed``: m/s of the
        fastest vertex (None: the coordinator's limit). An accepted reply's ``route`` lists
        the stops (x, y, scale[, angle]); a refused one says why ("no-path: ...")."""
        points = None if polygon is None else [(float(px), float(py)) for px, py in polygon]
        return self.request(SteerRequest("goto", goal=(x, y), polygon=points, speed=speed))


def _pair(text: str, option: str) -> tuple[float, float]:
    try:
        x, y = (float(part) for part in text.split(","))
    except ValueError:
        raise click.BadParameter(
            f"expected X,Y (two numbers), got {text!r}", param_hint=option
        ) from None
    return x, y


def _vertices(text: str) -> list[tuple[float, float]]:
    return [_pair(point, "--polygon") for point in text.split(";") if point.strip()]


REFUSED_EXIT = 1  # the coordinator refused the request (the reason is printed)
NO_ANSWER_EXIT = 3  # no coordinator answered


def steer_request(
    translate_: str | None,
    rotate: float | None,
    scale: float | None,
    polygon: str | None,
    goto: str | None,
    about: str | None,
    duration: float | None,
    speed: float | None,
) -> SteerRequest:
    """The SteerRequest of ``covswarm steer``'s options (as its parameters are named);
    click.UsageError with the reason for a combination or value it cannot send."""
    shape = None if goto is not None else polygon  # with --goto, --polygon is the goal's
    chosen = [o for o in (translate_, rotate, scale, shape, goto) if o is not None]
    if len(chosen) != 1:
        raise click.UsageError(
            "give exactly one of --translate, --rotate, --scale, --polygon, --goto"
        )
    if goto is not None and duration is not None:
        raise click.UsageError("--goto takes --speed, not --duration (its route is planned)")
    if about is not None and rotate is None and scale is None:
        raise click.UsageError("--about is the fixed point of --rotate or --scale only")
    try:
        centre = None if about is None else _pair(about, "--about")
        if translate_ is not None:
            dx, dy = _pair(translate_, "--translate")
            return SteerRequest("translate", dx=dx, dy=dy, duration=duration, speed=speed)
        elif rotate is not None:
            return SteerRequest(
                "rotate", angle=math.radians(rotate), about=centre, duration=duration, speed=speed
            )
        elif scale is not None:
            return SteerRequest("scale", factor=scale, about=centre, duration=duration, speed=speed)
        elif goto is not None:
            return SteerRequest(
                "goto",
                goal=_pair(goto, "--goto"),
                polygon=None if polygon is None else _vertices(polygon),
                speed=speed,
            )
        else:
            return SteerRequest(
                "polygon", polygon=_vertices(polygon or ""), duration=duration, speed=speed
            )
    except ValueError as exc:  # ProtocolError included: NaN, too many vertices, ...
        raise click.UsageError(str(exc)) from None


@click.command("steer")
@connect_option("Zenoh endpoint, e.g. tcp/127.0.0.1:7447.")
@click.option("--swarm", required=True, help="Swarm name of the running mission.")
@click.option("--translate", "translate_", metavar="DX,DY", help="Move S by (DX, DY) m.")
@click.option(
    "--rotate",
    type=FiniteFloat(min=-int(math.degrees(MAX_ANGLE)), max=int(math.degrees(MAX_ANGLE))),
    metavar="DEG",
    help="Turn S by DEG degrees (CCW).",
)
@click.option("--scale", type=FiniteFloat(min=0, min_open=True), help="Scale S by F.")
@click.option(
    "--polygon",
    metavar='"X,Y;X,Y;..."',
    help="Morph S into this convex polygon (with --goto: S's shape at the goal).",
)
@click.option(
    "--goto", "goto", metavar="X,Y", help="Take S's centroid to (X, Y) m around the obstacles."
)
@click.option("--about", metavar="X,Y", help="Fixed point of --rotate/--scale [S's centroid].")
@click.option(
    "--duration",
    type=FiniteFloat(min=0, min_open=True, max=MAX_DURATION),
    help="Seconds the motion takes.",
)
@click.option("--speed", type=FiniteFloat(min=0, min_open=True), help="m/s of S's fastest vertex.")
@click.option(
    "--timeout",
    type=FiniteFloat(min=0, min_open=True),
    default=2.0,
    show_default=True,
    help="s to wait for the coordinator's answer.",
)
@SECURE_OPTION
def steer_command(
    connect: Sequence[str], swarm: str, timeout: float, secure: Any, **motion: Any
) -> None:
    """Steer a running swarm: move, turn, scale or reshape S, or send it somewhere (--goto,
    planned by the coordinator around the obstacles). Prints accepted (and a goto's route)
    or the refusal.

    Exit status: 0 accepted, 1 refused, 3 no coordinator answered or no router let us in
    (2: bad options).
    """
    from covswarm.protocol.session import SessionError, open_session, session_config

    request = steer_request(**motion)  # its options as steer_request names them
    try:
        check_swarm(swarm)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    try:
        config = session_config(list(connect), secure=secure, role="operator")
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    if secure is not None:
        # A request lasts seconds: the operator is told of credentials about to end (one
        # that ended already was refused above), not watched as a long-lived process is.
        end, ending = credentials_end(secure, ["operator"])
        if (warning := expiry_warning(ending, end, datetime.now(timezone.utc))) is not None:
            click.echo(f"warning: {warning}", err=True)
    try:
        session = open_session(config)
    except SessionError as exc:  # no router there, or it refused our credentials
        click.echo(f"no answer: cannot join {', '.join(connect)}: {exc}", err=True)
        raise SystemExit(NO_ANSWER_EXIT) from None
    with session:
        try:
            reply = SteeringClient(session, swarm, timeout).request(request)
        except SteerTimeout as exc:
            click.echo(f"no answer: {exc}", err=True)
            raise SystemExit(NO_ANSWER_EXIT) from None
    if not reply.accepted:
        click.echo(f"refused: {reply.reason}")
        raise SystemExit(REFUSED_EXIT)
    note = f" ({reply.reason})" if reply.reason else ""
    click.echo(f"accepted: {request.describe()}, {reply.duration:.2f} s{note}")
    if reply.route is not None:
        click.echo(f"route: {describe_route(reply.route)}")


def describe_route(route: Sequence[Sequence[float]]) -> str:
    """A goto's stops (SteerReply.route) in one line: "(x, y) xscale", and the angle S is
    turned by in degrees where a stop carries one."""
    return " -> ".join(
        f"({x:.3f}, {y:.3f}) x{s:.2f}" + "".join(f" {math.degrees(a):+.0f} deg" for a in turn)
        for x, y, s, *turn in route
    )
