"""Barrier-certificate safety filter (tvd/safety.py) against dense references and in motion."""

from __future__ import annotations

import numpy as np
import pytest
from reference import dense_qp

from covswarm.tvd.drive import DEFAULT_PROJECTION_DISTANCE, KHEPERA_IV, integrate, wheel_speeds
from covswarm.tvd.safety import (
    DEFAULT_GAMMA,
    RECEDE_SLACK,
    barrier_gain,
    body_safe_distance,
    closest_feasible,
    pair_constraints,
    safe_velocity,
    team_safe_velocities,
    unicycle_rows,
)


def random_case(rng: np.random.Generator, most: int) -> tuple:
    """One robot's filter inputs at a random scale: (scale m, position (2,), 1 to ``most``
    neighbours (m, 2), safe distance m, nominal (2,) m/s, velocity (2,), theirs (m, 2))."""
    scale = 10.0 ** rng.uniform(-1, 1)  # layouts from 10 cm to 10 m across
    m = int(rng.integers(1, most + 1))
    me = rng.uniform(-1, 1, 2) * scale
    others = me + rng.normal(size=(m, 2)) * 0.4 * scale
    safe = 0.3 * scale * rng.uniform(0.3, 1.0)
    nominal = rng.normal(size=2) * scale
    velocity, theirs = rng.normal(size=2) * scale, rng.normal(size=(m, 2)) * scale
    return scale, me, others, safe, nominal, velocity, theirs


@pytest.mark.parametrize("seed", range(40))
def test_filter_matches_dense_qp_on_random_layouts(seed: int) -> None:
    rng = np.random.default_rng(seed)
    scale, me, others, safe, nominal, velocity, theirs = random_case(rng, 12)
    heading = rng.uniform(-np.pi, np.pi) if seed % 2 else None
    A, b = pair_constraints(me, others, safe, DEFAULT_GAMMA, velocity, theirs)
    if heading is not None:
        A = unicycle_rows(A, heading)
    reference = dense_qp(nominal, A, b)
    if reference is None:
        with pytest.raises(ValueError):
            closest_feasible(nominal, A, b)
        result = safe_velocity(
            me, nominal, others, safe, heading=heading, velocity=velocity,
            neighbor_velocities=theirs,
        )  # fmt: skip
        assert result.relaxed
        fallback = np.maximum(pair_constraints(me, others, safe, DEFAULT_GAMMA)[1], 0.0)
        assert np.all(A @ result.velocity <= fallback + 1e-9 * np.maximum(1.0, fallback))
        return
    u, active = closest_feasible(nominal, A, b)
    filtered = safe_velocity(
        me, nominal, others, safe, heading=heading, velocity=velocity, neighbor_velocities=theirs
    )
    np.testing.assert_array_equal(filtered.velocity, u)
    assert np.all(A @ u <= b + 1e-8 * np.maximum(1.0, np.abs(b)))
    cost, ref_cost = np.sum((u - nominal) ** 2), np.sum((reference - nominal) ** 2)
    assert cost <= ref_cost * (1 + 1e-7) + 1e-12
    np.testing.assert_allclose(u, reference, atol=1e-5 * scale)
    assert (active == 0) == np.allclose(u, nominal)


