"""The arena: a workspace box and convex obstacles, and the questions asked of them.

Every obstacle is a convex polygon (a box is one, a map is cut into boxes by
covswarm.world.maps). Queries are vectorised over obstacles through a padded array of all
their vertices, prefiltered by bounding boxes, so an agent can ask at 10 Hz among hundreds
of obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from covswarm.tvd.geometry import (
    area,
    clip_convex,
    clip_halfplane,
    drop_repeats,
    polygon_distance,
    validate_convex,
)

Box = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (m)

CHUNK_POINTS = 256  # points clearance() handles at once (nearby ones: few obstacles each)


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A named convex obstacle. vertices: (k, 2) m, validated and made CCW on construction."""

    name: str
    vertices: np.ndarray

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError("obstacle: name must be a non-empty string")
        try:
            vertices = validate_convex(self.vertices)
        except ValueError as exc:
            raise ValueError(f"{self.name}: {exc}") from None
        vertices.setflags(write=False)
        object.__setattr__(self, "vertices", vertices)

    @property
    def box(self) -> Box:
        """Bounding box (xmin, xmax, ymin, ymax), m."""
        low, high = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return (float(low[0]), float(high[0]), float(low[1]), float(high[1]))

    @property
    def is_box(self) -> bool:
        """Whether the obstacle is an axis-aligned rectangle (written back as a box)."""
        v = self.vertices
        if len(v) != 4:
            return False
        xs, ys = np.unique(v[:, 0]), np.unique(v[:, 1])
        return len(xs) == 2 and len(ys) == 2


def box_vertices(box: Sequence[float]) -> np.ndarray:
    """(4, 2) CCW corners of a box (xmin, xmax, ymin, ymax); ValueError if it is not one."""
    try:
        xmin, xmax, ymin, ymax = (float(v) for v in box)
    except (TypeError, ValueError):
        raise ValueError(f"box {box!r}: need 4 numbers xmin, xmax, ymin, ymax") from None
    if not all(math.isfinite(v) for v in (xmin, xmax, ymin, ymax)):
        raise ValueError(f"box {box!r}: need 4 finite numbers xmin, xmax, ymin, ymax")
    if not (xmin < xmax and ymin < ymax):
        raise ValueError(f"box {box!r}: need xmin < xmax and ymin < ymax")
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]])


