"""An agent told a command latency (``--command-latency L``) looks L ahead consistently: its
own pose, S and the robots around it, in its local diagram and its safety filter, and it
samples its barrier over the drive's period plus L (docs/real-robots.md, "A column at the
safe distance, under latency")."""

from __future__ import annotations

import numpy as np
import pytest
from columns import SAFE, pair_distances, run_column

from covswarm.agent import brain as brain_module
from covswarm.agent.brain import filter_one
from covswarm.agent.neighborhood import Neighborhood


@pytest.mark.parametrize("seed", range(3))
def test_the_local_view_looks_ahead_by_the_latency_with_each_robots_velocity(seed: int) -> None:
    rng = np.random.default_rng(seed)
    hood = Neighborhood(0, stale_timeout=1.0, beacon_timeout=25.0, linger_period=0.5)
    hood.reckoned = {
        rid: tuple(rng.uniform(-1.0, 1.0, 4).tolist()) for rid in rng.choice(500, 30, False)
    }
    hood.table_ids = np.array(list(hood.reckoned), dtype=np.int64)
    hood.table = np.array(list(hood.reckoned.values()))
    ahead = rng.uniform(0.05, 0.3)
    for reach in (None, 0.4):
        now = hood.relevant(0.0, (0.0, 0.0), reach)
        later = hood.relevant(0.0, (0.0, 0.0), reach, ahead)
        assert list(later) == list(now)
        for rid, (x, y) in later.items():
            _, _, vx, vy = hood.reckoned[rid]
            assert (x, y) == pytest.approx((now[rid][0] + ahead * vx, now[rid][1] + ahead * vy))


@pytest.mark.parametrize(
    ("transit", "command_delay"),
    [(0.001, 0.1), (0.1, 0.0)],
    ids=["commands-late", "every-message-late"],
)
@pytest.mark.parametrize("seed", range(3))
def test_a_column_told_the_latency_keeps_its_distance(
    transit: float, command_delay: float, seed: int
) -> None:
    """Seven robots 0.165 m apart that S sets moving along them, their commands acting 0.1 s
    after they are computed, the agents told so: nobody comes within the safe distance
    (measured over seeds 0-4: 0.1624 m at the closest; before the agents looked ahead at
    their neighbours too, 0.1512 m, and the column lost its order)."""
    result, _, _ = run_column(
        0.165, 0.19, seed, transit=transit, command_delay=command_delay, latency=0.1
    )
    assert pair_distances(result.trajectories).min() >= SAFE - 1e-3


@pytest.mark.parametrize(("latency", "gain"), [(0.0, 10.0), (0.1, 5.0), (0.3, 2.5)])
def test_the_barrier_is_sampled_over_the_period_and_the_latency(
    monkeypatch: pytest.MonkeyPatch, latency: float, gain: float
) -> None:
    """At 10 Hz a brain told L s of latency filters at the gain of a 0.1 + L s period,
    min(10, 1 / (0.1 + L)) /s: its headway behind a robot moving at v is that of a driver
    reacting in 0.1 + L s."""
    gains: list[float] = []

    def recording(filtering):
        gains.append(filtering.gamma)
        return filter_one(filtering)

    monkeypatch.setattr(brain_module, "filter_one", recording)
    run_column(0.165, 0.19, 0, ramp=0.5, latency=latency, after=1.0)
    assert len(gains) > 50
    # the first mission step of each brain has no period measured yet (1 s: gain 1 / (1 + L))
    assert np.median(gains) == pytest.approx(gain, rel=1e-6)
    assert max(gains) == pytest.approx(gain, rel=1e-6)