@pytest.mark.parametrize("seed", range(24))
def test_per_row_gains_match_dense_qp_row_by_row(seed: int) -> None:
    # neighbor_gammas (covswarm.agent.brain.filter_all's second pass): each pair row built
    # alone with its own scalar gain, then the dense QP over them.
    rng = np.random.default_rng(1000 + seed)
    scale, me, others, safe, nominal, velocity, theirs = random_case(rng, 9)
    m = len(others)
    heading = rng.uniform(-np.pi, np.pi) if seed % 2 else None
    gammas = rng.uniform(0.2, 10.0, m)
    rows = [
        pair_constraints(me, others[j : j + 1], safe, float(gammas[j]), velocity, theirs[j : j + 1])
        for j in range(m)
    ]
    A, b = np.vstack([a for a, _ in rows]), np.concatenate([b for _, b in rows])
    if heading is not None:
        A = unicycle_rows(A, heading)
    filtered = safe_velocity(
        me, nominal, others, safe, heading=heading, velocity=velocity,
        neighbor_velocities=theirs, neighbor_gammas=gammas,
    )  # fmt: skip
    reference = dense_qp(nominal, A, b)
    if reference is None:
        assert filtered.relaxed
        return
    assert not filtered.relaxed
    u = filtered.velocity
    assert np.all(A @ u <= b + 1e-8 * np.maximum(1.0, np.abs(b)))
    cost, ref_cost = np.sum((u - nominal) ** 2), np.sum((reference - nominal) ** 2)
    assert cost <= ref_cost * (1 + 1e-7) + 1e-12
    np.testing.assert_allclose(u, reference, atol=1e-5 * scale)


def test_per_row_gains_equal_to_gamma_change_nothing_and_bad_ones_are_refused() -> None:
    rng = np.random.default_rng(7)
    me, others = np.zeros(2), rng.normal(size=(6, 2)) * 0.3
    nominal, theirs = np.array([0.3, 0.1]), rng.normal(size=(6, 2)) * 0.1
    plain = safe_velocity(me, nominal, others, 0.2, gamma=3.0, neighbor_velocities=theirs)
    same = safe_velocity(
        me, nominal, others, 0.2, gamma=3.0, neighbor_velocities=theirs,
        neighbor_gammas=np.full(6, 3.0),
    )  # fmt: skip
    np.testing.assert_array_equal(same.velocity, plain.velocity)
    assert plain.active > 0  # the rows bind: a gain that changed them would show
    lower = safe_velocity(
        me, nominal, others, 0.2, gamma=3.0, neighbor_velocities=theirs,
        neighbor_gammas=np.full(6, 0.5),
    )  # fmt: skip
    assert np.linalg.norm(lower.velocity - nominal) > np.linalg.norm(plain.velocity - nominal)
    for bad in ([3.0] * 5 + [0.0], [3.0] * 5 + [-1.0], [3.0] * 5 + [np.nan], [3.0] * 5):
        with pytest.raises(ValueError, match="neighbor_gammas"):
            safe_velocity(me, nominal, others, 0.2, neighbor_gammas=np.array(bad))


def test_tight_corner_uses_two_rows() -> None:
    # Two neighbours ahead-left and ahead-right at the safe distance: forward is blocked by
    # both, and the closest safe velocity sits where both rows meet.
    me = np.zeros(2)
    others = np.array([[0.3, 0.2], [0.3, -0.2]])
    safe = float(np.hypot(0.3, 0.2))
    result = safe_velocity(me, np.array([1.0, 0.0]), others, safe)
    A, b = pair_constraints(me, others, safe, DEFAULT_GAMMA)
    np.testing.assert_allclose(result.velocity, dense_qp(np.array([1.0, 0.0]), A, b), atol=1e-7)
    np.testing.assert_allclose(result.velocity, [0.0, 0.0], atol=1e-12)
    assert result.active == 2 and not result.relaxed


def test_safe_nominal_is_untouched_and_bad_input_gives_zero() -> None:
    result = safe_velocity([0, 0], [0.1, 0.0], [[-1.0, 0.0], [np.nan, 0.0]], 0.2)
    np.testing.assert_array_equal(result.velocity, [0.1, 0.0])
    assert result.active == 0
    assert np.all(safe_velocity([0, 0], [np.inf, 0.0], [[1.0, 0.0]], 0.2).velocity == 0.0)
    assert np.all(safe_velocity([np.nan, 0], [0.1, 0.0], [[1.0, 0.0]], 0.2).velocity == 0.0)
    with pytest.raises(ValueError):
        safe_velocity([0, 0], [0.1, 0.0], [[1.0, 0.0]], 0.2, gamma=0.0)


