"""Latency compensation pieces (agent/latency.py) against independent references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, AgentConfig, Begun
from covswarm.agent.latency import HISTORY_SPAN, ClockBound, CommandHistory
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


def test_the_domain_is_extrapolated_by_the_age_of_its_stamp_not_of_its_receipt() -> None:
    """Each 20 Hz broadcast is taken 30 ms after it was sent (an agent takes it at its
    tick, whose phase it keeps): S is extrapolated over the age since its stamp, so exactly
    where it is. Its age since receipt left S 30 ms behind at every step."""
    wall, velocity = 1.7e9, np.array([0.2, 0.1])
    square = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)]
    brain = AgentBrain(0, AgentConfig(safety=False))
    for k in range(100):
        sent = 0.05 * k
        domain = protocol.Domain(
            seq=k + 1, stamp=wall + sent, t=sent, state="running",
            vertices=[tuple(np.add(v, velocity * sent)) for v in square],
            velocities=[tuple(velocity)] * 4, kappa=1.0,
        )  # fmt: skip
        assert brain.receive("domain", domain.encode(), sent + 0.03, wall + sent + 0.03)
    now = sent + 0.045  # 45 ms after the last broadcast was sent
    pose = protocol.Pose(id=0, x=1.0, y=1.0, theta=0.0, stamp=wall + now, seq=1)
    brain.receive("pose", pose.encode(), now, wall + now)
    begun = brain.begin(now, wall + now)
    assert isinstance(begun, Begun)
    np.testing.assert_allclose(begun.view.polygon, np.add(square, velocity * now), atol=1e-9)
    np.testing.assert_allclose(begun.view.polygon_velocity, [velocity] * 4)


def test_clock_bound_is_the_windowed_minimum() -> None:
    """Against brute force: the bound is the minimum of receipt - stamp over the messages
    of the last window s, on random arrivals with repeated values, bursts and silences
    longer than the window; clear forgets it."""
    rng = np.random.default_rng(1)
    bound = ClockBound(window=1.0)
    seen: list[tuple[float, float]] = []
    now = 0.0
    for k in range(1500):
        if k == 700:
            bound.clear()
            seen.clear()
            assert math.isnan(bound.bound)
        now += float(rng.choice([0.0, 0.01, 0.3, 1.5]))
        stamp = now - float(rng.choice([0.1, 0.2, rng.normal()]))
        bound.add(now, now, stamp)
        seen.append((now, now - stamp))
        assert bound.bound == min(value for t, value in seen[-200:] if t >= now - 1.0)


def test_command_history_keeps_the_last_span() -> None:
    """Against brute force: the commands kept are those sent within HISTORY_SPAN s of the
    last, all of them since the clock last stepped back."""
    rng = np.random.default_rng(2)
    history = CommandHistory()
    sent: list[tuple[float, float, float]] = []
    wall = 100.0
    for _ in range(600):
        wall += float(rng.choice([0.0, 0.05, 0.4, 3.0, -0.5]))
        left, right = (float(v) for v in rng.uniform(-0.5, 0.5, 2))
        if sent and wall < sent[-1][0]:
            sent.clear()
        history.add(wall, left, right)
        sent.append((wall, left, right))
        kept = [command for command in sent if command[0] >= wall - HISTORY_SPAN]
        assert [tuple(command) for command in history._sent] == kept


def segments_reference(commands, start, end, timeout):
    """The driving segments between ``start`` and ``end``, instant by instant from every
    command (brute force): on a fine grid, the newest command sent at or before each
    instant if younger than ``timeout``, else stopped; runs of equal wheels merged."""
    grid = np.linspace(start, end, 20001)
    mids = 0.5 * (grid[:-1] + grid[1:])
    wheels = []
    for t in mids:
        sent = [c for c in commands if c[0] <= t]
        newest = sent[-1] if sent else None
        on = newest is not None and t - newest[0] <= timeout
        wheels.append((newest[1], newest[2]) if on else (0.0, 0.0))
    durations: dict[tuple[float, float], float] = {}
    for w, a, b in zip(wheels, grid[:-1], grid[1:], strict=True):
        durations[w] = durations.get(w, 0.0) + (b - a)
    return durations


@pytest.mark.parametrize("seed", range(4))
def test_segments_of_a_recent_pose_match_every_command(seed: int) -> None:
    """A pose taken after most of the history (as every step's is): the segments start from
    the command driving at ``start`` (the scan from the newest), and drive each command as
    long as a brute-force replay of the whole history does."""
    rng = np.random.default_rng(seed)
    history = CommandHistory(cmd_timeout=0.3)
    walls = np.cumsum(rng.uniform(0.02, 0.1, 25)) + 50.0
    walls[5] = walls[4]  # two commands with one stamp: the later one drives
    walls[15:] += 0.5  # a gap beyond the timeout
    commands = [(float(w), *rng.uniform(-0.5, 0.5, 2).tolist()) for w in walls]
    for c in commands:
        history.add(*c)
    for start in [walls[0] - 0.1, walls[3], walls[4], walls[14] + 0.4, walls[-2] + 0.01]:
        end = start + rng.uniform(0.15, 0.6)
        got: dict[tuple[float, float], float] = {}
        for duration, left, right in history.segments(start, end):
            got[left, right] = got.get((left, right), 0.0) + duration
        assert math.isclose(sum(got.values()), end - start, rel_tol=1e-12)
        reference = segments_reference(commands, start, end, 0.3)
        grid_step = (end - start) / 20000
        for wheels in got.keys() | reference.keys():  # a sliver may fall between grid points
            assert abs(got.get(wheels, 0.0) - reference.get(wheels, 0.0)) <= 2.0 * grid_step