@dataclass(frozen=True, eq=False)
class _Pack:
    """All obstacles in padded arrays (m obstacles, K = most vertices).

    vertices (m, K, 2), a short polygon padded by repeating its last vertex (its padding edges
    have length 0); edges (m, K, 2) = next vertex - vertex; normals (m, K, 2) outward unit
    normals, 0 on padding edges; valid (m, K) False on padding edges; boxes (m, 4).
    """

    vertices: np.ndarray
    edges: np.ndarray
    normals: np.ndarray
    valid: np.ndarray
    boxes: np.ndarray

    @classmethod
    def of(cls, polygons: Sequence[np.ndarray]) -> _Pack:
        m = len(polygons)
        k = max((len(p) for p in polygons), default=3)
        vertices = np.zeros((m, k, 2))
        valid = np.zeros((m, k), dtype=bool)
        edges = np.zeros((m, k, 2))
        for j, p in enumerate(polygons):
            n = len(p)
            vertices[j, :n], vertices[j, n:] = p, p[-1]
            edges[j, :n] = np.roll(p, -1, axis=0) - p
            valid[j, :n] = True
        length = np.linalg.norm(edges, axis=2)
        normals = np.zeros_like(edges)
        normals[valid] = (
            np.stack([edges[valid][:, 1], -edges[valid][:, 0]], axis=1) / length[valid][:, None]
        )
        boxes = np.stack(
            [
                vertices[:, :, 0].min(axis=1),
                vertices[:, :, 0].max(axis=1),
                vertices[:, :, 1].min(axis=1),
                vertices[:, :, 1].max(axis=1),
            ],
            axis=1,
        ).reshape(m, 4)
        return cls(vertices, edges, normals, valid, boxes)

    def signed_distance(self, points: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(n, len(rows)) signed distance of each point to obstacles ``rows``: the distance
        outside, minus the depth to the nearest edge line inside (convex, so exact)."""
        v, d, nrm, ok = self.vertices[rows], self.edges[rows], self.normals[rows], self.valid[rows]
        # One edge at a time on (n, m) arrays: numpy reduces slowly over a short last axis.
        px, py = points[:, 0, None], points[:, 1, None]
        inside = np.full((len(points), len(rows)), -np.inf)
        nearest2 = np.full((len(points), len(rows)), np.inf)
        for e in range(v.shape[1]):
            rx, ry = px - v[None, :, e, 0], py - v[None, :, e, 1]
            depth = rx * nrm[None, :, e, 0] + ry * nrm[None, :, e, 1]
            inside = np.maximum(inside, np.where(ok[None, :, e], depth, -np.inf))
            dx, dy = d[None, :, e, 0], d[None, :, e, 1]
            length2 = dx * dx + dy * dy
            t = np.clip((rx * dx + ry * dy) / np.where(length2 > 0.0, length2, 1.0), 0.0, 1.0)
            gx, gy = rx - t * dx, ry - t * dy
            nearest2 = np.minimum(nearest2, gx * gx + gy * gy)
        # inside <= 0 iff inside or on the boundary (convex: the deepest edge line decides)
        return np.where(inside <= 0.0, inside, np.sqrt(nearest2))

    def separation(self, polygon: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(len(rows),) the largest gap between the projections of ``polygon`` (k, 2, convex
        CCW) and each obstacle on the edge normals of both: > 0 iff they are disjoint, and a
        lower bound on their distance (projection does not lengthen)."""
        v, nrm, ok = self.vertices[rows], self.normals[rows], self.valid[rows]
        edges = np.roll(polygon, -1, axis=0) - polygon
        own = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / np.linalg.norm(edges, axis=1)[:, None]
        s_on_own = polygon @ own.T  # (k, k)
        o_on_own = np.einsum("mKj,kj->mKk", v, own)  # (m, K, k)
        sep_own = np.maximum(
            o_on_own.min(axis=1) - s_on_own.max(axis=0), s_on_own.min(axis=0) - o_on_own.max(axis=1)
        ).max(axis=1)
        o_on_theirs = np.einsum("mKj,mLj->mKL", v, nrm)  # vertex K on normal L
        s_on_theirs = np.einsum("kj,mLj->mkL", polygon, nrm)
        gaps = np.maximum(
            s_on_theirs.min(axis=1) - o_on_theirs.max(axis=1),
            o_on_theirs.min(axis=1) - s_on_theirs.max(axis=1),
        )
        sep_theirs = np.where(ok, gaps, -np.inf).max(axis=1)
        return np.maximum(sep_own, sep_theirs)


@dataclass(frozen=True, eq=False)
class World:
    """The arena: an optional workspace box S must stay in and convex obstacles.

    Obstacles may overlap each other (a box drawn over a map's wall): the queries answer for
    their union.
    """

    workspace: Box | None
    obstacles: tuple[Obstacle, ...] = ()
    _pack: _Pack = field(init=False, repr=False)
    _disjoint: tuple[np.ndarray, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.workspace is not None:
            box_vertices(self.workspace)
            object.__setattr__(self, "workspace", tuple(float(v) for v in self.workspace))
        obstacles = tuple(self.obstacles)
        if not all(isinstance(o, Obstacle) for o in obstacles):
            raise ValueError("world: obstacles must be Obstacle instances")
        object.__setattr__(self, "obstacles", obstacles)
        pack = _Pack.of([o.vertices for o in obstacles])
        object.__setattr__(self, "_pack", pack)
        object.__setattr__(self, "_disjoint", _disjoint_pieces(obstacles, pack.boxes))

    @classmethod
    def from_boxes_and_polygons(
        cls,
        workspace: Box | None,
        obstacles: Iterable[Any] = (),
        *,
        prefix: str = "obstacle",
        first: int = 1,
    ) -> World:
        """A world from a workspace and obstacle entries, each a box [xmin, xmax, ymin, ymax]
        (4 numbers) or a convex polygon [[x, y], ...]; named "<prefix> <first + i>"."""
        built = [make_obstacle(f"{prefix} {first + i}", entry) for i, entry in enumerate(obstacles)]
        return cls(workspace, tuple(built))

    def with_obstacles(self, extra: Iterable[Obstacle]) -> World:
        """This world plus the obstacles ``extra`` (a map's pieces, say)."""
        return World(self.workspace, self.obstacles + tuple(extra))

    @property
    def bounds(self) -> Box | None:
        """The workspace if there is one, else the obstacles' bounding box; None if empty."""
        if self.workspace is not None:
            return self.workspace
        if not self.obstacles:
            return None
        b = self._pack.boxes
        return (
            float(b[:, 0].min()),
            float(b[:, 1].max()),
            float(b[:, 2].min()),
            float(b[:, 3].max()),
        )

    def candidates(self, box: Sequence[float], margin: float = 0.0) -> np.ndarray:
        """Indices of the obstacles whose bounding box comes within ``margin`` (m) of ``box``
        (xmin, xmax, ymin, ymax)."""
        b = self._pack.boxes
        return np.flatnonzero(
            (b[:, 0] <= box[1] + margin)
            & (b[:, 1] >= box[0] - margin)
            & (b[:, 2] <= box[3] + margin)
            & (b[:, 3] >= box[2] - margin)
        )

    def obstacle_gap(self, polygon: np.ndarray, rows: np.ndarray) -> tuple[float, int]:
        """Exact distance (m) from a convex CCW polygon to the nearest of obstacles ``rows``
        and that obstacle's index (0 when touching or overlapping); (inf, -1) if none.

        The separating-axis gap is a lower bound of each distance, so only the obstacles whose
        bound is below the best exact distance so far need the exact computation.
        """
        if len(rows) == 0:
            return math.inf, -1
        bound = self._pack.separation(polygon, rows)
        best, best_row = math.inf, -1
        for j in np.argsort(bound, kind="stable"):
            if bound[j] >= best:
                break
            if bound[j] <= 0.0:
                return 0.0, int(rows[j])
            d = polygon_distance(polygon, self.obstacles[rows[j]].vertices)
            if d < best:
                best, best_row = d, int(rows[j])
        return best, best_row

    def describe(self, name: str) -> str:
        """``name`` (an obstacle's, or "workspace", as contact() says) with where it is, for
        a message: "'map piece 5' ([1.8, 2.2] x [0.9, 1.3] m)" (a map's pieces are known
        by number only)."""
        for row, obstacle in enumerate(self.obstacles):
            if obstacle.name == name:
                x0, x1, y0, y1 = self._pack.boxes[row]
                return f"{name!r} ([{x0:.3g}, {x1:.3g}] x [{y0:.3g}, {y1:.3g}] m)"
        if name == "workspace" and self.workspace is not None:
            x0, x1, y0, y1 = self.workspace
            return f"the workspace [{x0:.4g}, {x1:.4g}] x [{y0:.4g}, {y1:.4g}] m"
        return name

    def workspace_gap(self, polygon: np.ndarray) -> float:
        """How far (m) S's nearest vertex is inside the workspace's walls (negative: that far
        outside); inf without a workspace. S is convex, so its vertices decide."""
        if self.workspace is None:
            return math.inf
        xmin, xmax, ymin, ymax = self.workspace
        p = np.asarray(polygon, dtype=float)
        return float(np.min([p[:, 0] - xmin, xmax - p[:, 0], p[:, 1] - ymin, ymax - p[:, 1]]))

    def contact(self, polygon: np.ndarray, tolerance: float = 0.0) -> str | None:
        """What a convex CCW polygon S (k, 2) touches: the name of the first obstacle (in the
        world's order) within ``tolerance`` m of S or overlapping it, else "workspace" if a
        vertex of S lies more than ``tolerance`` outside the workspace box, else None.

        S may rest on the workspace's walls (the walls bound S, they are not obstacles).
        """
        p = np.asarray(polygon, dtype=float)
        low, high = p.min(axis=0), p.max(axis=0)
        rows = self.candidates((low[0], high[0], low[1], high[1]), tolerance)
        if len(rows):
            near = rows[self._pack.separation(p, rows) <= tolerance]
            for j in near:
                if polygon_distance(p, self.obstacles[j].vertices) <= tolerance:
                    return self.obstacles[j].name
        if self.workspace_gap(p) < -tolerance:
            return "workspace"
        return None

    def overlap_area(self, polygon: np.ndarray) -> float:
        """Area (m^2) of S ∩ (union of the obstacles), exact: the obstacles are cut at
        construction into pairwise interior-disjoint convex pieces with the same union, so
        the clipped areas add up."""
        p = np.asarray(polygon, dtype=float)
        low, high = p.min(axis=0), p.max(axis=0)
        total = 0.0
        for piece in self._disjoint:
            if (
                piece[:, 0].min() < high[0]
                and piece[:, 0].max() > low[0]
                and piece[:, 1].min() < high[1]
                and piece[:, 1].max() > low[1]
            ):
                total += area(clip_convex(p, piece))
        return total

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """(n,) signed clearance (m) of points (n, 2): the distance to the nearest obstacle or
        workspace wall, 0 on an obstacle's boundary, negative inside an obstacle (minus the
        depth) or outside the workspace; inf in an empty world without a workspace."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        out = np.full(len(p), np.inf)
        if self.workspace is not None:
            xmin, xmax, ymin, ymax = self.workspace
            walls = np.stack([p[:, 0] - xmin, xmax - p[:, 0], p[:, 1] - ymin, ymax - p[:, 1]])
            dx = np.maximum(-walls[:2].min(axis=0), 0.0)
            dy = np.maximum(-walls[2:].min(axis=0), 0.0)
            # inside: the nearest wall; outside: minus the distance to the box
            out = np.where(walls.min(axis=0) >= 0.0, walls.min(axis=0), -np.hypot(dx, dy))
        m = len(self.obstacles)
        if m == 0 or len(p) == 0:
            return out
        # Chunks of about CHUNK_POINTS nearby points (sorted by cells that hold about that
        # many): only obstacles whose bounding box is nearer than some point's upper bound on
        # its nearest obstacle can matter, usually few. The bound: a convex obstacle touches
        # every side of its bounding box, so it is no farther than the farther end of any
        # side: the least of those (the R-tree MINMAXDIST) bounds the distance.
        boxes = self._pack.boxes
        span = np.maximum(np.ptp(p, axis=0), 1e-9)
        cell = float(np.sqrt(span[0] * span[1] * CHUNK_POINTS / len(p))) or float(span.max())
        cells = np.floor((p - p.min(axis=0)) / cell)
        order = np.lexsort((cells[:, 1], cells[:, 0]))
        xs, ys = boxes[:, :2], boxes[:, 2:]
        for start in range(0, len(p), CHUNK_POINTS):
            idx = order[start : start + CHUNK_POINTS]
            chunk = p[idx]
            cx, cy = chunk[:, 0, None], chunk[:, 1, None]
            left, right = (xs[None, :, 0] - cx) ** 2, (xs[None, :, 1] - cx) ** 2  # (c, m)
            low, high = (ys[None, :, 0] - cy) ** 2, (ys[None, :, 1] - cy) ** 2
            gap_x = np.maximum(np.maximum(xs[None, :, 0] - cx, cx - xs[None, :, 1]), 0.0)
            gap_y = np.maximum(np.maximum(ys[None, :, 0] - cy, cy - ys[None, :, 1]), 0.0)
            lower = np.hypot(gap_x, gap_y)  # (c, m) never more than the distance
            # a vertical side's farther end: its x distance and the farther of the y ends
            far_y, far_x = np.maximum(low, high), np.maximum(left, right)
            upper = np.sqrt(
                np.minimum(np.minimum(left, right) + far_y, np.minimum(low, high) + far_x).min(
                    axis=1
                )
            )
            upper = np.minimum(upper, np.abs(out[idx]))  # a nearer wall: farther ones are moot
            rows = np.flatnonzero((lower <= upper[:, None]).any(axis=0))
            if len(rows) == 0:
                continue  # every obstacle is farther than the walls
            nearest = self._pack.signed_distance(chunk, rows).min(axis=1)
            out[idx] = np.minimum(out[idx], nearest)
        return out

    def nearby(self, point: np.ndarray, radius: float) -> list[np.ndarray]:
        """The obstacles (each (k, 2) CCW vertices) within ``radius`` m of ``point`` (2,):
        prefiltered by bounding boxes, then by exact distance."""
        if not self.obstacles:  # a workspace alone: asked for every robot at every step
            return []
        q = np.asarray(point, dtype=float).reshape(2)
        rows = self.candidates((q[0], q[0], q[1], q[1]), radius)
        if len(rows) == 0:
            return []
        near = rows[self._pack.signed_distance(q[None, :], rows)[0] <= radius]
        return [self.obstacles[j].vertices for j in near]


def make_obstacle(name: str, entry: Any) -> Obstacle:
    """An Obstacle from a box [xmin, xmax, ymin, ymax] or a polygon [[x, y], ...]."""
    if isinstance(entry, Obstacle):
        return Obstacle(name, entry.vertices)
    if isinstance(entry, (list, tuple, np.ndarray)) and len(entry) == 4:
        if all(isinstance(v, (int, float, np.floating, np.integer)) for v in entry):
            if any(isinstance(v, bool) for v in entry):
                raise ValueError(f"{name}: box {list(entry)!r}: need numbers, not booleans")
            try:
                return Obstacle(name, box_vertices(entry))
            except ValueError as exc:
                raise ValueError(f"{name}: {exc}") from None
    if isinstance(entry, (list, tuple, np.ndarray)) and all(
        isinstance(v, (list, tuple, np.ndarray)) for v in entry
    ):
        for v in entry:
            if any(isinstance(c, bool) or not isinstance(c, (int, float, np.number)) for c in v):
                raise ValueError(f"{name}: polygon vertex {list(v)!r} is not a pair of numbers")
        return Obstacle(name, np.asarray(entry, dtype=float))
    raise ValueError(
        f"{name}: {entry!r} is neither a box [xmin, xmax, ymin, ymax] "
        "nor a convex polygon [[x, y], ...]"
    )


def _subtract(a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """a minus b for convex CCW polygons, as disjoint convex pieces: the part of a outside
    edge i of b and inside edges 0..i-1, for each i (together: the part outside some edge)."""
    pieces = []
    inside = a
    b = drop_repeats(b)
    for start, end in zip(b, np.roll(b, -1, axis=0), strict=True):
        if len(inside) == 0:
            break
        outside = clip_halfplane(inside, end, start - end)
        if area(outside) > 0.0:
            pieces.append(outside)
        inside = clip_halfplane(inside, start, end - start)
    return pieces


def _disjoint_pieces(obstacles: Sequence[Obstacle], boxes: np.ndarray) -> tuple[np.ndarray, ...]:
    """Convex pieces with pairwise disjoint interiors whose union is the obstacles' union:
    each obstacle minus those before it. Only boxes that overlap with positive area are
    compared, so the disjoint boxes of a map cost one vectorised test each."""
    pieces: list[np.ndarray] = []
    owners: list[int] = []
    for j, obstacle in enumerate(obstacles):
        b = boxes[j]
        earlier = np.flatnonzero(
            (boxes[:j, 0] < b[1])
            & (boxes[:j, 1] > b[0])
            & (boxes[:j, 2] < b[3])
            & (boxes[:j, 3] > b[2])
        )
        mine = [obstacle.vertices]
        if len(earlier):
            overlapping = set(earlier.tolist())
            for piece, owner in zip(pieces, owners, strict=True):
                if owner in overlapping:
                    mine = [part for m in mine for part in _subtract(m, piece)]
        pieces += mine
        owners += [j] * len(mine)
    return tuple(pieces)
