"""The broadcast domain and density between two broadcasts (pure).

The coordinator broadcasts S's vertices with their exact velocities and the density with
its rates, so an agent holds a first-order model of both between messages. Beyond
``max_extrapolation`` s the model holds still, so a lost coordinator cannot drag the swarm
away.
"""

from __future__ import annotations

import numpy as np

from covswarm import protocol
from covswarm.tvd.density import Density


def extrapolate_domain(
    domain: protocol.Domain, elapsed: float, max_extrapolation: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (k, 2) m and vertex velocities (k, 2) m/s of the domain ``elapsed`` s of
    mission time after the broadcast's ``t``.

    Moves the vertices along their velocities for ``elapsed`` (never backwards), at most
    ``max_extrapolation`` s; beyond that the domain holds still (zero velocities). The
    agent measures ``elapsed`` from the broadcast's stamp, on its own clock within the bound
    on the coordinator's offset (covswarm.agent.latency).
    """
    vertices = np.array(domain.vertices, dtype=float)
    velocities = np.array(domain.velocities, dtype=float)
    if elapsed > max_extrapolation:
        return vertices + velocities * max_extrapolation, np.zeros_like(velocities)
    return vertices + velocities * max(elapsed, 0.0), velocities


def extrapolate_density(
    density: Density | None, elapsed: float, max_extrapolation: float
) -> Density | None:
    """The broadcast density ``elapsed`` s after its stamp, as ``extrapolate_domain``.

    Advanced linearly for at most ``max_extrapolation`` s, then held still (zero rates); a
    density that the linear advance would make invalid is held as received.
    """
    if density is None:
        return None
    try:
        advanced = density.at(density.time + min(max(elapsed, 0.0), max_extrapolation))
    except ValueError:
        return density.frozen()
    return advanced.frozen() if elapsed > max_extrapolation else advanced
