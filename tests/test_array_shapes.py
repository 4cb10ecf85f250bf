"""The math library refuses arrays of the wrong shape with the argument's name (a (2, n)
array for an (n, 2) one was reshaped into other robots' coordinates: full speed toward a
robot 0.2 m away), an amplification guard that is not a positive factor, and a still mask
that is not one; a robot without a finite position gets 0 from the team's filter."""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.tvd import control, coverage, drive, safety

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_a_transposed_neighbour_array_is_refused_not_reshaped() -> None:
    neighbours = np.array([[0.2, 0.0], [-0.5, 0.3], [0.0, 0.6]])
    right = safety.safe_velocity(np.zeros(2), np.array([1.0, 0.0]), neighbours, 0.16, 10.0)
    assert right.active == 1 and right.velocity[0] < 0.5
    with pytest.raises(ValueError, match=r"neighbors must have shape \(m, 2\), got \(2, 3\)"):
        safety.safe_velocity(np.zeros(2), np.array([1.0, 0.0]), neighbours.T, 0.16, 10.0)
    with pytest.raises(ValueError, match=r"position must have shape \(2,\)"):
        safety.safe_velocity(np.zeros(3), np.array([1.0, 0.0]), neighbours, 0.16, 10.0)
    with pytest.raises(ValueError, match=r"neighbor_velocities must have shape \(3, 2\)"):
        safety.safe_velocity(
            np.zeros(2), np.array([1.0, 0.0]), neighbours, 0.16, 10.0,
            neighbor_velocities=np.zeros((2, 2)),
        )  # fmt: skip
    assert safety.safe_velocity(np.zeros(2), np.ones(2), [], 0.16, 10.0).velocity.tolist() == [
        1.0,
        1.0,
    ]


def test_the_team_filter_and_the_wheels_refuse_wrong_shapes() -> None:
    rng = np.random.default_rng(0)
    positions, nominal = rng.uniform(0, 1, (5, 2)), rng.normal(0, 0.1, (5, 2))
    with pytest.raises(ValueError, match=r"nominal must have shape \(5, 2\), got \(3, 2\)"):
        safety.team_safe_velocities(positions, nominal[:3], 0.16, 10.0, 0.5)
    with pytest.raises(ValueError, match=r"headings must have shape \(5,\)"):
        safety.team_safe_velocities(positions, nominal, 0.16, 10.0, 0.5, headings=np.zeros(4))
    with pytest.raises(ValueError, match=r"velocities must have shape \(m, 2\), got \(2, 5\)"):
        drive.wheel_speeds(np.zeros(5), nominal.T)
    with pytest.raises(ValueError, match=r"headings must have shape \(5,\), got \(4,\)"):
        drive.wheel_speeds(np.zeros(4), nominal)
    with pytest.raises(ValueError, match=r"poses must have shape \(m, 3\), got \(4, 2\)"):
        drive.integrate(np.zeros((4, 2)), np.zeros((4, 2)), 0.1)
    with pytest.raises(ValueError, match=r"wheels must have shape \(4, 2\), got \(3, 2\)"):
        drive.integrate(np.zeros((4, 3)), np.zeros((3, 2)), 0.1)


@pytest.mark.parametrize("headings", [None, "zeros"])
def test_a_robot_without_a_finite_position_gets_zero_from_the_team_filter(headings) -> None:
    rng = np.random.default_rng(1)
    positions, nominal = rng.uniform(0, 1, (6, 2)), rng.normal(0, 0.1, (6, 2))
    positions[2] = np.nan
    heading = None if headings is None else np.zeros(6)
    out, _, _ = safety.team_safe_velocities(positions, nominal, 0.16, 10.0, 0.5, headings=heading)
    assert out[2].tolist() == [0.0, 0.0]
    assert np.all(np.isfinite(out))
    # the others are filtered as if it were not there
    rest = np.delete(np.arange(6), 2)
    alone, _, _ = safety.team_safe_velocities(
        positions[rest],
        nominal[rest],
        0.16,
        10.0,
        0.5,
        headings=None if heading is None else heading[rest],
    )
    np.testing.assert_allclose(out[rest], alone, atol=1e-12)


@pytest.mark.parametrize("factor", [-1.0, 0.0, float("nan"), float("inf")])
def test_the_amplification_guard_must_be_a_positive_factor(factor: float) -> None:
    positions = np.random.default_rng(2).uniform(0.1, 0.9, (8, 2))
    with pytest.raises(ValueError, match="max_amplification must be a finite number > 0"):
        control.tvd_d1(positions, SQUARE, np.zeros((4, 2)), 1.0, max_amplification=factor)
    view = control.LocalView(0, dict(enumerate(positions)), SQUARE, np.zeros((4, 2)), 1.0)
    with pytest.raises(ValueError, match="max_amplification"):
        control.local_steps([view], max_amplification=factor)


def test_a_still_mask_must_be_one() -> None:
    positions = np.random.default_rng(3).uniform(0.1, 0.9, (10, 2))
    mask = np.zeros(10, dtype=bool)
    mask[[0, 3]] = True
    expected = coverage.aggregate_error(positions, SQUARE, still=mask)
    for wrong in (np.array([0, 3]), mask.astype(int), np.array([True])):
        with pytest.raises(ValueError, match=r"still must be a \(10,\) bool array"):
            coverage.aggregate_error(positions, SQUARE, still=wrong)
    points, _, batch = coverage.tessellate(positions, SQUARE)
    offsets = points - coverage.as_vectors(batch.centroid)
    assert expected == pytest.approx(float(np.linalg.norm(offsets[~mask])))


@pytest.mark.parametrize("dt", [float("nan"), float("inf"), -0.1, "0.1"])
def test_integrate_refuses_a_step_that_is_no_time(dt) -> None:
    """A NaN step made every pose NaN, a negative one drove the robots backwards."""
    with pytest.raises(ValueError, match="dt must be a finite number of seconds >= 0"):
        drive.integrate(np.zeros((2, 3)), np.full((2, 2), 0.1), dt)
    assert np.array_equal(drive.integrate(np.zeros((1, 3)), np.ones((1, 2)), 0.0), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="dt must be"):  # one per robot (a robot process's)
        drive.integrate(np.zeros((2, 3)), np.full((2, 2), 0.1), np.array([0.05, -0.01]))
    moved = drive.integrate(np.zeros((2, 3)), np.full((2, 2), 0.1), np.array([0.05, 0.1]))
    np.testing.assert_allclose(moved[:, 0], [0.005, 0.01])


def test_a_robot_needs_positive_dimensions_and_speed() -> None:
    for field in ("wheel_radius", "wheel_separation", "body_diameter", "max_wheel_speed"):
        for value in (0.0, -1.0, float("nan"), float("inf"), True):
            with pytest.raises(ValueError, match=f"DiffDrive: {field} must be"):
                drive.DiffDrive(**{field: value})
    with pytest.raises(ValueError, match="wheel_separation must be > 0 m"):
        drive.twist_from_wheels(0.1, 0.2, 0.0)
