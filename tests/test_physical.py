"""Physical figures of a run (mission/physical.py) against brute-force references."""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.mission.physical import physical_summary, proximity, wheel_figures


def brute_force(t: np.ndarray, traj: np.ndarray, diameter: float) -> tuple[float, int, float]:
    """(smallest distance, episodes, pair-seconds) from every pair at every sample."""
    T, n, _ = traj.shape
    d = np.linalg.norm(traj[:, :, None] - traj[:, None], axis=3)  # (T, n, n), NaN if unknown
    iu = np.triu_indices(n, 1)
    pair_d = d[:, iu[0], iu[1]]  # (T, pairs)
    close = np.where(np.isnan(pair_d), False, pair_d < diameter)
    starts = close & ~np.vstack([np.zeros((1, close.shape[1]), bool), close[:-1]])
    held = np.diff(t, append=t[-1])
    return float(np.nanmin(pair_d)), int(starts.sum()), float((close * held[:, None]).sum())


@pytest.mark.parametrize("seed", range(8))
def test_proximity_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T, n = 60, int(rng.integers(2, 12))
    t = np.cumsum(rng.uniform(0.05, 0.15, T))
    traj = np.cumsum(rng.normal(scale=0.05, size=(T, n, 2)), axis=0) + rng.uniform(0, 0.6, (n, 2))
    traj[rng.random((T, n)) < 0.1] = np.nan  # robots unknown at some samples
    diameter = 0.14
    smallest, when, approaches = proximity(t, traj, diameter)
    ref_min, ref_count, ref_time = brute_force(t, traj, diameter)
    assert smallest == pytest.approx(ref_min, abs=1e-12)
    assert len(approaches) == ref_count
    assert sum(a.duration for a in approaches) == pytest.approx(ref_time, abs=1e-9)
    for a in approaches:
        assert a.closest < diameter and a.pair[0] < a.pair[1]


def test_summary_keys_and_ids() -> None:
    t = np.array([0.0, 0.1, 0.2, 0.3])
    # Robots 7 and 9 (columns 0, 1) meet for two samples, then part.
    traj = np.array([[[0, 0], [1, 0]], [[0, 0], [0.1, 0]], [[0, 0], [0.05, 0]], [[0, 0], [1, 0]]])
    summary, approaches = physical_summary(t, traj.astype(float), 0.14, ids=[7, 9])
    assert summary["min_pairwise_distance"] == pytest.approx(0.05)
    assert summary["min_distance_t"] == pytest.approx(0.2)
    assert summary["close_approaches"] == 1
    assert summary["close_approach_time"] == pytest.approx(0.2)
    assert summary["close_approach_list"][0]["pair"] == [7, 9]
    assert summary["close_approach_list"][0]["at"] == pytest.approx([0.025, 0.0])
    lone = physical_summary(t, traj[:, :1].astype(float), 0.14)[0]
    assert lone["min_pairwise_distance"] is None and lone["close_approaches"] == 0


def test_wheel_figures() -> None:
    t = np.array([0.0, 0.1, 0.2, 0.3])
    wheels = np.array(
        [[[0.1, 0.2], [0.8, 0.3]], [[-0.8, 0.5], [0.0, 0.0]], [[0.3, 0.3], [0.5, -0.2]],
         [[np.nan, np.nan], [0.1, 0.1]]]
    )  # fmt: skip
    figures = wheel_figures(t, wheels, 0.8)
    assert figures["max_wheel_speed_used"] == pytest.approx(0.8)
    assert figures["saturated_time"] == pytest.approx(0.2)  # two commands held 0.1 s each
    assert figures["saturated_fraction"] == pytest.approx(2 / 7)


def test_sim_summary_reports_physical_figures(tmp_path) -> None:
    from covswarm.deploy.simulate import build_summary, simulate
    from covswarm.mission.scenario_files import load_scenario

    scenario = load_scenario("passage")
    options = dict(law="da", kappa=scenario.kappa, dt=0.05, duration=2.0, seed=0)
    result = simulate(scenario, agents=6, dynamics="unicycle", **options)
    summary = build_summary(scenario, result, feedforward=True, dynamics="unicycle", **options)
    d = np.linalg.norm(result.trajectories[:, :, None] - result.trajectories[:, None], axis=3)
    assert summary["min_pairwise_distance"] == pytest.approx((d + 9 * np.eye(6)).min())
    assert 0 < summary["max_wheel_speed_used"] <= 0.8 + 1e-12
    single = simulate(scenario, agents=6, dynamics="single", **options)
    summary = build_summary(scenario, single, feedforward=True, dynamics="single", **options)
    assert summary["max_wheel_speed_used"] is None


def brute_force_approaches(t, traj, diameter, ids):
    """Episodes by every pair at every sample (O(T n^2)): the reference for proximity."""
    n = traj.shape[1]
    steps = np.diff(t, append=t[-1])
    open_, done = {}, []
    for k in range(len(t)):
        now = set()
        for i in range(n):
            for j in range(i + 1, n):
                if not (np.isfinite(traj[k, i]).all() and np.isfinite(traj[k, j]).all()):
                    continue
                dist = float(np.hypot(*(traj[k, i] - traj[k, j])))
                if dist >= diameter:
                    continue
                now.add((i, j))
                mid = tuple(0.5 * (traj[k, i] + traj[k, j]))
                entry = open_.setdefault((i, j), [t[k], 0.0, dist, mid])
                entry[1] += steps[k]
                if dist < entry[2]:
                    entry[2], entry[3] = dist, mid
        for pair in [p for p in open_ if p not in now]:
            done.append((pair, *open_.pop(pair)))
    done += [(pair, *entry) for pair, entry in open_.items()]
    rows = [(tuple(sorted((ids[i], ids[j]))), s, d, c, a) for (i, j), s, d, c, a in done]
    return sorted(rows, key=lambda r: (r[1], r[0]))


@pytest.mark.parametrize("seed", range(6))
def test_close_approaches_are_the_brute_force_episodes(seed: int) -> None:
    """Random walks packed in a small box (many episodes opening, closing and reopening),
    some robots unknown at some samples, ids not 0..n-1."""
    rng = np.random.default_rng(seed)
    T, n, diameter = 40, 18, 0.14
    traj = rng.uniform(0.0, 0.6, (1, n, 2)) + np.cumsum(rng.normal(0, 0.03, (T, n, 2)), axis=0)
    traj[rng.random((T, n)) < 0.05] = np.nan
    t = np.cumsum(rng.uniform(0.05, 0.15, T))
    ids = list(rng.permutation(100)[:n])
    _, _, approaches = proximity(t, traj, diameter, ids)
    expected = brute_force_approaches(t, traj, diameter, ids)
    assert len(expected) > 20
    assert [a.pair for a in approaches] == [r[0] for r in expected]
    got = np.array([[a.start, a.duration, a.closest, *a.at] for a in approaches])
    want = np.array([[s, d, c, *at] for _, s, d, c, at in expected])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
