"""The arena on the wire: covswarm.world.model.World <-> covswarm.protocol.World.

The wire's resolution is 1 mm (integer coordinates pack in 1-3 bytes). Rounding must never
let a robot or S touch a wall the sender knows: obstacles are rounded outward (the sent
polygon is the convex hull of the millimetre grid points around each vertex, so it contains
the true one) and the workspace inward. Coordinates already on the grid (maps at 5 cm,
boxes in round numbers) are sent exactly.
"""

from __future__ import annotations

import math

import numpy as np

from covswarm.protocol.messages import MM
from covswarm.protocol.messages import World as WorldMessage
from covswarm.world.model import Obstacle, World

_SNAP = 1e-6  # mm: a coordinate this close to a whole millimetre is on the grid


def _down(mm: float) -> int:
    near = round(mm)
    return near if abs(mm - near) < _SNAP else math.floor(mm)


def _up(mm: float) -> int:
    near = round(mm)
    return near if abs(mm - near) < _SNAP else math.ceil(mm)


def _hull(points: set[tuple[int, int]]) -> list[tuple[int, int]]:
    """Strictly convex CCW hull of integer points (Andrew's monotone chain, exact)."""
    ordered = sorted(points)

    def chain(seq: list[tuple[int, int]]) -> list[tuple[int, int]]:
        out: list[tuple[int, int]] = []
        for p in seq:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-2], out[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0:
                    break
                out.pop()
            out.append(p)
        return out

    lower, upper = chain(ordered), chain(ordered[::-1])
    return lower[:-1] + upper[:-1]


def outward_mm(vertices: np.ndarray) -> list[tuple[int, int]]:
    """(k, 2) convex polygon in m -> the smallest convex polygon on the millimetre grid that
    contains it: the hull of the grid corners around each vertex (CCW, whole mm)."""
    corners: set[tuple[int, int]] = set()
    for x, y in np.asarray(vertices, dtype=float) * MM:
        for gx in {_down(x), _up(x)}:
            for gy in {_down(y), _up(y)}:
                corners.add((gx, gy))
    return _hull(corners)


def to_message(world: World, seq: int, stamp: float) -> WorldMessage:
    """The World message of ``world`` (ProtocolError if it does not fit the wire's bounds)."""
    workspace = None
    if world.workspace is not None:
        xmin, xmax, ymin, ymax = (v * MM for v in world.workspace)
        workspace = (_up(xmin) / MM, _down(xmax) / MM, _up(ymin) / MM, _down(ymax) / MM)
    polygons = tuple(
        tuple((x / MM, y / MM) for x, y in outward_mm(o.vertices)) for o in world.obstacles
    )
    return WorldMessage(
        seq=seq,
        stamp=stamp,
        obstacles=polygons,
        workspace=workspace,
        names=tuple(o.name for o in world.obstacles),
    )


def from_message(message: WorldMessage) -> World:
    """The model World of a decoded message (ValueError if its geometry is refused)."""
    names = message.names or ()
    obstacles = tuple(
        Obstacle(name, np.array(polygon, dtype=float))
        for name, polygon in zip(names, message.obstacles, strict=True)
    )
    return World(message.workspace, obstacles)
