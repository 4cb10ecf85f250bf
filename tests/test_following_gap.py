"""A column of robots following S opens to the safety filter's headway (docs/scaling.md, "The
start wave is the filter's headway").

The reciprocal split (covswarm.tvd.safety) clips each robot's share of a pair's motion to
+-gamma h / 2, so a robot behind another on their line may close on it at most at
gamma (d^2 - D^2) / (2 d) m/s, whatever the two drive: to follow at speed v it needs the gap
d*(v) = v / gamma + sqrt((v / gamma)^2 + D^2). A column standing closer than that when S
starts opens link by link, and its tail lags (n - 1) (d* - spacing) behind its head.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import NetsimResult, run_netsim
from covswarm.mission.scenario_files import scenario_from_dict
from covswarm.tvd.drive import KHEPERA_IV
from covswarm.tvd.safety import DEFAULT_GAMMA, body_safe_distance, pair_constraints

SAFE = body_safe_distance(KHEPERA_IV.body_diameter)  # 0.16 m


def headway(speed: float, safe: float = SAFE, gamma: float = DEFAULT_GAMMA) -> float:
    """d*(v): the least gap at which the split lets a robot follow another at ``speed``."""
    return speed / gamma + math.sqrt((speed / gamma) ** 2 + safe**2)


@pytest.mark.parametrize("seed", range(4))
def test_the_split_caps_a_followers_closing_speed_whatever_the_pair_drives(seed: int) -> None:
    """A follower at distance d behind its leader, both driving along their line fast
    enough for the clip to hold (2 d |v| >= gamma h / 2): its row allows it at most
    gamma (d^2 - D^2) / (2 d) toward the leader, the same for every such velocity."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        d = rng.uniform(SAFE + 1e-3, 0.3)
        gamma = rng.uniform(2.0, 10.0)
        cap = gamma * (d * d - SAFE * SAFE) / (2.0 * d)
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        leader = rng.uniform(-1.0, 1.0, 2)
        follower = leader - d * direction
        speed = rng.uniform(1.01 * cap / 2.0, 1.0)  # the clip saturates from cap / 2 on
        drive = speed * direction
        A, b = pair_constraints(follower, leader[None], SAFE, gamma, drive, drive[None])
        along = float(A[0] @ direction)  # the row's coefficient of speed toward the leader
        assert along == pytest.approx(2.0 * d, rel=1e-12)
        assert b[0] / along == pytest.approx(cap, rel=1e-9, abs=1e-12)
        # and no faster whatever the leader reports beyond that
        faster = (speed + 0.5) * direction
        A, b_faster = pair_constraints(follower, leader[None], SAFE, gamma, drive, faster[None])
        assert b_faster[0] == pytest.approx(b[0], rel=1e-12)


def pair_distances(trajectories: np.ndarray) -> np.ndarray:
    """(T, n (n - 1) / 2) m: the distance of every pair of robots at every sample of
    ``trajectories`` (T, n, 2)."""
    apart = np.linalg.norm(trajectories[:, :, None] - trajectories[:, None], axis=-1)
    first, second = np.triu_indices(trajectories.shape[1], 1)
    return apart[:, first, second]


def column(spacing: float, speed: float, rows: int = 7, ramp: float = 2.0, duration: float = 8.0):
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
) -> tuple[NetsimResult, np.ndarray, Callable[[float], float]]:
    """The agents' closed loop (covswarm.deploy.netsim) over :func:`column` for 6 s after S
    reached ``speed``: every message ``transit`` s late, the commands ``command_delay`` s
    later still, the agents told a command latency of ``latency`` s. Returns the result,
    the start poses and S's shift at t."""
    scenario, poses, shift = column(spacing, speed, ramp=ramp, duration=ramp + 6.0)
    result = run_netsim(
        scenario,
        poses=poses,
        seed=seed,
        transit=transit,
        command_delay=command_delay,
        config=AgentConfig(command_latency=latency),
    )
    return result, poses, shift


@pytest.mark.parametrize(
    ("spacing", "speed"),
    [(0.165, 0.19), (0.165, 0.10), (0.19, 0.19)],
    ids=["at-the-safe-distance", "slower", "beyond-the-headway"],
)
def test_a_column_opens_to_the_filters_headway_and_no_further(spacing: float, speed: float) -> None:
    """The agents' closed loop (covswarm.deploy.netsim): 6 s after S reached its speed every
    gap of a column that stood closer than d*(v) is d*(v) (measured over seeds 0-4: within
    0.4 mm), and its tail lags the head by the links' openings; a column that stood farther
    apart keeps its spacing and barely lags. Nobody comes within the safe distance."""
    result, poses, shift = run_column(spacing, speed, seed=1)
    y = result.trajectories[-1][:, 1]  # robot 0 at the tail
    gaps = np.diff(y)
    lag = shift(float(result.t[-1])) - (y - poses[:, 1])
    target = headway(speed)
    if spacing < target:
        assert np.all(np.abs(gaps - target) < 1.5e-3), (gaps, target)
        opened = (len(y) - 1) * (target - spacing)
        assert lag[0] - lag[-1] == pytest.approx(opened, rel=0.1)
    else:
        assert np.all(np.abs(gaps - spacing) < 3e-3), gaps
        assert np.all(np.abs(lag) < 0.01), lag
    assert pair_distances(result.trajectories).min() >= SAFE - 1e-3
