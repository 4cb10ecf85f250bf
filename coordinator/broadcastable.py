"""Whether a mission can go on the wire: ``covswarm sim`` and ``covswarm run`` accept and
refuse the same scenarios.

The simulator needs no messages, so without this check it ran missions (a 100-vertex S,
kappa 2000) whose Domain broadcast protocol.Domain refuses, and ``covswarm run`` of the
same file failed mid-start.
"""

from __future__ import annotations

from covswarm.mission.scenarios import Scenario, check_motion, check_route_duration
from covswarm.protocol import Domain, ProtocolError
from covswarm.protocol import World as WorldMessage
from covswarm.world.wire import to_message


def check_broadcastable(scenario: Scenario, kappa: float, duration: float) -> None:
    """ValueError with a sentence unless every Domain of ``scenario`` over [0, duration] s,
    with gain ``kappa`` (1/s), is one the agents decode (protocol.Domain.decode: field
    bounds, vertex count, payload size), checked at the motion's sample times, and its
    world one they decode too (protocol.World: obstacle count, coordinates, payload size):
    a map's pieces past those bounds were refused by the coordinator once the team was up.
    S itself is checked over ``duration`` too (mission.scenarios.check_motion): a run
    longer than its scenario's own duration was checked over the scenario's alone; and a
    planned route must end within it (mission.scenarios.check_route_duration: a
    ``--duration`` shorter than the route cut it short without a word).

    The messages say what ``covswarm run`` could not send: ``covswarm sim`` has no agents,
    but refuses the same scenarios."""
    try:
        check_route_duration(scenario.motion, duration, "--duration")
        check_motion(scenario.motion, duration)
    except ValueError as exc:
        raise ValueError(f"scenario {scenario.name}: {exc}") from None
    try:
        WorldMessage.decode(to_message(scenario.world, 0, 0.0).encode())
    except ProtocolError as exc:
        raise ValueError(
            f"scenario {scenario.name}: its world does not fit a World message ({exc}), so "
            "covswarm run could not send it to its processes (the message's limits: "
            "docs/world.md)"
        ) from None
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
            what = "density" if str(exc).startswith("density") else "domain"
            path = scenario.density_path
            turns = path is not None and bool(path.turn_rates.any())
            turning = " (a bump's cov_rate includes its turn_rate's turning)" * (
                turns and "cov_rate" in str(exc)
            )
            raise ValueError(
                f"scenario {scenario.name}: its {what} at t = {float(t):g} s does not fit a "
                f"Domain message ({exc}), so covswarm run could not send it to its "
                f"processes{turning}"
            ) from None
