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

Every call sends one SteerRequest as a Zenoh query on ``covswarm/<swarm>/steer`` and returns
the coordinator's SteerReply; a new request pre-empts the motion in progress. Raises
:class:`SteerTimeout` when no coordinator answers within ``timeout`` s, and ProtocolError
(before sending anything) for a request that cannot be encoded (NaN, out-of-range values).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from covswarm.protocol.keys import check_swarm, steer_key
from covswarm.protocol.messages import ProtocolError
from covswarm.protocol.steering import SteerReply, SteerRequest


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
            f"no coordinator of swarm {self.swarm!r} answered within {self.timeout:g} s{detail}"
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


__all__ = ["ProtocolError", "SteerReply", "SteerRequest", "SteerTimeout", "SteeringClient"]