def test_overlapping_robots_never_close_further() -> None:
    # Boxed in by three robots inside the safe distance: infeasible, relaxed to "close on no
    # one"; a coincident robot contributes no direction and blocks nothing.
    me = np.zeros(2)
    others = np.array([[0.1, 0.0], [-0.05, 0.09], [-0.05, -0.09], [0.0, 0.0]])
    result = safe_velocity(me, np.array([0.3, 0.1]), others, 0.2)
    assert result.relaxed
    closing = -(me - others[:3]) @ result.velocity
    assert np.all(closing <= 1e-12)


@pytest.mark.parametrize("reciprocal", [False, True])
def test_sampled_single_integrators_never_cross_the_safe_distance(reciprocal: bool) -> None:
    # The module's claim: with gamma T <= 1 and zero-order hold, h(t) >= (1 - gamma s) h, for
    # both splits (the reciprocal one with everyone's previous velocity, as reported, and
    # the receding credit: on D - RECEDE_SLACK, and on D without velocities).
    # Eight robots swap places across a circle (everyone through the centre) at 5 Hz.
    period, safe = 0.2, 0.25
    gamma = barrier_gain(DEFAULT_GAMMA, period)
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    p = 1.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    goals = -p
    u = np.zeros_like(p)
    closest = np.inf
    for _ in range(200):
        nominal = np.clip(goals - p, -0.3, 0.3)
        known = {"velocity": None, "neighbor_velocities": None}
        u = np.array([
            safe_velocity(
                p[i], nominal[i], np.delete(p, i, 0), safe, gamma,
                **({"velocity": u[i], "neighbor_velocities": np.delete(u, i, 0)}
                   if reciprocal else known),
            ).velocity
            for i in range(len(p))
        ])  # fmt: skip
        for s in np.linspace(0, period, 11)[1:]:
            q = p + s * u
            d = np.linalg.norm(q[:, None] - q[None], axis=2) + np.eye(len(q)) * 9
            closest = min(closest, d.min())
        p = p + period * u
    assert closest >= safe - (RECEDE_SLACK if reciprocal else 0.0) - 1e-9


@pytest.mark.parametrize("reports", ["honest", "random"])
@pytest.mark.parametrize("seed", range(4))
def test_a_receding_credit_costs_at_most_the_slack(reports: str, seed: int) -> None:
    """Whatever velocities the robots report (their last ones, or random: stale or wrong),
    as long as both of a pair read the same, a team of sampled single integrators never
    comes within D - RECEDE_SLACK (the credits' cap: module docstring). Eight robots swap
    places across a circle at 10 Hz, 0.8 m/s at most; checked 10 times a period."""
    rng = np.random.default_rng(seed)
    period, safe, n = 0.1, 0.16, 8
    gamma = barrier_gain(DEFAULT_GAMMA, period)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(-0.2, 0.2, n)
    p = 0.5 * np.column_stack([np.cos(angles), np.sin(angles)])
    goals = -p + rng.normal(scale=0.05, size=p.shape)
    u = np.zeros_like(p)
    closest = np.inf
    for _ in range(150):
        nominal = np.clip(goals - p, -0.8, 0.8)
        told = u if reports == "honest" else rng.uniform(-0.8, 0.8, size=u.shape)
        u = np.array([
            safe_velocity(
                p[i], nominal[i], np.delete(p, i, 0), safe, gamma,
                velocity=told[i], neighbor_velocities=np.delete(told, i, 0),
            ).velocity
            for i in range(n)
        ])  # fmt: skip
        for s in np.linspace(0, period, 11)[1:]:
            q = p + s * u
            d = np.linalg.norm(q[:, None] - q[None], axis=2) + np.eye(n) * 9
            closest = min(closest, d.min())
        p = p + period * u
    assert safe - RECEDE_SLACK - 1e-9 <= closest
    if reports == "random":
        assert closest < safe  # the credit was spent: the test can fail


