"""A column of robots following S opens to the safety filter's headway (docs/scaling.md, "The
start wave is the filter's headway").

The reciprocal split (covswarm.tvd.safety) clips each robot's share of a pair's motion to
+-gamma h / 2, so a robot behind another on their line may close on it at most at
gamma (d^2 - D^2) / (2 d) m/s, whatever the two drive: to follow at speed v it needs the gap
d*(v) = v / gamma + sqrt((v / gamma)^2 + D^2). A column standing closer than that when S
starts opens link by link, and its tail lags (n - 1) (d* - spacing) behind its head.
"""

from __future__ import annotations

import numpy as np
import pytest
from columns import SAFE, headway, pair_distances, run_column

from covswarm.tvd.safety import pair_constraints


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
