"""Robots that drive into a still S from outside it, in the agents' closed loop
(covswarm.deploy.netsim): cells empty on the way in, so no Voronoi neighbour follows or
relays them. Shared by tests/test_approach_safety.py and scripts/approach_safety.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from columns import pair_distances

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import run_netsim
from covswarm.mission.scenario_files import scenario_from_dict
from covswarm.mission.scenarios import Scenario
from covswarm.tvd.drive import KHEPERA_IV

BODY = KHEPERA_IV.body_diameter  # m: closer than this, two robots touch


def still_square(agents: int, side: float, duration: float) -> Scenario:
    """A square S of ``side`` m centred on the origin that does not move, for ``agents``."""
    half = 0.5 * side
    square = [[-half, -half], [half, -half], [half, half], [-half, half]]
    return scenario_from_dict(
        {
            "name": "approach",
            "agents": agents,
            "kappa": 3.0,
            "duration": duration,
            "dynamics": "unicycle",
            "workspace": [-4.0, 4.0, -4.0, 4.0],
            "domain": {"kind": "keyframes", "times": [0.0, duration], "vertices": [square] * 2},
        }
    )


def scattered(agents: int, seed: int, half: float = 3.0, keep_out: float = 1.0) -> np.ndarray:
    """(agents, 3) start poses (m, m, rad): uniform in the square of half-size ``half`` m
    but outside the one of half-size ``keep_out`` m, at least 0.3 m apart, headings uniform."""
    rng = np.random.default_rng(seed)
    points: list[np.ndarray] = []
    while len(points) < agents:
        p = rng.uniform(-half, half, 2)
        if np.abs(p).max() >= keep_out and all(np.hypot(*(p - q)) > 0.3 for q in points):
            points.append(p)
    return np.array([(x, y, rng.uniform(-math.pi, math.pi)) for x, y in points])


def ring(agents: int, radius: float) -> np.ndarray:
    """(agents, 3) start poses evenly on a circle of ``radius`` m, each facing the centre:
    every pair heads for the others at the wheels' top speed."""
    angles = 2.0 * math.pi * np.arange(agents) / agents
    return np.c_[radius * np.cos(angles), radius * np.sin(angles), angles + math.pi]


@dataclass(frozen=True)
class Approach:
    """What a run of robots driving into S shows: the closest two robots came (m), the
    samples (0.1 s) at which two touched, the mission steps slowed by the unseen-speed
    limit (all robots), e_a at the end (m)."""

    closest: float
    touching: int
    speed_limited: int
    final_error: float


def approach(
    poses: np.ndarray,
    side: float,
    seed: int,
    rate: float = 10.0,
    latency: float = 0.0,
    duration: float = 15.0,
) -> Approach:
    """The robots of ``poses`` driving into a still square S of ``side`` m (no announced
    start: they start as placed) at ``rate`` Hz, their commands ``latency`` s late and the
    agents told so."""
    result = run_netsim(
        still_square(len(poses), side, duration),
        poses=poses,
        seed=seed,
        rate=rate,
        command_delay=latency,
        config=AgentConfig(command_latency=latency),
        announce_start=False,
    )
    apart = pair_distances(result.trajectories)
    return Approach(
        closest=float(apart.min()),
        touching=int((apart < BODY).any(axis=1).sum()),
        speed_limited=sum(int(s.get("speed_limited", 0)) for s in result.stats.values()),
        final_error=float(result.error[-1]),
    )
