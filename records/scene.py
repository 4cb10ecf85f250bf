"""Foxglove scene messages of a run, built from numpy arrays (no I/O).

Everything lives in one fixed frame, ``world`` (metres, the scenario's plane at z = 0).
Entity ids carry what a viewer (or ``covswarm replay``) needs to tell things apart: robot
``<id>`` on the robots topic, cell ``<id>`` on the cells topic, ``S`` for the domain.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CylinderPrimitive,
    Duration,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

FRAME = "world"
ROBOT_DIAMETER = 0.14  # m, a Khepera IV
ROBOT_HEIGHT = 0.05  # m
# A robot not updated for this long leaves the scene (a dead robot does not linger).
ROBOT_LIFETIME = 1.0  # s
ROBOT_COLOR = Color(r=0.12, g=0.35, b=0.85, a=0.9)
HEADING_COLOR = Color(r=0.95, g=0.55, b=0.1, a=1.0)
DOMAIN_COLOR = Color(r=0.1, g=0.1, b=0.1, a=1.0)
CELL_COLOR = Color(r=0.45, g=0.45, b=0.45, a=0.8)
OBSTACLE_COLOR = Color(r=0.55, g=0.3, b=0.25, a=0.6)
WORKSPACE_COLOR = Color(r=0.6, g=0.6, b=0.6, a=1.0)
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_ORIGIN = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=_IDENTITY)
_ROBOT_SIZE = Vector3(x=ROBOT_DIAMETER, y=ROBOT_DIAMETER, z=ROBOT_HEIGHT)
_ROBOT_LIFETIME = Duration(sec=int(ROBOT_LIFETIME), nsec=0)


def timestamp(t: float) -> Timestamp:
    """A Foxglove Timestamp of mission time ``t`` (s since the mission's start, >= 0)."""
    ns = max(0, round(t * 1e9))
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def robots_update(
    t: float, ids: Sequence[int], poses: np.ndarray, times: np.ndarray | None = None
) -> SceneUpdate:
    """One entity per robot: a Khepera-sized disc and an arrow along its heading.

    ids: n robot ids; poses: (n, 3) rows x, y (m), theta (rad); times: (n,) mission times
    at which each pose was measured, the entities' timestamps (default: all t).
    """
    rows = np.asarray(poses, dtype=float)
    ns = np.round(np.maximum(np.full(len(ids), t) if times is None else times, 0.0) * 1e9)
    sec, nsec = np.divmod(ns.astype(np.int64), 1_000_000_000)
    half = 0.5 * rows[:, 2]
    entities = []
    # Built per robot at the pose rate (2000 a second at 100 robots): the constant parts are
    # shared, and the disc and the arrow share one pose (the arrow's head sticks out).
    for ident, x, y, qz, qw, s, n in zip(
        ids, rows[:, 0].tolist(), rows[:, 1].tolist(), np.sin(half).tolist(),
        np.cos(half).tolist(), sec.tolist(), nsec.tolist(), strict=True,
    ):  # fmt: skip
        pose = Pose(
            position=Vector3(x=x, y=y, z=0.5 * ROBOT_HEIGHT),
            orientation=Quaternion(x=0.0, y=0.0, z=qz, w=qw),
        )
        entities.append(
            SceneEntity(
                timestamp=Timestamp(sec=s, nsec=n),
                frame_id=FRAME,
                id=str(ident),
                lifetime=_ROBOT_LIFETIME,
                arrows=[
                    ArrowPrimitive(
                        pose=pose,
                        shaft_length=0.07,
                        shaft_diameter=0.02,
                        head_length=0.04,
                        head_diameter=0.05,
                        color=HEADING_COLOR,
                    )
                ],
                cylinders=[
                    CylinderPrimitive(
                        pose=pose,
                        size=_ROBOT_SIZE,
                        bottom_scale=1.0,
                        top_scale=1.0,
                        color=ROBOT_COLOR,
                    )  # fmt: skip
                ],
            )
        )
    return SceneUpdate(entities=entities)


def _loop(points: np.ndarray, color: Color, thickness: float) -> LinePrimitive:
    return LinePrimitive(
        type=LinePrimitiveLineType.LineLoop,
        pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=_IDENTITY),
        thickness=thickness,
        scale_invariant=True,
        points=[Point3(x=x, y=y, z=0.0) for x, y in np.asarray(points, dtype=float).tolist()],
        color=color,
    )


def domain_update(t: float, vertices: np.ndarray) -> SceneUpdate:
    """S(t) as a closed line loop, entity ``S``. vertices: (k, 2) m."""
    entity = SceneEntity(
        timestamp=timestamp(t),
        frame_id=FRAME,
        id="S",
        lines=[_loop(vertices, DOMAIN_COLOR, 3.0)],
    )
    return SceneUpdate(entities=[entity])


def cells_update(t: float, ids: Sequence[int], cells: Sequence[np.ndarray]) -> SceneUpdate:
    """Each robot's Voronoi cell in S as a line loop, entity ``<id>``; empty cells omitted.

    cells: n arrays (m_i, 2) of counter-clockwise vertices (covswarm.tvd.coverage.cells).
    """
    stamp = timestamp(t)
    entities = [
        SceneEntity(
            timestamp=stamp, frame_id=FRAME, id=str(ident), lines=[_loop(cell, CELL_COLOR, 1.0)]
        )
        for ident, cell in zip(ids, cells, strict=True)
        if len(cell) >= 3
    ]
    return SceneUpdate(entities=entities)


def arena_update(
    t: float,
    workspace: tuple[float, float, float, float] | None,
    obstacles: Sequence[np.ndarray],
) -> SceneUpdate:
    """The workspace outline (entity ``workspace``) and the obstacles (``obstacle/<k>``).

    workspace: (xmin, xmax, ymin, ymax) m; obstacles: convex polygons, (m_k, 2) vertices
    (m), each filled as a triangle fan on the plane.
    """
    stamp = timestamp(t)
    entities = []
    if workspace is not None:
        x0, x1, y0, y1 = workspace
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=FRAME,
                id="workspace",
                lines=[_loop(corners, WORKSPACE_COLOR, 1.0)],
            )
        )
    for k, polygon in enumerate(obstacles):
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=FRAME,
                id=f"obstacle/{k}",
                triangles=[_filled(polygon, OBSTACLE_COLOR)],
            )
        )
    return SceneUpdate(entities=entities)


def _filled(polygon: np.ndarray, color: Color) -> TriangleListPrimitive:
    """A convex polygon (k, 2) as k - 2 triangles fanned from its first vertex, indexed so
    that each vertex is sent once (built once a second for up to a map's 4096 pieces)."""
    points = np.asarray(polygon, dtype=float).tolist()
    return TriangleListPrimitive(
        pose=_ORIGIN,
        points=[Point3(x=x, y=y, z=0.0) for x, y in points],
        color=color,
        indices=[i for j in range(1, len(points) - 1) for i in (0, j, j + 1)],
    )