def unicycle_run(
    poses: np.ndarray, goals: np.ndarray, safety: bool, seconds: float = 12.0
) -> tuple[float, np.ndarray]:
    """Khepera IV unicycles at 10 Hz, each steered to its goal at up to 0.2 m/s through the
    filter as the agents use it (centre rows, reciprocal split with the centre velocities of
    the last commands), integrated in exact arcs 10 substeps per period.
    (closest centre distance, final poses)."""
    period, substeps = 0.1, 10
    safe = body_safe_distance(KHEPERA_IV.body_diameter)
    gamma = barrier_gain(DEFAULT_GAMMA, period)
    closest = np.inf
    centre_velocity = np.zeros((len(poses), 2))
    for _ in range(round(seconds / period)):
        heading = poses[:, 2]
        ahead = np.column_stack([np.cos(heading), np.sin(heading)])
        steered = poses[:, :2] + DEFAULT_PROJECTION_DISTANCE * ahead
        gap = goals - steered
        speed = np.linalg.norm(gap, axis=1, keepdims=True)
        nominal = gap * np.minimum(1.0, 0.2 / np.maximum(speed, 1e-12))
        if safety:
            nominal = np.array([
                safe_velocity(
                    poses[i, :2], nominal[i], np.delete(poses[:, :2], i, 0), safe, gamma,
                    heading=heading[i], velocity=centre_velocity[i],
                    neighbor_velocities=np.delete(centre_velocity, i, 0),
                ).velocity
                for i in range(len(poses))
            ])  # fmt: skip
        wheels = wheel_speeds(heading, nominal)
        centre_velocity = wheels.mean(axis=1, keepdims=True) * ahead
        for _ in range(substeps):
            poses = integrate(poses, wheels, period / substeps)
            d = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=2)
            closest = min(closest, (d + np.eye(len(poses)) * 9).min())
    return closest, poses


@pytest.mark.parametrize("offset", [0.0, 0.02, 0.08])
def test_head_on_unicycles_keep_their_bodies_apart(offset: float) -> None:
    # Two Khepera IV driving straight at each other's start (0.8 m apart, facing each other).
    poses = np.array([[-0.4, 0.0, 0.0], [0.4, offset, np.pi]])
    goals = poses[::-1, :2].copy()
    unsafe, _ = unicycle_run(poses.copy(), goals, safety=False)
    assert unsafe < KHEPERA_IV.body_diameter  # without the filter they collide
    closest, _ = unicycle_run(poses.copy(), goals, safety=True)
    assert closest >= KHEPERA_IV.body_diameter


@pytest.mark.parametrize("seed", range(3))
def test_crossing_unicycles_with_random_headings(seed: int) -> None:
    # Six robots swap places through the centre, random initial headings.
    rng = np.random.default_rng(seed)
    angles = np.linspace(0, 2 * np.pi, 6, endpoint=False) + rng.uniform(-0.2, 0.2, 6)
    xy = 0.6 * np.column_stack([np.cos(angles), np.sin(angles)])
    poses = np.column_stack([xy, rng.uniform(-np.pi, np.pi, 6)])
    closest, final = unicycle_run(poses, -xy, safety=True, seconds=20.0)
    assert closest >= KHEPERA_IV.body_diameter
    # Barrier certificates promise safety, not arrival: a symmetric swap can jam at the
    # centre (the known deadlock). The team still got closer to its goals (1.2 m at start).
    assert np.linalg.norm(final[:, :2] + xy, axis=1).mean() < 1.0


