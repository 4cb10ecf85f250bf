"""A column of robots that S sets moving along them, in the agents' closed loop
(covswarm.deploy.netsim), and the safety filter's headway d*(v) it opens to: shared by
tests/test_following_gap.py, tests/test_command_latency.py and scripts/column_wave.py."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import NetsimResult, run_netsim
from covswarm.mission.scenario_files import scenario_from_dict
from covswarm.tvd.drive import KHEPERA_IV
from covswarm.tvd.safety import (
    DEFAULT_GAMMA,
    RECEDE_SHARE,
    RECEDE_SLACK,
    body_safe_distance,
)

SAFE = body_safe_distance(KHEPERA_IV.body_diameter)  # 0.16 m


def recede_cap(safe: float = SAFE, gamma: float = DEFAULT_GAMMA) -> float:
    """The most a receding neighbour adds to a robot's bound: gamma (D^2 - (D - slack)^2) / 2."""
    return 0.5 * gamma * (safe**2 - (safe - RECEDE_SLACK) ** 2)


def headway(speed: float, safe: float = SAFE, gamma: float = DEFAULT_GAMMA) -> float:
    """d*(v): the least gap at which the split lets a robot follow another at ``speed``.

    Following at v the follower's row reads 2 d v <= gamma (d^2 - D^2) + min(RECEDE_SHARE
    2 d v, cap): d must clear both roots, 2 d v (1 - RECEDE_SHARE) = gamma (d^2 - D^2) and
    2 d v - cap = gamma (d^2 - D^2)."""
    shared = (1.0 - RECEDE_SHARE) * speed / gamma
    uncapped = shared + math.sqrt(shared**2 + safe**2)
    capped = speed + math.sqrt(speed**2 + gamma * (gamma * safe**2 - recede_cap(safe, gamma)))
    return max(uncapped, capped / gamma)


def pair_distances(trajectories: np.ndarray) -> np.ndarray:
    """(T, n (n - 1) / 2) m: the distance of every pair of robots at every sample of
    ``trajectories`` (T, n, 2)."""
    apart = np.linalg.norm(trajectories[:, :, None] - trajectories[:, None], axis=-1)
    first, second = np.triu_indices(trajectories.shape[1], 1)
    return apart[:, first, second]


def column(spacing: float, speed: float, ramp: float, duration: float, rows: int = 7):
    """A one-robot-wide S of ``rows`` cells ``spacing`` m tall, a robot at each cell's centre
    facing S's motion (+y): S's speed ramps from 0 to ``speed`` over ``ramp`` s (knots of a
    keyframes scenario). Returns (scenario, poses (rows, 3), S's shift at t (m))."""
    width = 0.25
    box = np.array([(0, 0), (width, 0), (width, rows * spacing), (0, rows * spacing)], float)

    def shift(t: float) -> float:
        return 0.5 * speed * min(t, ramp) ** 2 / ramp + speed * max(t - ramp, 0.0)

    times = [*np.linspace(0.0, ramp, 9).tolist(), duration]
    scenario = scenario_from_dict(
        {
            "name": "column",
            "agents": rows,
            "kappa": 3.0,
            "duration": duration,
            "dynamics": "unicycle",
            "workspace": [-2.0, 2.0, -2.0, 2.0 + speed * duration + rows * spacing],
            "domain": {
                "kind": "keyframes",
                "times": times,
                "vertices": [(box + (0.0, shift(t))).tolist() for t in times],
            },
        }
    )
    poses = np.array([(0.5 * width, (r + 0.5) * spacing, 0.5 * math.pi) for r in range(rows)])
    return scenario, poses, shift


def run_column(
    spacing: float,
    speed: float,
    seed: int,
    ramp: float = 2.0,
    transit: float = 0.001,
    command_delay: float = 0.0,
    latency: float = 0.0,
    after: float = 6.0,
) -> tuple[NetsimResult, np.ndarray, Callable[[float], float]]:
    """The agents' closed loop (covswarm.deploy.netsim) over :func:`column` for ``after`` s
    after S reached ``speed``: every message ``transit`` s late, the commands ``command_delay`` s
    later still, the agents told a command latency of ``latency`` s. Returns the result,
    the start poses and S's shift at t."""
    scenario, poses, shift = column(spacing, speed, ramp, ramp + after)
    result = run_netsim(
        scenario,
        poses=poses,
        seed=seed,
        transit=transit,
        command_delay=command_delay,
        config=AgentConfig(command_latency=latency),
    )
    return result, poses, shift
