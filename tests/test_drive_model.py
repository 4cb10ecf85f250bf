"""Differential-drive mapping (tvd/drive.py) and arc integration (tvd/drive.py integrate)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from covswarm.tvd.drive import (
    DEFAULT_PROJECTION_DISTANCE,
    KHEPERA_IV,
    PASS_ANGLE,
    PASS_BELOW,
    PASS_STOPPED,
    TURN_RATE,
    TURN_TOLERANCE,
    DiffDrive,
    integrate,
    integrate_one,
    pass_sides,
    steer,
    steer_one,
    turn_in_place,
    wheel_speeds,
)

L = DEFAULT_PROJECTION_DISTANCE
HALF_TRACK = KHEPERA_IV.wheel_separation / 2


def euler(poses: np.ndarray, wheels: np.ndarray, dt: float, substeps: int) -> np.ndarray:
    """Reference: many tiny forward-Euler unicycle steps (wheels assumed within limits)."""
    poses = poses.copy()
    v = wheels.mean(axis=1)
    w = (wheels[:, 1] - wheels[:, 0]) / KHEPERA_IV.wheel_separation
    h = dt / substeps
    for _ in range(substeps):
        poses[:, 0] += h * v * np.cos(poses[:, 2])
        poses[:, 1] += h * v * np.sin(poses[:, 2])
        poses[:, 2] += h * w
    return poses


def test_khepera_constants() -> None:
    assert KHEPERA_IV == DiffDrive(0.021, 0.1054, 0.14, 0.8)


def test_forward_velocity_drives_both_wheels_equally() -> None:
    wheels = wheel_speeds(np.array([0.0, np.pi / 2]), np.array([[0.1, 0.0], [0.0, -0.2]]))
    np.testing.assert_allclose(wheels, [[0.1, 0.1], [-0.2, -0.2]], atol=1e-15)


def test_sideways_velocity_turns_in_place() -> None:
    wheels = wheel_speeds(np.array([0.0]), np.array([[0.0, 0.01]]))
    w = 0.01 / L
    np.testing.assert_allclose(wheels, [[-w * HALF_TRACK, w * HALF_TRACK]])


def test_saturation_scales_both_wheels_and_keeps_curvature() -> None:
    headings = np.array([0.3, -2.0])
    velocities = np.array([[3.0, 1.0], [0.0, 5.0]])
    raw = wheel_speeds(headings, velocities, robot=DiffDrive(max_wheel_speed=1e9))
    wheels = wheel_speeds(headings, velocities)
    np.testing.assert_allclose(np.abs(wheels).max(axis=1), KHEPERA_IV.max_wheel_speed)
    np.testing.assert_allclose(wheels[:, 0] * raw[:, 1], wheels[:, 1] * raw[:, 0])


def test_non_finite_input_gives_stopped_robot() -> None:
    headings = np.array([np.nan, 0.0, 0.0, 0.0])
    velocities = np.array([[0.1, 0.0], [np.inf, 0.0], [0.0, np.nan], [0.1, 0.1]])
    wheels = wheel_speeds(headings, velocities)
    assert np.all(np.isfinite(wheels))
    np.testing.assert_array_equal(wheels[:3], 0.0)
    assert np.all(wheels[3] != 0.0)


def test_empty_team_and_bad_arguments() -> None:
    assert wheel_speeds(np.zeros(0), np.zeros((0, 2))).shape == (0, 2)
    with pytest.raises(ValueError):
        wheel_speeds(np.zeros(2), np.zeros((3, 2)))
    with pytest.raises(ValueError):
        wheel_speeds(np.zeros(1), np.zeros((1, 2)), projection_distance=0.0)


def test_projected_point_follows_the_command() -> None:
    """The point projection_distance ahead of the axle moves with the commanded velocity."""
    rng = np.random.default_rng(3)
    headings = rng.uniform(-np.pi, np.pi, 20)
    velocities = rng.uniform(-0.05, 0.05, (20, 2))  # small: no saturation
    poses = np.column_stack([rng.uniform(-1, 1, (20, 2)), headings])
    dt = 1e-4
    after = integrate(poses, wheel_speeds(headings, velocities), dt)

    def front(p: np.ndarray) -> np.ndarray:
        return p[:, :2] + L * np.column_stack([np.cos(p[:, 2]), np.sin(p[:, 2])])

    np.testing.assert_allclose((front(after) - front(poses)) / dt, velocities, atol=1e-4)


def test_straight_line_and_turn_in_place() -> None:
    poses = np.array([[0.0, 0.0, np.pi / 4], [1.0, 2.0, 0.0]])
    wheels = np.array([[0.2, 0.2], [-0.1, 0.1]])
    out = integrate(poses, wheels, 0.5)
    np.testing.assert_allclose(out[0], [0.1 / np.sqrt(2), 0.1 / np.sqrt(2), np.pi / 4])
    np.testing.assert_allclose(out[1], [1.0, 2.0, 0.5 * 0.1 / HALF_TRACK])


def test_arc_matches_fine_euler() -> None:
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-1, 1, (30, 2)), rng.uniform(-np.pi, np.pi, 30)])
    wheels = rng.uniform(-0.5, 0.5, (30, 2))
    exact = integrate(poses, wheels, 0.3)
    reference = euler(poses, wheels, 0.3, 20000)
    np.testing.assert_allclose(exact[:, :2], reference[:, :2], atol=2e-5)
    wrapped = np.angle(np.exp(1j * (exact[:, 2] - reference[:, 2])))
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-9)


def test_full_circle_returns_home_and_heading_wraps() -> None:
    wheels = np.array([[0.1, 0.3]])
    w = 0.2 / KHEPERA_IV.wheel_separation
    start = np.array([[0.5, -0.5, 3.0]])
    out = integrate(start, wheels, 2 * np.pi / w)
    np.testing.assert_allclose(out, start, atol=1e-12)
    half = integrate(start, wheels, np.pi / w)
    assert -np.pi <= half[0, 2] < np.pi


def test_wheels_clamped_each_and_nan_stops() -> None:
    poses = np.zeros((2, 3))
    out = integrate(poses, np.array([[5.0, 5.0], [np.nan, np.nan]]), 1.0)
    np.testing.assert_allclose(out, [[KHEPERA_IV.max_wheel_speed, 0.0, 0.0], [0.0, 0.0, 0.0]])
    with pytest.raises(ValueError):
        integrate(np.zeros((2, 3)), np.zeros((1, 2)), 0.1)


def test_integrate_one_is_integrate_for_one_robot() -> None:
    rng = np.random.default_rng(7)
    poses = np.column_stack([rng.uniform(-3, 3, (400, 2)), rng.uniform(-np.pi, np.pi, 400)])
    wheels = rng.uniform(-1.5, 1.5, (400, 2))  # beyond the limit too: clamped alike
    wheels[:50, 1] = wheels[:50, 0]  # straight lines (turn exactly 0)
    wheels[50:60, 0] = np.nan  # a non-finite rim speed counts as 0
    wheels[60:70, 1] = np.inf
    dts = rng.uniform(0.0, 0.6, 400)
    for pose, wheel, dt in zip(poses, wheels, dts, strict=True):
        expected = integrate(pose[None], wheel[None], dt)[0]
        got = integrate_one(*pose.tolist(), *wheel.tolist(), dt)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_steer_one_is_steer_for_one_robot() -> None:
    """The plain-float steer an agent uses for its robot equals the numpy one row by row:
    random headings and velocities, held commands that cap the turn and ones that do not,
    zero, huge and non-finite velocities, non-finite headings, a tiny robot limit."""
    rng = np.random.default_rng(11)
    n = 600
    headings = rng.uniform(-4.0, 4.0, n)
    velocities = rng.normal(0.0, 0.5, (n, 2)) * rng.choice([1e-3, 1.0, 10.0], (n, 1))
    holds = rng.choice([0.0, 0.02, 0.1, 0.5], n)
    velocities[:20] = 0.0
    velocities[20:30] *= 1e300  # huge but finite: saturated
    velocities[30:40] = rng.choice([-1.7e308, 1.7e308], (10, 2))  # products overflow
    velocities[40:50, 0] = np.nan
    velocities[50:60, 1] = np.inf
    headings[60:70] = rng.choice([np.nan, np.inf, -np.inf], 10)
    velocities[70:80] = velocities[70:80, ::-1] * [[-1.0, 1.0]]  # sideways: capped if held
    capped_seen = 0
    for robot in (KHEPERA_IV, DiffDrive(max_wheel_speed=0.05)):
        for distance in (L, 0.05):
            wheels, capped = steer(headings, velocities, robot, distance, holds)
            for k in range(n):
                left, right, cap = steer_one(
                    float(headings[k]), *velocities[k].tolist(), robot, distance, float(holds[k])
                )
                np.testing.assert_allclose([left, right], wheels[k], rtol=1e-12, atol=1e-15)
                assert cap == bool(capped[k]), k
                capped_seen += cap
            peaks = np.abs(wheels).max(axis=1)
            np.testing.assert_allclose(peaks[20:30], robot.max_wheel_speed)
            assert np.all(np.isfinite(wheels))
            assert np.all(wheels[40:70] == 0.0)  # a non-finite input stops the robot
    assert capped_seen > 100  # the cap was exercised
    # Aimed elsewhere than the velocity (a filter's clipped forward speed): the same again,
    # with rows held back to every fraction of the aim's forward speed (veering or not).
    aims = velocities + rng.normal(0.0, 0.5, (n, 2))
    aims[100:110] = np.nan
    e = np.stack([np.cos(headings[200:400]), np.sin(headings[200:400])], axis=1)
    ahead = np.abs(rng.normal(0.0, 1.0, 200))
    aims[200:400] = velocities[200:400] + (ahead * rng.uniform(0.0, 1.2, 200))[:, None] * e
    velocities[200:210] += 1e-3 * e[:10]  # forward speeds just above the aim's
    wheels, capped = steer(headings, velocities, KHEPERA_IV, L, holds, aims)
    plain = steer(headings, velocities, KHEPERA_IV, L, holds)[0]
    veered = np.any(wheels[200:400] != plain[200:400], axis=1)
    assert 50 < np.count_nonzero(veered) < 200
    assert np.array_equal(steer(headings, velocities, KHEPERA_IV, L, holds, velocities)[0],
                          steer(headings, velocities, KHEPERA_IV, L, holds)[0])  # fmt: skip
    for k in range(n):
        left, right, cap = steer_one(
            float(headings[k]), *velocities[k].tolist(), KHEPERA_IV, L, float(holds[k]),
            tuple(aims[k].tolist()),
        )  # fmt: skip
        np.testing.assert_allclose([left, right], wheels[k], rtol=1e-12, atol=1e-15)
        assert cap == bool(capped[k]), k
    with pytest.raises(ValueError, match="aims"):
        steer(np.zeros(2), np.zeros((2, 2)), aims=np.zeros((3, 2)))
    for bad in ({"projection_distance": 0.0}, {"hold": -0.1}, {"hold": float("nan")}):
        with pytest.raises(ValueError):
            steer_one(0.0, 0.1, 0.0, **bad)
        with pytest.raises(ValueError):
            steer(np.zeros(1), np.array([[0.1, 0.0]]), **bad)


def _error(heading: float, direction: float) -> float:
    return math.remainder(direction - heading, math.tau)


def test_a_turn_in_place_takes_the_shorter_way_and_keeps_the_centre() -> None:
    left, right = turn_in_place(0.0, 1.0, 0.5)
    assert left == -right and right > 0.0  # counter-clockwise: the right rim forwards
    left, right = turn_in_place(0.0, -1.0, 0.5)
    assert right < 0.0
    left, right = turn_in_place(3.0, -3.0, 0.5)  # 0.28 rad the short way, across +-pi
    assert right > 0.0
    x, y, heading = integrate_one(0.3, -0.2, 3.0, left, right, 0.1)
    assert (x, y) == pytest.approx((0.3, -0.2), abs=1e-12)
    assert heading > 3.0
    assert turn_in_place(1.0, 1.0 + 0.9 * TURN_TOLERANCE, 0.5) == (0.0, 0.0)
    for bad in ((math.nan, 1.0, 0.5), (0.0, math.inf, 0.5), (0.0, 1.0, 0.0), (0.0, 1.0, -1.0)):
        assert turn_in_place(*bad) == (0.0, 0.0)


@pytest.mark.parametrize("seed", range(5))
def test_a_turn_held_alone_stops_facing_the_direction_never_past_it(seed: int) -> None:
    """A command that nothing follows turns the robot by its error over the hold (up to
    TURN_RATE) until the robot drops it: facing the direction, or short of it when capped;
    never beyond."""
    rng = np.random.default_rng(seed)
    for _ in range(200):
        heading, direction = rng.uniform(-math.pi, math.pi, 2)
        hold = float(rng.uniform(0.2, 2.0))
        left, right = turn_in_place(float(heading), float(direction), hold)
        _, _, after = integrate_one(0.0, 0.0, float(heading), left, right, hold)
        before = _error(heading, direction)
        if abs(before) <= TURN_TOLERANCE:
            assert after == heading
            continue
        turned = _error(heading, after)
        assert turned == pytest.approx(
            math.copysign(min(abs(before), TURN_RATE * hold), before), abs=1e-9
        )


def test_turns_sent_every_period_face_the_direction_without_overshoot() -> None:
    """Stepped at 10 Hz from the pose a period old (a period of latency), as a waiting
    brain does, from every start: within the tolerance in under 2 s, the error never
    changing sign beyond it."""
    hold, period = 0.5, 0.1
    for start in np.linspace(-math.pi, math.pi, 73):
        heading, seen, direction = float(start), float(start), 0.7
        sign = math.copysign(1.0, _error(heading, direction))
        for _ in range(20):
            left, right = turn_in_place(seen, direction, hold)
            seen = heading
            _, _, heading = integrate_one(0.0, 0.0, heading, left, right, period)
            assert sign * _error(heading, direction) > -TURN_TOLERANCE
        assert abs(_error(heading, direction)) <= TURN_TOLERANCE


@pytest.mark.parametrize("aimed", [True, False])
def test_a_robot_blocked_ahead_turns_to_its_aim_and_stays(aimed: bool) -> None:
    """A filter for unicycles clips only the forward speed (here to 0: robots ahead) and
    keeps the sideways part of the nominal velocity. Steered toward that filtered velocity,
    square to the heading at every step, the robot swings a quarter turn about its aim each
    period with its wheels at their limit; steered toward the aim, it faces it within a few
    periods and stops turning."""
    nominal = np.array([-2.0, 1.0])  # an empty cell's pull toward S's centroid, m/s
    heading, period = 0.3, 0.1
    errors, peaks = [], []
    for _ in range(40):
        e = np.array([math.cos(heading), math.sin(heading)])
        blocked = nominal - (nominal @ e) * e  # forward speed clipped to 0
        aim = tuple(nominal.tolist()) if aimed else None
        left, right, _ = steer_one(heading, *blocked.tolist(), KHEPERA_IV, 0.05, period, aim)
        _, _, heading = integrate_one(0.0, 0.0, heading, left, right, period)
        errors.append(abs(_error(heading, math.atan2(nominal[1], nominal[0]))))
        peaks.append(max(abs(left), abs(right)))
    if aimed:
        assert max(errors[10:]) < 1e-6 and max(peaks[10:]) < 1e-6
    else:
        assert min(errors[10:]) > 0.5 and min(peaks[10:]) > 0.5 * KHEPERA_IV.max_wheel_speed


def _held_back(heading: float, nominal: np.ndarray, ratio: float) -> np.ndarray:
    """``nominal`` with its forward part from ``heading`` cut to ``ratio`` of it, as a
    filter for unicycles bounds it (the sideways part kept)."""
    e = np.array([math.cos(heading), math.sin(heading)])
    return nominal - (1.0 - ratio) * (nominal @ e) * e


@pytest.mark.parametrize("ratio", [0.0, 0.02, 0.1, 0.3, 0.6, 1.0])
def test_a_robot_held_back_settles_left_of_its_aim_without_swinging(ratio: float) -> None:
    """Its forward speed cut to ``ratio`` of the aim's every period, a robot turns to a
    heading PASS_ANGLE * g(ratio) left of its aim (none when stopped dead or not held
    back) and holds it: the turn never reverses, the wheels stop turning it and drive the
    forward speed the filter left (up to their limit), where the swing saturated them."""
    nominal = np.array([-2.0, 1.0])  # m/s
    aim = math.atan2(nominal[1], nominal[0])
    veer = PASS_ANGLE * min(1.0, ratio / PASS_STOPPED) * max(0.0, 1.0 - ratio / PASS_BELOW)
    assert (veer > 0.0) == (0.0 < ratio < PASS_BELOW)
    heading, period, turns = aim - 0.4, 0.1, []
    for _ in range(40):
        velocity = _held_back(heading, nominal, ratio)
        left, right, _ = steer_one(
            heading, *velocity.tolist(), KHEPERA_IV, 0.05, period, tuple(nominal.tolist())
        )
        _, _, after = integrate_one(0.0, 0.0, heading, left, right, period)
        turns.append(math.remainder(after - heading, math.tau))
        heading = after
    assert all(turn >= -1e-12 for turn in turns)  # toward the left veer, never back
    assert abs(_error(heading, aim + veer)) < 1e-3
    forward = min(ratio * float(np.hypot(*nominal)) * math.cos(veer), KHEPERA_IV.max_wheel_speed)
    assert abs(right - left) < 1e-3 and abs(0.5 * (left + right) - forward) < 1e-3


def _pass(
    aimed: bool, lead_speed: float, offset: float = 0.0, away: bool = False
) -> tuple[np.ndarray, float, int, float]:
    """A robot 3 m from its goal (nominal 3 m/s per m of it: an empty cell's pull) behind a
    robot 0.3 m ahead and ``offset`` m to its left driving ``lead_speed`` m/s toward it,
    both filtered for each other as covswarm sim does, 10 s at 10 Hz, passing on the left
    or (``away``) on the side pass_sides gives: the follower's track, its distance to the
    goal at the end, its turn reversals of more than 0.2 rad a period (swings) and the
    closest the two came (m)."""
    from covswarm.tvd.safety import (
        DEFAULT_GAMMA,
        SAFETY_RADIUS,
        barrier_gain,
        body_safe_distance,
        team_safe_velocities,
    )

    dt, goal = 0.1, np.array([3.0, 0.0])
    poses = np.array([[0.0, 0.0, 0.0], [0.3, offset, 0.0]])
    centre = np.zeros((2, 2))
    track, swings, last, closest = [], 0, 0.0, np.inf
    for _ in range(100):
        nominal = np.array([3.0 * (goal - poses[0, :2]), [lead_speed, 0.0]])
        velocity, _, _ = team_safe_velocities(
            poses[:, :2], nominal, body_safe_distance(KHEPERA_IV.body_diameter),
            barrier_gain(DEFAULT_GAMMA, dt), SAFETY_RADIUS, headings=poses[:, 2],
            velocities=centre,
        )  # fmt: skip
        sides = pass_sides(poses[:, :2], nominal, poses[:, :2], SAFETY_RADIUS) if away else None
        aims = nominal if aimed else None
        wheels = steer(poses[:, 2], velocity, KHEPERA_IV, 0.05, dt, aims, sides)[0]
        wheels[1] = lead_speed  # the leader drives straight on
        forward = wheels.mean(axis=1)
        centre = forward[:, None] * np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=1)
        after = integrate(poses, wheels, dt)
        turn = math.remainder(after[0, 2] - poses[0, 2], math.tau)
        swings += abs(turn) > 0.2 and abs(last) > 0.2 and turn * last < 0.0
        last, poses = turn, after
        track.append(poses[0, :2].copy())
        closest = min(closest, float(np.hypot(*(poses[0, :2] - poses[1, :2]))))
    return np.array(track), float(np.hypot(*(goal - poses[0, :2]))), swings, closest


@pytest.mark.parametrize("lead_speed", [0.05, 0.1])
def test_a_robot_behind_a_slower_one_passes_it_on_the_left(lead_speed: float) -> None:
    """Facing its goal behind a robot that drives there slower, a robot that only faced its
    aim would follow it at its pace (as the swing's cap does on this exact line: no
    sideways part to swing by). Held back, it veers left, passes and reaches the goal,
    without swinging and without closing on the other robot."""
    track, left, swings, closest = _pass(True, lead_speed)
    assert left < 0.05 and swings == 0
    assert track[:, 1].max() > 0.1 and track[:, 1].min() > -0.01  # passed on its left
    assert closest > 0.15  # the filter's safe distance (0.16 m) less its sampling slack
    behind, followed, _, _ = _pass(False, lead_speed)
    assert followed > 1.5 and np.abs(behind[:, 1]).max() < 1e-6


@pytest.mark.parametrize("offset", [0.03, 0.05, 0.1])
def test_a_robot_held_back_by_one_ahead_on_its_left_passes_it_on_the_right(
    offset: float,
) -> None:
    """The slower robot ahead a few centimetres to the left: veering left turns the
    follower into it, and it trails it at its pace (2.3 m from its goal after 10 s; how
    robots behind S's trailing edge stayed out). Passing away from it (pass_sides), it
    passes on the right and reaches its goal, without swinging or closing in."""
    track, left, swings, closest = _pass(True, 0.05, offset, away=True)
    assert left < 0.05 and swings == 0
    assert track[:, 1].min() < -0.1 and track[:, 1].max() < 0.01  # passed on its right
    assert closest > 0.15
    _, trailing, _, _ = _pass(True, 0.05, offset, away=False)
    assert trailing > 1.5


def test_pass_sides_turn_away_from_the_nearest_robot_ahead() -> None:
    """pass_sides against a loop over the others: the nearest robot within the radius with a
    positive projection on the aim holds the robot back; -1 (pass on the right) when it
    lies left of the aim, +1 otherwise and when none is ahead; a robot at the very
    position is itself. Random teams, the robot itself among the others."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        n, m = int(rng.integers(1, 6)), int(rng.integers(0, 12))
        positions = rng.uniform(-1.0, 1.0, (n, 2))
        aims = rng.normal(0.0, 1.0, (n, 2))
        others = np.vstack([rng.uniform(-1.0, 1.0, (m, 2)), positions[:1]])
        radius = float(rng.uniform(0.2, 1.5))
        sides = pass_sides(positions, aims, others, radius)
        for i in range(n):
            best, side = math.inf, 1.0
            for other in others:
                rel = other - positions[i]
                d2 = float(rel @ rel)
                if 0.0 < d2 <= radius**2 and float(rel @ aims[i]) > 0.0 and d2 < best:
                    best = d2
                    left = aims[i][0] * rel[1] - aims[i][1] * rel[0] > 0.0
                    side = -1.0 if left else 1.0
            assert sides[i] == side
    assert pass_sides(np.zeros((2, 2)), np.ones((2, 2)), np.zeros((0, 2)), 0.5).tolist() == [1, 1]


@pytest.mark.parametrize("ratio", [0.02, 0.1, 0.3])
def test_a_robot_held_back_veers_to_the_side_it_is_given(ratio: float) -> None:
    """side -1 mirrors side +1 about the aim: the robot settles PASS_ANGLE * g(ratio) to
    the right of its aim instead of the left, and steer's sides do what steer_one's side
    does."""
    nominal = np.array([-2.0, 1.0])
    aim = math.atan2(nominal[1], nominal[0])
    veer = PASS_ANGLE * min(1.0, ratio / PASS_STOPPED) * max(0.0, 1.0 - ratio / PASS_BELOW)
    for side in (1.0, -1.0):
        heading = aim
        for _ in range(40):
            velocity = _held_back(heading, nominal, ratio)
            left, right, _ = steer_one(
                heading, *velocity.tolist(), KHEPERA_IV, 0.05, 0.1, tuple(nominal.tolist()), side
            )
            batch = steer(
                [heading], velocity[None], KHEPERA_IV, 0.05, 0.1, nominal[None], np.array([side])
            )[0][0]
            np.testing.assert_allclose([left, right], batch, rtol=1e-12, atol=1e-15)
            heading = integrate_one(0.0, 0.0, heading, left, right, 0.1)[2]
        assert abs(_error(heading, aim + side * veer)) < 1e-3
