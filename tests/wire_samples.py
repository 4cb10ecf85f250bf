"""Messages several tests build (not a test module)."""

from __future__ import annotations

from collections.abc import Sequence

from covswarm import protocol


def domain_message(
    vertices: Sequence[Sequence[float]],
    *,
    seq: int,
    stamp: float,
    state: str = "running",
    velocity: Sequence[float] = (0.0, 0.0),
    tile_size: float | None = None,
) -> protocol.Domain:
    """A Domain broadcast at mission time 0, kappa 1: S at ``vertices`` (m) translating at
    ``velocity`` (m/s, every vertex alike; still by default)."""
    return protocol.Domain(
        seq=seq,
        stamp=stamp,
        t=0.0,
        state=state,
        vertices=vertices,
        velocities=[list(velocity)] * len(vertices),
        kappa=1.0,
        tile_size=tile_size,
    )
