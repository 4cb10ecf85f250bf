"""Whether a mission can go on the wire: ``covswarm sim`` and ``covswarm run`` accept and
refuse the same scenarios.

The simulator needs no messages, so without this check it ran missions (a 100-vertex S,
kappa 2000) whose Domain broadcast protocol.Domain refuses, and ``covswarm run`` of the
same file failed mid-start.
"""

from __future__ import annotations

from covswarm.mission.scenarios import Scenario
from covswarm.protocol import Domain, ProtocolError


def check_broadcastable(scenario: Scenario, kappa: float, duration: float) -> None:
    """ValueError with a sentence unless every Domain of ``scenario`` over [0, duration] s,
    with gain ``kappa`` (1/s), is one the agents decode (protocol.Domain.decode: field
    bounds, vertex count, payload size), checked at the motion's sample times."""
    for t in scenario.motion.sample_times(duration):
        vertices, velocities = scenario.domain(float(t))
        density = scenario.density(float(t))
        try:
            message = Domain(
                seq=0,
                stamp=0.0,
                t=float(t),
                state="running",
                vertices=vertices,
                velocities=velocities,
                kappa=kappa,
                density=None if density is None else density.to_dict(),
            )
            Domain.decode(message.encode())
        except ProtocolError as exc:
            raise ValueError(
                f"scenario {scenario.name}: its domain at t = {float(t):g} s cannot be "
                f"broadcast to the agents ({exc})"
            ) from None
