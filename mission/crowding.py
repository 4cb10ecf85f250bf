"""Whether a team fits its domain: the smallest cell a CVT would give it, against a robot's room.

A centroidal Voronoi tessellation under a density phi has cells of area proportional to
phi^(-1/2) (Gersho's asymptotics in the plane; exact for uniform phi), so with N robots in S

    A_min = (integral over S of phi^(1/2) dq) / (N sqrt(max over S of phi))      (m^2).

Robots of diameter d kept apart by a margin m (covswarm.tvd.safety) pack at best
hexagonally, sqrt(3)/2 (d + m)^2 of area each. A mission whose smallest cell is below that
asks for robots closer than their bodies allow: the safety filter holds them apart, the
CVT is out of reach and each agent's neighbourhood crowds (a 100-robot run of the
``formation`` built-in lost its domain that way). Pure functions; the estimate is checked
against converged simulations in tests/test_crowding.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from covswarm.tvd.safety import DEFAULT_MARGIN

# Points per side of the grid over S's bounding box for the two integrals (the density's
# bumps are smooth; 96^2 points resolve a bump a tenth of S's width to about 1 %).
GRID = 96
# Times per mission at which S and the density are examined.
TIMES = 9


@dataclass(frozen=True)
class Crowding:
    """The smallest CVT cell over the mission (m^2, at mission time ``t`` s) against the
    area one robot needs (m^2)."""

    smallest_cell: float
    needed: float
    t: float

    @property
    def crowded(self) -> bool:
        return self.smallest_cell < self.needed

    def to_dict(self) -> dict[str, Any]:
        return {
            "smallest_cell_m2": self.smallest_cell,
            "needed_m2": self.needed,
            "at_t": self.t,
            "crowded": self.crowded,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Crowding:
        """Inverse of ``to_dict`` (a summary.json's ``crowding``)."""
        return cls(data["smallest_cell_m2"], data["needed_m2"], data["at_t"])

    def warning(self, agents: int, safety: bool = True) -> str:
        """What to tell the user; ``safety``: whether a safety filter keeps robots apart."""
        consequence = (
            "the safety filter will hold the robots apart and the team cannot reach the CVT"
            if safety
            else "without a safety filter the robots will overlap"
        )
        return (
            f"{agents} robots do not fit: at t = {self.t:.1f} s the smallest cell of the "
            f"coverage would be {self.smallest_cell:.4f} m^2, and a robot needs "
            f"{self.needed:.4f} m^2; {consequence} (fewer robots, or a larger domain)"
        )


# Least area of S per robot, in robot rooms: the steering's too-small rule
# (covswarm.coordinator.steering.MIN_ROOMS, which the mission room cannot import).
MIN_ROOMS = 2.0


def least_domain(
    agents: int, robot_diameter: float, margin: float = DEFAULT_MARGIN
) -> tuple[float, float]:
    """The smallest S a team may take: (area in m^2, MIN_ROOMS robot rooms per robot; width
    in m, one body with ``margin`` either side)."""
    return agents * MIN_ROOMS * robot_room(robot_diameter, margin), robot_diameter + 2 * margin


def robot_room(diameter: float, margin: float) -> float:
    """Area (m^2) per robot of diameter ``diameter`` m kept ``margin`` m apart, packed
    hexagonally: sqrt(3)/2 (d + m)^2."""
    return 0.5 * math.sqrt(3.0) * (diameter + margin) ** 2


def smallest_cell_area(polygon: np.ndarray, agents: int, density: Any = None) -> float:
    """Estimated smallest CVT cell (m^2) of ``agents`` robots in the convex CCW ``polygon``
    (k, 2) m under ``density`` (anything with ``phi(q)`` for q (m, 2); None: uniform)."""
    if agents < 1:
        raise ValueError(f"agents must be positive, got {agents}")
    polygon = np.asarray(polygon, dtype=float)
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    step = (high - low) / GRID
    axes = [low[i] + step[i] * (np.arange(GRID) + 0.5) for i in range(2)]
    q = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    edges = np.roll(polygon, -1, axis=0) - polygon
    # Inside a CCW convex polygon: left of every edge.
    cross = edges[:, 0] * (q[:, None, 1] - polygon[:, 1]) - edges[:, 1] * (
        q[:, None, 0] - polygon[:, 0]
    )
    q = q[np.all(cross >= 0.0, axis=1)]
    cell = float(step[0] * step[1])
    if density is None:
        return len(q) * cell / agents
    phi = np.asarray(density.phi(q), dtype=float)
    return float(np.sqrt(phi).sum() * cell / (agents * math.sqrt(phi.max())))


def crowding(
    scenario: Any, agents: int, duration: float, margin: float = DEFAULT_MARGIN
) -> Crowding:
    """The mission's most crowded moment: ``scenario`` (covswarm.mission.scenarios.Scenario)
    with ``agents`` robots of its ``robot_diameter`` kept ``margin`` m apart, S and the
    density examined at TIMES times over [0, duration] s."""
    needed = robot_room(scenario.robot_diameter, margin)
    worst = None
    for t in np.linspace(0.0, duration, TIMES):
        polygon = scenario.motion(float(t))[0]
        area = smallest_cell_area(polygon, agents, scenario.density(float(t)))
        if worst is None or area < worst[0]:
            worst = (area, float(t))
    assert worst is not None
    return Crowding(worst[0], needed, worst[1])
