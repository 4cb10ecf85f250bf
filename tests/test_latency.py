"""Latency compensation pieces (agent/latency.py) against independent references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from covswarm.agent.latency import ClockBound, CommandHistory, MissionTimeEstimate
from covswarm.tvd.drive import KHEPERA_IV


def euler_reference(pose, commands, taken, target, timeout, h=1e-5):
    """Tiny forward-Euler unicycle steps; at each instant the wheels are the newest command
    sent at or before it if younger than ``timeout``, else stopped; clamped like the robot."""
    x, y, th = pose
    t = taken
    walls = [c[0] for c in commands]
    while t < target - 1e-12:
        step = min(h, target - t)
        k = np.searchsorted(walls, t + 0.5 * step, side="right") - 1
        left = right = 0.0
        if k >= 0 and t + 0.5 * step - walls[k] <= timeout:
            left, right = (np.clip(v, -0.8, 0.8) for v in commands[k][1:])
        v, w = 0.5 * (left + right), (right - left) / KHEPERA_IV.wheel_separation
        mid = th + 0.5 * step * w
        x, y, th = x + step * v * math.cos(mid), y + step * v * math.sin(mid), th + step * w
        t += step
    return np.array([x, y, (th + math.pi) % (2 * math.pi) - math.pi])


@pytest.mark.parametrize("seed", range(3))
def test_prediction_matches_small_step_integration(seed: int) -> None:
    rng = np.random.default_rng(seed)
    history = CommandHistory(cmd_timeout=0.5)
    walls = np.cumsum(rng.uniform(0.05, 0.1, 10)) + 100.0
    walls[7:] += 0.6  # a gap longer than the command timeout: the robot stopped meanwhile
    commands = [(w, *rng.uniform(-1.0, 1.0, 2)) for w in walls]  # some beyond the limit
    for c in commands:
        history.add(*c)
    pose = np.array([0.3, -0.2, 2.5])
    taken = walls[2] + 0.03
    target = walls[-1] + 0.7  # past the last command's timeout
    predicted = history.predict(pose, taken, target)
    reference = euler_reference(pose, commands, taken, target, 0.5)
    # The reference resolves each switch to its 1e-5 s step: ~1e-5 m per switch at 0.8 m/s.
    np.testing.assert_allclose(predicted[:2], reference[:2], atol=1e-4)
    assert abs(math.remainder(predicted[2] - reference[2], 2 * math.pi)) < 1e-3


def test_prediction_without_commands_or_time_is_the_pose() -> None:
    history = CommandHistory()
    pose = np.array([1.0, 2.0, 0.5])
    np.testing.assert_array_equal(history.predict(pose, 10.0, 10.3), pose)
    history.add(10.1, 0.2, 0.2)
    np.testing.assert_array_equal(history.predict(pose, 10.3, 10.2), pose)
    moved = history.predict(pose, 10.0, 10.3)  # stopped until 10.1, then 0.2 s straight
    np.testing.assert_allclose(moved[:2], pose[:2] + 0.04 * np.array([np.cos(0.5), np.sin(0.5)]))
    with pytest.raises(ValueError):
        CommandHistory(cmd_timeout=0.0)


def test_clock_bound_corrects_a_sender_ahead_and_bounds_one_behind() -> None:
    rng = np.random.default_rng(0)
    for skew in (0.25, -0.25):  # sender's clock ahead of ours, then behind
        bound = ClockBound()
        for k in range(200):
            ours = 1000.0 + 0.05 * k
            transit = 0.001 + rng.exponential(0.01) + (0.3 if k % 3 else 0.0)  # late ones too
            bound.add(ours, ours + transit, ours + skew)  # stamped on the sender's clock
        if skew > 0:
            assert bound.bound == pytest.approx(-skew, abs=0.002)
            assert bound.to_local(1000.0 + skew) == pytest.approx(1000.0, abs=0.002)
        else:
            assert bound.bound == pytest.approx(-skew, abs=0.002)  # ours - theirs <= 0.25
            assert bound.to_local(999.75) == 999.75  # indistinguishable from delay


def test_mission_time_estimate_from_receipts_and_restart() -> None:
    clock = MissionTimeEstimate()
    assert clock.mission_time(5.0) is None
    rng = np.random.default_rng(1)
    # Mission time = our monotonic - 40 s; broadcasts at 20 Hz, some 0.2 s late.
    for k in range(100):
        sent = 50.0 + 0.05 * k
        clock.add(sent + 0.001 + rng.exponential(0.02) + 0.2 * (k % 4 == 1), sent - 40.0, k + 1)
    assert clock.mission_time(60.0) == pytest.approx(20.0, abs=0.002)
    # A restarted coordinator (seq from 1 again) on a mission clock 3 s behind.
    clock.add(56.0, 13.0, 1)
    assert clock.mission_time(57.0) == pytest.approx(14.0, abs=1e-9)
