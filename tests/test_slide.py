"""A robot that the safety filter stops dead beside a still robot turns toward its slide
(covswarm.tvd.drive.steer's ``slides``, covswarm.agent.brain.slide_velocity): the
velocity the same rows leave a robot that could move sideways; and it aims at its slide
until the rows no longer bend its aim (AgentBrain._safety_inputs). Facing its aim, it
waited for ever, its aim and the filter's row in balance: the deadlock of a robot behind a
stranded one (tests/test_faults.py's newcomer run, robot 4 0.160 m from robot 3, 75
degrees off its aim, for the last 10 s of the mission)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from script_modules import load_script

from covswarm.deploy.netsim import run_netsim
from covswarm.deploy.plan import initial_poses
from covswarm.mission.physical import proximity
from covswarm.mission.scenario_files import load_scenario
from covswarm.tvd.coverage import mass_centroid
from covswarm.tvd.drive import (
    BESIDE_ANGLE,
    BESIDE_REACH,
    KHEPERA_IV,
    SLIDE_MIN,
    STOPPED_SPEED,
    steer,
    steer_one,
    stopped_beside,
    stopped_dead,
    stopped_dead_one,
)

# One brain stepped at 10 Hz beside a stranded robot at the safe distance, with and
# without its slide (scripts/slide_escape.py, which draws docs/img/slide-escape.png).
escape = load_script("slide_escape")
AROUND = [10, 20, 30, 45, 60, -10, -40]  # degrees off the aim


@pytest.mark.parametrize("degrees", AROUND)
def test_a_robot_stopped_dead_beside_a_still_one_gets_past_it(degrees: int) -> None:
    brain, path, neighbour = escape.drive_past(math.radians(degrees))
    # Turned back toward its aim as soon as it faced its slide, it arced into the still
    # robot (to 0.149 m at 10 degrees) and was stopped again; aiming at its slide until
    # the rows no longer bend its aim, it keeps the safe distance (the barrier is sampled:
    # a 0.4 mm give at 60 degrees, with or without the slide).
    assert escape.closest(path, neighbour) >= escape.SAFE - 5e-4
    assert path[-1][0] > neighbour[0] + 0.25  # past it, on to S
    assert 1 <= brain.counters.slid <= 45
    assert brain._slide_side is None  # (the way clear: it aims where its law says)


@pytest.mark.parametrize("degrees", AROUND)
def test_facing_its_aim_it_waited_for_ever(degrees: int) -> None:
    brain, path, neighbour = escape.drive_past(math.radians(degrees), slides=False)
    assert path[-1][0] < neighbour[0]  # never past it
    assert brain.counters.slid == 0


@pytest.mark.parametrize("degrees", [0, 1, 3, -3])
def test_a_still_robot_dead_ahead_is_passed_on_the_side_away_from_it(degrees: int) -> None:
    # Within asin(SLIDE_MIN) (5.7 degrees) of its aim its slide is too short: it takes the
    # slide of its aim turned a quarter, to the side it passes on, away from the robot
    # (AgentBrain.slide_of; the left when it is dead ahead).
    brain, path, neighbour = escape.drive_past(math.radians(degrees))
    assert escape.closest(path, neighbour) >= escape.SAFE - 5e-4
    assert path[-1][0] > neighbour[0] + 0.25
    side = 1.0 if degrees <= 0 else -1.0
    assert side * path[-1][1] > 0.1
    assert 1 <= brain.counters.slid <= 45


def test_a_boxed_in_robot_waits() -> None:
    # Still robots all round, 60 degrees apart: no slide is SLIDE_MIN of its aim long, its
    # own or its aim's turned a quarter, and it waits, facing its aim.
    around = tuple(math.radians(a) for a in (60, -60, 120, -120, 180))
    brain, path, neighbour = escape.drive_past(0.0, also=around)
    assert math.hypot(path[-1][0] - escape.START[0], path[-1][1] - escape.START[1]) < 0.01
    assert brain.counters.slid == 0


def test_in_a_cup_of_still_robots_it_turns_about_and_keeps_its_distance() -> None:
    # Still robots at 0 and 60 degrees either side, the way back open: the slide of its aim
    # turned a quarter leads back along the cup's side, and it turns about in the cup
    # without getting out (138 steps slid in 15 s; before, it waited facing its aim). Never
    # closer than the safe distance; getting out of a cup is a planner's work.
    around = (math.radians(60.0), math.radians(-60.0))
    brain, path, neighbour = escape.drive_past(0.0, seconds=15.0, also=around)
    for angle in (0.0, *around):
        still = (
            escape.START[0] + (escape.SAFE + 1e-3) * math.cos(angle),
            escape.START[1] + (escape.SAFE + 1e-3) * math.sin(angle),
        )
        assert escape.closest(path, still) >= escape.SAFE - 5e-4
    assert path[-1][0] < neighbour[0]
    assert brain.counters.slid > 0


def test_steer_turns_toward_the_slide_only_when_stopped_dead() -> None:
    heading, aim = 0.0, (0.2, 0.0)
    slide = (0.1, -0.1)  # 45 degrees to the right
    # Stopped dead (forward speed 0): toward the slide, the right wheel slower.
    left, right, _ = steer_one(heading, 0.0, 0.0, KHEPERA_IV, 0.03, 0.1, aim, 1.0, slide)
    assert left > 0.0 > right and left == pytest.approx(-right)
    assert stopped_dead_one(heading, 0.0, 0.0, aim)
    # Moving (forward speed above 0), or the aim behind: the slide is not read.
    for velocity, aim_ in (((0.05, 0.0), aim), ((0.0, 0.0), (-0.2, 0.0))):
        assert not stopped_dead_one(heading, *velocity, aim_)
        assert steer_one(heading, *velocity, KHEPERA_IV, 0.03, 0.1, aim_, 1.0, slide) == (
            steer_one(heading, *velocity, KHEPERA_IV, 0.03, 0.1, aim_, 1.0)
        )
    # A slide under SLIDE_MIN of the aim's speed (boxed in): it faces its aim, as before.
    short = (0.0, -0.99 * SLIDE_MIN * 0.2)
    assert steer_one(heading, 0.0, 0.0, KHEPERA_IV, 0.03, 0.1, aim, 1.0, short) == (
        steer_one(heading, 0.0, 0.0, KHEPERA_IV, 0.03, 0.1, aim, 1.0)
    )
    # Capped for the hold: at most to face the slide.
    left, right, capped = steer_one(heading, 0.0, 0.0, KHEPERA_IV, 0.03, 0.5, aim, 1.0, slide)
    turned = (right - left) / KHEPERA_IV.wheel_separation * 0.5
    assert capped and turned == pytest.approx(-math.pi / 4)


def test_steer_and_steer_one_agree_with_slides() -> None:
    rng = np.random.default_rng(5)
    n = 400
    headings = rng.uniform(-4.0, 4.0, n)
    aims = rng.normal(0.0, 0.3, (n, 2))
    e = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    lateral = np.stack([-e[:, 1], e[:, 0]], axis=1)
    # The filter's answer: the aim's sideways part and a forward speed cut to 0 or below on
    # half the rows, kept on the rest.
    forward = np.einsum("ij,ij->i", aims, e)
    cut = rng.random(n) < 0.5
    forward = np.where(cut, -np.abs(rng.normal(0.0, 0.01, n)) * rng.integers(0, 2, n), forward)
    velocities = np.einsum("ij,ij->i", aims, lateral)[:, None] * lateral + forward[:, None] * e
    slides = rng.normal(0.0, 0.3, (n, 2)) * rng.choice([0.01, 1.0], (n, 1))
    slides[:10] = np.nan  # not read where not stopped dead; else a stopped robot
    holds = rng.choice([0.0, 0.1, 0.5], n)
    wheels, capped = steer(headings, velocities, KHEPERA_IV, 0.03, holds, aims, None, slides)
    plain = steer(headings, velocities, KHEPERA_IV, 0.03, holds, aims)[0]
    dead = stopped_dead(headings, velocities, aims)
    assert 50 < np.count_nonzero(dead) < 300
    assert np.array_equal(wheels[~dead], plain[~dead])  # the slide read only where dead
    assert np.count_nonzero(np.any(wheels != plain, axis=1)) > 25  # slides under SLIDE_MIN too
    for k in range(n):
        got = steer_one(
            float(headings[k]), *velocities[k].tolist(), KHEPERA_IV, 0.03, float(holds[k]),
            tuple(aims[k].tolist()), 1.0, tuple(slides[k].tolist()),
        )  # fmt: skip
        np.testing.assert_allclose(got[:2], wheels[k], rtol=1e-12, atol=1e-15)
        assert got[2] == bool(capped[k]), k
        assert (
            stopped_dead_one(float(headings[k]), *velocities[k].tolist(), tuple(aims[k]))
            == (dead[k])
        )
    with pytest.raises(ValueError, match="slides"):
        steer(np.zeros(2), np.zeros((2, 2)), slides=np.zeros((3, 2)))


def test_a_robot_held_at_the_safe_distance_is_stopped_dead_whatever_the_rounding() -> None:
    # Held at the barrier's rest, its forward speed is +-1e-17 m/s from step to step; a test
    # of <= 0 restarted its SLIDE_AFTER wait at every positive one (tests/test_sim_still.py's
    # team behind its dead robots).
    aim = (0.3, 0.1)
    for forward in (-1e-17, 0.0, 1e-17, 0.5 * STOPPED_SPEED, STOPPED_SPEED):
        assert stopped_dead_one(0.0, forward, 0.05, aim)
        assert stopped_dead(np.zeros(1), np.array([[forward, 0.05]]), np.array([aim]))[0]
    assert not stopped_dead_one(0.0, 2.0 * STOPPED_SPEED, 0.0, aim)
    assert not stopped_dead_one(0.0, 0.0, 0.0, (-0.3, 0.1))  # its aim behind it: not held


def test_stopped_beside_against_a_restatement() -> None:
    """stopped_beside against the angles themselves (atan2), on random neighbourhoods: some
    with a robot ahead, some with all beside or behind, some with none close."""
    rng = np.random.default_rng(11)
    safe = 0.16
    seen = {True: 0, False: 0}
    for _ in range(600):
        me = rng.uniform(-1.0, 1.0, 2)
        heading = float(rng.uniform(-math.pi, math.pi))
        m = int(rng.integers(0, 5))
        bearings = rng.uniform(-math.pi, math.pi, m)
        distances = rng.uniform(0.12, 0.2, m)
        others = me + distances[:, None] * np.stack([np.cos(bearings), np.sin(bearings)], 1)
        rows = np.concatenate([others, rng.normal(0.0, 0.1, (m, 2))], axis=1)  # x, y, vx, vy
        close = [
            math.atan2(oy - me[1], ox - me[0])
            for ox, oy in others.tolist()
            if math.hypot(ox - me[0], oy - me[1]) <= safe + BESIDE_REACH
        ]
        off = [abs((b - heading + math.pi) % (2.0 * math.pi) - math.pi) for b in close]
        expected = bool(close) and all(a > BESIDE_ANGLE for a in off)
        if any(abs(a - BESIDE_ANGLE) < 1e-9 for a in off):
            continue  # on the boundary: rounding decides
        got = stopped_beside(tuple(me.tolist()), heading, rows, safe)
        assert got == expected, (me, heading, others)
        seen[expected] += 1
    assert min(seen.values()) > 100
    # Its own row (distance 0) is itself, not a robot beside it.
    assert not stopped_beside((0.0, 0.0), 0.0, np.zeros((1, 4)), safe)


@pytest.mark.parametrize("degrees", [75, 90, -75])
def test_a_robot_stopped_dead_with_none_ahead_slides_at_once(degrees: int) -> None:
    # The still robot beside it (more than BESIDE_ANGLE off its heading) is in no file it
    # could wait its turn in: it slides from its first stopped step, where SLIDE_AFTER (1 s)
    # alone kept it standing for the first 0.6 s (tests/test_beside_slide_script.py).
    brain, path, neighbour = escape.drive_past(math.radians(degrees), seconds=0.6)
    assert brain.counters.slid >= 2
    assert escape.closest(path, neighbour) >= 0.15


def test_a_robot_stopped_dead_behind_one_ahead_waits_its_turn() -> None:
    # 30 degrees off its heading, the still robot is ahead of it: it waits SLIDE_AFTER.
    brain, _, _ = escape.drive_past(math.radians(30.0), seconds=0.6)
    assert brain.counters.slid == 0


SQUARE_200 = load_scenario(Path(__file__).parent / "data" / "square-200.toml")


def test_two_robots_side_by_side_no_longer_hold_up_the_corner_behind_them() -> None:
    """Robots 58 and 167 of tests/data/square-200.toml stop each other dead side by side
    (their aims converge) with robot 132 queued behind them at the corner S's trailing edge
    passes first; brains stepped every 0.08-0.14 s (deploy.netsim, phase seed 2). Waiting
    out SLIDE_AFTER together, they held 132 back until it stood 0.127 m off its centroid at
    1.6 s (e_a 0.17 m); sliding at once, 0.040 m (measured 3 Dec 2026)."""
    run = run_netsim(
        SQUARE_200, seed=2, duration=2.0, poses=initial_poses(SQUARE_200, 200, 0),
        turn_gaps=(0.08, 0.14), hold_after=0.3,
    )  # fmt: skip
    k = int(np.argmin(np.abs(run.t - 1.6)))
    _, centroids = mass_centroid(run.trajectories[k], SQUARE_200.domain(run.t[k])[0])
    assert np.linalg.norm(run.trajectories[k][132] - centroids[132]) < 0.08
    assert proximity(run.t, run.trajectories, KHEPERA_IV.body_diameter)[0] >= 0.14