def test_convoy_is_not_held_back_by_the_reciprocal_split() -> None:
    # A robot 0.18 m behind another, both moving at 0.16 m/s in +x: the Robotarium split
    # (velocities unknown) lets the follower advance at only gamma h / (4 d) ~ 0.09 m/s, the
    # reciprocal one keeps the convoy's speed.
    me, leader, v = np.zeros(2), np.array([[0.18, 0.0]]), np.array([0.16, 0.0])
    safe = body_safe_distance(KHEPERA_IV.body_diameter)
    blind = safe_velocity(me, v, leader, safe).velocity
    assert blind[0] < 0.1
    shared = safe_velocity(me, v, leader, safe, velocity=v, neighbor_velocities=v[None]).velocity
    np.testing.assert_allclose(shared, v)


def test_unicycle_rows_only_limit_the_forward_speed() -> None:
    # A neighbour dead ahead: the steered velocity keeps its sideways part (the turn) and
    # loses the forward part that would close the gap; rows match the dense QP.
    me, heading = np.zeros(2), 0.0
    others = np.array([[0.17, 0.0]])
    nominal = np.array([0.2, 0.1])
    result = safe_velocity(me, nominal, others, 0.16, heading=heading)
    A, b = pair_constraints(me, others, 0.16, DEFAULT_GAMMA)
    rows = unicycle_rows(A, heading)
    np.testing.assert_allclose(result.velocity, dense_qp(nominal, rows, b), atol=1e-7)
    assert result.velocity[1] == pytest.approx(0.1)
    assert result.velocity[0] < 0.2


@pytest.mark.parametrize("seed", range(3))
def test_team_filter_is_each_robots_filter_against_the_robots_near_it(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, radius, safe = 12, 0.5, 0.16
    positions = rng.uniform(-0.6, 0.6, size=(n, 2))
    nominal = rng.normal(scale=0.2, size=(n, 2))
    headings = rng.uniform(-np.pi, np.pi, size=n)
    velocities = rng.normal(scale=0.1, size=(n, 2))
    out, active, relaxed = team_safe_velocities(
        positions, nominal, safe, 10.0, radius, headings=headings, velocities=velocities
    )
    for i in range(n):
        near = [
            j for j in range(n) if j != i and np.hypot(*(positions[j] - positions[i])) <= radius
        ]
        one = safe_velocity(
            positions[i], nominal[i], positions[near], safe, 10.0, heading=headings[i],
            velocity=velocities[i], neighbor_velocities=velocities[near],
        )  # fmt: skip
        # The team's unicycles are filtered in one batch (safe_unicycle_velocities): the same
        # closed form to rounding.
        np.testing.assert_allclose(out[i], one.velocity, rtol=0, atol=1e-12)
        assert (active[i], relaxed[i]) == (one.active, one.relaxed)
    assert active.sum() > 0  # the layout is tight enough for the filter to act


@pytest.mark.parametrize("seed", range(3))
def test_a_subset_of_the_team_is_filtered_as_the_whole_team_would_be(seed: int) -> None:
    # The simulator's slides (covswarm.tvd.drive.steer): single integrators, some robots.
    rng = np.random.default_rng(seed)
    n = 12
    positions = rng.uniform(-0.6, 0.6, size=(n, 2))
    nominal = rng.normal(scale=0.2, size=(n, 2))
    velocities = rng.normal(scale=0.1, size=(n, 2))
    whole = team_safe_velocities(positions, nominal, 0.16, 10.0, 0.5, velocities=velocities)
    subset = rng.choice(n, size=5, replace=False)
    some = team_safe_velocities(
        positions, nominal, 0.16, 10.0, 0.5, velocities=velocities, subset=subset
    )
    rest = np.setdiff1d(np.arange(n), subset)
    for full, part in zip(whole, some, strict=True):
        np.testing.assert_array_equal(part[subset], full[subset])
    np.testing.assert_array_equal(some[0][rest], nominal[rest])
    assert not some[1][rest].any() and not some[2][rest].any()
    with pytest.raises(ValueError, match="single integrators"):
        team_safe_velocities(
            positions, nominal, 0.16, 10.0, 0.5, headings=np.zeros(n), subset=subset
        )
