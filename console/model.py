"""The console's picture of a running swarm: a sans-IO state model fed with decoded messages.

console.server subscribes to the swarm's keys and feeds what arrives here (Domain, Status,
Pose, World, liveliness changes, steering replies); :meth:`SwarmView.snapshot` turns it into
the JSON document the page draws and ``GET /api/state`` returns, :meth:`SwarmView.world_document`
the arena (workspace, obstacles) the page fetches from ``GET /api/world`` when the snapshot's
world version changes (the arena is static and may hold a map's hundreds of pieces: it is not
resent at the frame rate). No zenoh, no clock of its own:
every method takes the time it happens at, so the model is unit-tested without a network.

The Voronoi cells and every robot's distance to its cell's centroid are computed here from
the latest poses and S, with covswarm.tvd.coverage (the same cells the agents compute); the
aggregate error e_a over the last minute is the coordinator's (Status), the authority.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from covswarm.protocol import Domain, Pose, Status

ERROR_WINDOW = 60.0  # s of mission time of e_a history sent to the page
POSE_TIMEOUT = 2.0  # s without a pose from a robot before it is no longer drawn
DIGITS = 4  # decimals of metres and radians in the JSON (0.1 mm): smaller frames
STEERING_LOG = 20  # steering outcomes kept for the page
# Route-less Statuses (sent every 0.5 s) before a route drawn from this console's own reply
# is dropped: one may have been sent before the goto was accepted and arrive after the reply.
ROUTE_GRACE = 2


@dataclass(frozen=True)
class RobotSeen:
    """The newest pose of one robot and when it arrived (monotonic s)."""

    x: float
    y: float
    theta: float
    received: float


def _round(value: float) -> float:
    return round(float(value), DIGITS)


def _points(array: np.ndarray) -> list[list[float]]:
    """(m, 2) array -> JSON list of [x, y] rounded to DIGITS."""
    return np.round(np.asarray(array, dtype=float), DIGITS).tolist()


def polygon_centroid(vertices: np.ndarray) -> np.ndarray:
    """Area centroid (2,) m of a simple polygon (k, 2) m (shoelace formula); the vertex mean
    for a degenerate one (zero area)."""
    x, y = vertices[:, 0], vertices[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    twice_area = cross.sum()
    if abs(twice_area) < 1e-12:
        return vertices.mean(axis=0)
    return np.array(
        [((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]
    ) / (3.0 * twice_area)


def cells_and_errors(
    positions: np.ndarray, polygon: np.ndarray, density: Any = None
) -> tuple[list[np.ndarray], np.ndarray]:
    """Each robot's Voronoi cell clipped to S and its distance to the cell's centroid.

    positions: (n, 2) m; polygon: (k, 2) m, convex; density: None (uniform) or a
    covswarm.tvd.density.Density. Returns n arrays (m_i, 2) of counter-clockwise vertices
    ((0, 2) for an empty cell) and ||p_i - c_i|| (n,) in m, whose norm is the aggregate
    error e_a (Section 5). One tessellation for both (tvd.coverage.cells and mass_centroid
    would build it twice). Raises ValueError for an invalid polygon or density.
    """
    from covswarm.tvd.coverage import as_vectors, tessellate

    points, _, batch = tessellate(positions, polygon, density=density)
    cells = [batch.vertices(i) for i in range(len(points))]
    errors = np.linalg.norm(points - as_vectors(batch.centroid), axis=1)
    return cells, errors


class SwarmView:
    """What the console knows about one swarm, and the JSON state document built from it.

    Times: ``now`` is the console's monotonic clock (s), used for pose freshness; mission
    time comes from the coordinator's messages.
    """

    def __init__(
        self, swarm: str, error_window: float = ERROR_WINDOW, pose_timeout: float = POSE_TIMEOUT
    ) -> None:
        self.swarm = swarm
        self.error_window = error_window
        self.pose_timeout = pose_timeout
        self.domain: Domain | None = None
        self.status: Status | None = None
        self.robots: dict[int, RobotSeen] = {}
        self.alive: dict[str, set[int]] = {"agent": set(), "robot": set(), "coordinator": set()}
        self.errors: deque[tuple[float, float]] = deque()  # (mission t, e_a) from Status
        self.steering: deque[dict[str, Any]] = deque(maxlen=STEERING_LOG)
        # Input dropped, per reason (a ProtocolError's reason, or "geometry" for a domain
        # whose polygon or density the cells could not be built from): counted, never shown
        # as if it were the swarm's state.
        self.dropped: dict[str, int] = {}
        # (wire dict, Density, what the page draws of it): parsed once per change of density
        self._density_cache: tuple[Any, Any, dict[str, Any]] | None = None
        self.world: dict[str, Any] | None = None  # world_document(), None before any World
        self._world_content: tuple[Any, ...] | None = None  # what the version counts changes of
        # The route S follows (see on_status and on_steering), drawn while it runs.
        self.route: dict[str, Any] | None = None
        # Route-less Statuses a route from this console's own reply outlives (ROUTE_GRACE,
        # then 0 once a Status confirmed it).
        self._route_grace = 0
        self.arena_version = 0  # counts changes of the arena (World content), 0 before one
        self.map_png: bytes | None = None  # the map's picture (a PNG) for the page, or None
        self._map_answered = 0  # the arena version whose map query was answered

    # -- inputs -----------------------------------------------------------------------------

    def on_domain(self, domain: Domain) -> None:
        """A Domain broadcast (the coordinator's S(t))."""
        self.domain = domain

    def on_status(self, status: Status) -> None:
        """A Status broadcast: e_a joins the history while the mission runs, and its route
        (the goto S follows, whoever sent it) becomes the route drawn; a Status without
        one ends it (after ROUTE_GRACE of them for a route this console's own steering
        reply drew before any Status told it: an older Status may arrive after the reply)."""
        self.status = status
        self._status_route(status.route)
        if self.errors and status.t < self.errors[-1][0]:
            self.errors.clear()  # mission time went back: a new mission (or coordinator)
        if status.state == "running" and status.error is not None:
            self.errors.append((status.t, status.error))
        while self.errors and self.errors[0][0] < status.t - self.error_window:
            self.errors.popleft()

    def on_pose(self, pose: Pose, now: float) -> None:
        """A robot's pose, received at ``now`` (monotonic s)."""
        self.robots[pose.id] = RobotSeen(pose.x, pose.y, pose.theta, now)

    def on_liveliness(self, role: str, ident: int, alive: bool) -> None:
        """A liveliness token of (role, id) appeared or vanished."""
        members = self.alive.setdefault(role, set())
        if alive:
            members.add(ident)
        else:
            members.discard(ident)
            if role == "robot":
                self.robots.pop(ident, None)

    def on_world(self, world: Any) -> None:
        """A World broadcast (protocol.World: workspace, obstacles, names). The coordinator
        repeats it every second: the version goes up only when the arena changes, so the
        page fetches it again only then."""
        content = (world.workspace, world.obstacles, world.names)
        if content == self._world_content:
            return
        self._world_content = content
        self.arena_version += 1
        self.map_png = None  # a new arena: its map is asked for again (map_wanted)
        version = 1 if self.world is None else self.world["version"] + 1
        self.world = {
            "version": version,
            "map": None,
            "workspace": None if world.workspace is None else [_round(v) for v in world.workspace],
            "obstacles": [
                {"name": name, "polygon": _points(np.asarray(polygon, dtype=float))}
                for name, polygon in zip(world.names, world.obstacles, strict=True)
            ],
        }

    def on_dropped(self, reason: str) -> None:
        """Count one dropped input (malformed message, unusable geometry)."""
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def on_steering(self, outcome: dict[str, Any]) -> None:
        """Record one steering request's outcome (console.server's dict) for the page.

        An accepted goto with a route (outcome["route"]: its stops [x, y, scale] or [x, y,
        scale, angle], S's centroid in m, its size relative to S when the route starts and
        its rotation since, SteerReply.route) becomes the route drawn at once: {"goal":
        [x, y], "waypoints": the stops, "shape": S's vertices relative to its centroid when
        the goto was accepted (m; the page draws S at each stop as shape scaled and rotated;
        [] before any Domain), "wall": s, "duration": s}. Any other accepted request ends
        it. The coordinator's Statuses then tell it (on_status: the route of a goto sent by
        any client is drawn the same way, its wall and duration None)."""
        self.steering.append(dict(outcome))
        if not outcome.get("accepted"):
            return
        request = outcome.get("request") or {}
        route = outcome.get("route")
        if request.get("kind") == "goto" and route:
            self.route = {
                "goal": [_round(v) for v in request["goal"]],
                "waypoints": [[_round(v) for v in stop] for stop in route],
                "shape": self._shape(),
                "wall": outcome.get("wall"),
                "duration": outcome.get("duration"),
            }
            self._route_grace = ROUTE_GRACE
        else:
            self.route = None

    def _status_route(self, stops: Any) -> None:
        if stops is None:
            if self.route is not None:
                self._route_grace -= 1
                if self._route_grace <= 0:
                    self.route = None
            return
        waypoints = [[_round(v) for v in stop] for stop in stops]
        self._route_grace = 0  # told by the coordinator: gone with the first Status without
        if self.route is not None and self.route["waypoints"] == waypoints:
            return
        self.route = {
            "goal": waypoints[-1][:2],
            "waypoints": waypoints,
            "shape": self._shape(),
            "wall": None,
            "duration": None,
        }

    def _shape(self) -> list[list[float]]:
        """S's vertices relative to its centroid now (m), [] before any Domain."""
        if self.domain is None:
            return []
        vertices = np.asarray(self.domain.vertices, dtype=float)
        return _points(vertices - polygon_centroid(vertices))

    def on_map(self, arena_version: int, image: Any) -> None:
        """The coordinator's answer to the map query made for ``arena_version``: a
        protocol.MapImage (drawn under the obstacles) or None (the scenario has no map).
        An answer for an older arena is ignored. The world document's version goes up
        with a picture, so the page fetches it again."""
        if arena_version != self.arena_version or self.world is None:
            return
        self._map_answered = arena_version
        if image is None:
            return
        self.map_png = image.png
        self.world["map"] = {
            "origin": [_round(v) for v in image.origin],
            "resolution": image.resolution,
            "width": image.width,
            "height": image.height,
        }
        self.world["version"] += 1

    def map_wanted(self) -> int | None:
        """The arena version whose map picture to ask the coordinator for, None when there
        is no arena yet or its map query was answered."""
        if self.arena_version == 0 or self._map_answered == self.arena_version:
            return None
        return self.arena_version

    def world_document(self) -> dict[str, Any] | None:
        """The arena for the page, None before any World: {version, workspace ([xmin, xmax,
        ymin, ymax] m or None), obstacles ([{name, polygon [[x, y], ...] CCW m}]), map (None,
        or the picture's {origin [x, y] m of its lower-left corner, resolution m per pixel,
        width, height} pixels: the page draws ``map_png`` there, row 0 at the top)}. Its
        size is bounded by the World message's (protocol.World)."""
        return self.world

    # -- output -----------------------------------------------------------------------------

    def fresh_robots(self, now: float) -> dict[int, RobotSeen]:
        """Robots whose last pose is at most ``pose_timeout`` old, by id."""
        stale = [i for i, seen in self.robots.items() if now - seen.received > self.pose_timeout]
        for ident in stale:
            del self.robots[ident]
        return dict(sorted(self.robots.items()))

    def _density(self) -> tuple[Any, dict[str, Any] | None]:
        """The domain's density as a tvd Density and as the page draws it (see ``snapshot``),
        (None, None) when uniform; parsed once per change. ValueError if malformed."""
        wire = None if self.domain is None else self.domain.density
        if wire is None:
            return None, None
        if self._density_cache is None or self._density_cache[0] is not wire:
            from covswarm.tvd.density import Density

            density = Density.from_dict(wire)
            view = {
                "floor": float(density.floor),
                "bumps": [
                    {"mean": _points(mean), "precision": _points(precision), "weight": _round(w)}
                    for mean, precision, w in zip(
                        density.means, density.precisions, density.weights, strict=True
                    )
                ],
            }
            self._density_cache = (wire, density, view)
        return self._density_cache[1:]

    def snapshot(self, now: float, wall: float) -> dict[str, Any]:
        """The state document (JSON-ready) at monotonic ``now`` and wall-clock ``wall``.

        Keys: swarm, stamp (wall s), t (mission s, None before any Domain), state
        ("waiting" | "running" | "done" | "unknown"), polygon ([[x, y]] CCW as broadcast,
        [] before any Domain), velocities, robots ([{id, x, y, theta, error, cell}] with
        error = ||p_i - c_i|| in m and cell its Voronoi cell, both None without a usable S),
        error (the coordinator's e_a), error_history ([[t, e_a]] over the last
        ``error_window`` s), alive ({agents, robots, coordinator}), steering (latest
        outcomes, newest last), dropped (per reason), density (None: uniform; else
        {floor, bumps: [{mean [x, y] m, precision [[a, b], [b, c]] 1/m^2, weight}]}: phi(q) =
        floor + sum weight exp(-1/2 (q - mean)^T precision (q - mean)) at the broadcast's t,
        which the page shades inside S), world (None before any World, else {version,
        obstacles (count)}: the page fetches ``world_document`` when the version changes),
        route (the newest accepted goto's route, see ``on_steering``, or None).
        """
        robots = self.fresh_robots(now)
        domain = self.domain
        density, density_view, usable = None, None, True
        try:
            density, density_view = self._density()
        except ValueError:  # no cells from it, nothing shaded
            usable = False
        polygon = np.asarray(domain.vertices, dtype=float) if domain else np.zeros((0, 2))
        cells: list[Any] = [None] * len(robots)
        errors: list[Any] = [None] * len(robots)
        if domain is not None and robots:
            positions = np.array([(r.x, r.y) for r in robots.values()])
            built = None
            if usable:
                try:
                    built, distances = cells_and_errors(positions, polygon, density)
                except ValueError:
                    pass
            if built is None:
                self.on_dropped("geometry")
            else:
                cells = [_points(cell) for cell in built]
                errors = [_round(d) for d in distances]
        status = self.status
        return {
            "swarm": self.swarm,
            "stamp": wall,
            "t": None if domain is None else domain.t,
            "state": "unknown" if domain is None else domain.state,
            "polygon": _points(polygon),
            "velocities": [] if domain is None else _points(np.asarray(domain.velocities)),
            "robots": [
                {
                    "id": ident,
                    "x": _round(seen.x),
                    "y": _round(seen.y),
                    "theta": _round(math.remainder(seen.theta, math.tau)),
                    "error": errors[k],
                    "cell": cells[k],
                }
                for k, (ident, seen) in enumerate(robots.items())
            ],
            "error": None if status is None else status.error,
            "error_history": [[t, e] for t, e in self.errors],
            "alive": {
                "agents": len(self.alive.get("agent", ())),
                "robots": len(self.alive.get("robot", ())),
                "coordinator": bool(self.alive.get("coordinator")),
            },
            "steering": list(self.steering),
            "dropped": dict(self.dropped),
            "density": density_view,
            "world": None
            if self.world is None
            else {"version": self.world["version"], "obstacles": len(self.world["obstacles"])},
            "route": self.route,
        }
