"""Steering S (coordinator.steering): convex at every instant, exact vertex velocities,
pre-emption from wherever S is, speed limit, and every refusal reason."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from scipy.spatial import ConvexHull
from shapely.geometry import MultiPoint, Polygon

from covswarm.coordinator.steering import (
    BRAKE_DECELERATION,
    PEAK_RATE,
    REFUSALS,
    Brake,
    Limits,
    Morph,
    Steering,
    brake_span,
    centroid,
    default_max_domain_speed,
    simplify,
    smoothstep,
    support_pairs,
)
from covswarm.protocol.steering import SteerRequest
from covswarm.tvd.coverage import signed_area, validate_polygon

SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
WORKSPACE = (-3.0, 3.0, -2.0, 2.0)
LIMITS = Limits(max_speed=0.5, workspace=WORKSPACE, min_area=0.3)


def random_convex(rng: np.random.Generator, n_points: int, center, radius: float) -> np.ndarray:
    points = rng.uniform(-radius, radius, size=(n_points, 2)) + np.asarray(center)
    return points[ConvexHull(points).vertices]  # CCW


def still(polygon: np.ndarray):
    return lambda t: (polygon.copy(), np.zeros_like(polygon))


def steering(polygon: np.ndarray = SQUARE, limits: Limits = LIMITS) -> Steering:
    return Steering(still(polygon), limits)


def send(steer: Steering, request: SteerRequest, t: float, running: bool = True):
    return steer.handle(request.encode(), t, 1.7e9 + t, running)


def same_set(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    return Polygon(a).symmetric_difference(Polygon(b)).area <= tol


def finite_difference(motion, t: float, h: float = 1e-6) -> np.ndarray:
    (after, _), (before, _) = motion(t + h), motion(t - h)
    return (after - before) / (2.0 * h)


# --- the Minkowski morph ----------------------------------------------------------------


@pytest.mark.parametrize("seed", range(12))
def test_morph_is_the_convex_minkowski_combination_at_every_instant(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = random_convex(rng, int(rng.integers(3, 12)), (0.0, 0.0), 1.0)
    b = random_convex(rng, int(rng.integers(3, 12)), rng.uniform(-1, 1, 2), 1.5)
    morph = Morph(a, b, 2.0, 3.0, support_pairs(a, b))
    for t in np.linspace(2.0, 5.5, 36):
        vertices, velocities = morph(float(t))
        validate_polygon(vertices)  # convex, simple, no repeated vertex
        assert signed_area(vertices) > 0.0
        s, _ = smoothstep((t - 2.0) / 3.0)
        # Independent reference: the hull of all pairwise combinations (shapely).
        reference = MultiPoint([(1 - s) * p + s * q for p in a for q in b]).convex_hull
        assert Polygon(vertices).symmetric_difference(reference).area <= 1e-9
        assert velocities.shape == vertices.shape
    assert same_set(morph(5.0)[0], b) and np.allclose(morph(5.0)[1], 0.0)


@pytest.mark.parametrize("seed", range(8))
def test_morph_vertex_velocities_match_central_differences(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    a = random_convex(rng, 9, (0.0, 0.0), 1.0)
    b = random_convex(rng, 7, (0.4, -0.2), 0.8)
    morph = Morph(a, b, 0.0, 2.0, support_pairs(a, b))
    for t in rng.uniform(0.05, 1.95, 10):
        vertices, velocities = morph(float(t))
        assert len(vertices) == len(support_pairs(a, b))
        np.testing.assert_allclose(velocities, finite_difference(morph, float(t)), atol=1e-6)


def test_morph_starts_and_ends_without_zero_length_edges() -> None:
    a = SQUARE
    b = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])  # a diamond: 8 pairs
    morph = Morph(a, b, 0.0, 1.0, support_pairs(a, b))
    assert len(support_pairs(a, b)) == 8
    for t in (0.0, 1e-9, 1.0 - 1e-12, 1.0):
        vertices, velocities = morph(t)
        validate_polygon(vertices)
        assert np.abs(velocities).max() < 1e-6  # s' vanishes at both ends


# --- similarity motions (translate, rotate, scale) ---------------------------------------


@pytest.mark.parametrize(
    "request_",
    [
        SteerRequest("translate", dx=1.0, dy=-0.3, duration=4.0),
        SteerRequest("rotate", angle=math.radians(70.0), duration=5.0),
        SteerRequest("rotate", angle=-1.0, about=(0.5, 0.5), duration=5.0),
        SteerRequest("scale", factor=1.8, duration=3.0),
        SteerRequest("scale", factor=0.7, about=(-0.5, -0.5), duration=3.0),
    ],
    ids=lambda r: r.describe(),
)
def test_similarities_are_convex_exact_and_end_where_asked(request_: SteerRequest) -> None:
    steer = steering(limits=Limits(2.0, WORKSPACE, 0.3))  # fast enough for every duration
    reply = send(steer, request_, 1.0)
    assert reply.accepted and reply.duration == pytest.approx(request_.duration)
    for t in np.linspace(1.01, 1.0 + request_.duration - 0.01, 25):
        vertices, velocities = steer.domain(float(t))
        validate_polygon(vertices)
        np.testing.assert_allclose(velocities, finite_difference(steer.domain, float(t)), atol=1e-6)
    end, velocity = steer.domain(1.0 + request_.duration + 0.5)
    about = centroid(SQUARE) if request_.about is None else np.array(request_.about)
    c, s = math.cos(request_.angle), math.sin(request_.angle)
    expected = about + request_.factor * (SQUARE - about) @ np.array([[c, s], [-s, c]])
    np.testing.assert_allclose(end, expected + [request_.dx, request_.dy], atol=1e-12)
    assert np.abs(velocity).max() < 1e-12


# --- speed limit -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "request_",
    [
        SteerRequest("translate", dx=2.0, dy=1.0),
        SteerRequest("rotate", angle=2.0),
        SteerRequest("scale", factor=2.5),
        SteerRequest("polygon", polygon=[[1, -1], [2.5, 0], [1, 1.5]]),
        SteerRequest("translate", dx=2.0, dy=1.0, duration=0.5),  # too fast: stretched
        SteerRequest("translate", dx=2.0, dy=1.0, speed=9.0),  # too fast: clipped
    ],
    ids=lambda r: r.describe(),
)
def test_no_vertex_moves_faster_than_the_limit(request_: SteerRequest) -> None:
    steer = steering()
    reply = send(steer, request_, 0.0)
    assert reply.accepted
    speeds = [
        np.linalg.norm(steer.domain(float(t))[1], axis=1).max()
        for t in np.linspace(0.0, reply.duration, 401)
    ]
    assert max(speeds) <= LIMITS.max_speed * (1 + 1e-9)
    assert max(speeds) >= 0.5 * LIMITS.max_speed  # and it is not needlessly slow
    if request_.duration is not None or request_.speed is not None:
        assert "stretched" in reply.reason or "clipped" in reply.reason


def test_a_requested_speed_below_the_limit_is_kept() -> None:
    steer = steering()
    reply = send(steer, SteerRequest("translate", dx=1.0, dy=0.0, speed=0.1), 0.0)
    assert reply.accepted and reply.reason == ""
    assert reply.duration == pytest.approx(PEAK_RATE * 1.0 / 0.1)


def test_default_domain_speed_leaves_room_to_close_a_gap() -> None:
    assert default_max_domain_speed(0.8, 2.0) == pytest.approx(0.8 - 2.0 * 0.14)
    assert default_max_domain_speed(0.8, 8.0) == pytest.approx(0.2)  # never below a quarter


# --- pre-emption -------------------------------------------------------------------------


def assert_smooth(steer: Steering, t0: float, t1: float, limit: float) -> None:
    """Between t0 and t1: convex, velocities = central differences of the vertices, no vertex
    faster than ``limit`` (vertex lists of a brake and of the motion after it line up)."""
    for t in np.linspace(t0, t1, 41)[1:-1]:
        vertices, velocity = steer.domain(t)
        validate_polygon(vertices)
        np.testing.assert_allclose(velocity, finite_difference(steer.domain, t), atol=1e-6)
        assert np.linalg.norm(velocity, axis=1).max() <= limit + 1e-9


def test_a_new_request_takes_over_from_wherever_s_is_without_a_jump() -> None:
    steer = steering()
    assert send(steer, SteerRequest("translate", dx=2.0, dy=0.0, duration=4.0), 1.0).accepted
    t = 2.7
    before, moving = steer.domain(t)
    assert 0.1 < before[0, 0] + 0.5 < 1.9 and np.abs(moving).max() > 0.2  # mid-way, moving
    target = [[-1.0, -1.0], [0.0, -1.2], [0.5, 0.0], [-0.5, 1.0]]
    reply = send(steer, SteerRequest("polygon", polygon=target), t)
    assert reply.accepted and reply.reason.startswith("braking")
    # S goes on where it was, at the speed it had: position and velocity continuous.
    after, velocity = steer.domain(t)
    np.testing.assert_array_equal(after, before)
    np.testing.assert_array_equal(velocity, moving)
    speed = float(np.linalg.norm(moving, axis=1).max())
    braking = brake_span(speed)
    assert braking == pytest.approx(2.0 * speed / BRAKE_DECELERATION)
    # It brakes along the translation: the fastest vertex slows at most BRAKE_DECELERATION
    # beyond what the translation itself was doing, and stops where the brake ends.
    for tb in np.linspace(t, t + braking, 30)[1:-1]:
        _, v_after = steer.domain(tb + 1e-6)
        _, v_before = steer.domain(tb - 1e-6)
        slowing = np.linalg.norm(v_after - v_before, axis=1).max() / 2e-6
        assert slowing <= BRAKE_DECELERATION + 0.3  # the translation's own: < 0.3 m/s^2
        assert steer.domain(tb)[0][0, 1] == pytest.approx(before[0, 1])  # still along x
    stopped, at_rest = steer.domain(t + braking)
    assert np.abs(at_rest).max() == 0.0
    assert stopped[0, 0] > before[0, 0]  # it went on a little, not back
    assert_smooth(steer, t, t + reply.duration, LIMITS.max_speed)
    assert same_set(steer.domain(t + reply.duration)[0], np.array(target))
    # A rotation pre-empting the moving morph brakes it; another one during that brake
    # keeps the brake (S's velocity is continuous) and only replaces what follows it.
    later = t + braking + 1.0
    mid, mid_velocity = steer.domain(later)
    assert send(steer, SteerRequest("rotate", angle=0.3), later).accepted
    np.testing.assert_array_equal(steer.domain(later)[0], mid)
    np.testing.assert_array_equal(steer.domain(later)[1], mid_velocity)
    brake = steer.motion
    assert isinstance(brake, Brake) and brake.t0 == later
    reply = send(steer, SteerRequest("scale", factor=0.8), later + 0.05)
    assert reply.accepted
    assert steer.motion.t0 == later and steer.motion.span == brake.span
    assert reply.duration == pytest.approx(brake.end - later - 0.05 + steer.motion.then.span)
    stop, _ = brake.motion(brake.stop_time)
    np.testing.assert_allclose(
        steer.domain(brake.end + steer.motion.then.span)[0],
        centroid(stop) + 0.8 * (stop - centroid(stop)),
        atol=1e-12,
    )
    assert_smooth(steer, later, later + 10.0, LIMITS.max_speed)


def test_a_still_s_does_not_brake() -> None:
    steer = steering()
    reply = send(steer, SteerRequest("translate", dx=1.0, dy=0.0, duration=4.0), 1.0)
    assert reply.accepted and reply.reason == "" and reply.duration == 4.0
    assert not isinstance(steer.motion, Brake)
    # Once that motion ended, S is at rest again: the next one starts at once.
    assert send(steer, SteerRequest("rotate", angle=0.3, duration=3.0), 5.0).duration == 3.0
    assert not isinstance(steer.motion, Brake)


@pytest.mark.parametrize("every", [2.0, 0.05])
def test_brakes_never_nest(every: float) -> None:
    """Requests after the last brake ended, or a stream of them while S brakes (an operator
    dragging at 20 Hz): at most one brake, never a chain that grows with the requests."""
    steer = steering(limits=Limits(0.5, None, 0.0))
    for k in range(60):
        t = every * k + 1.0
        before = steer.domain(t)
        assert send(steer, SteerRequest("translate", dx=1.0, dy=0.0), t).accepted
        for ahead, behind in zip(steer.domain(t), before, strict=True):
            np.testing.assert_array_equal(ahead, behind)
        assert not isinstance(getattr(steer.motion, "motion", None), Brake)
        assert not isinstance(getattr(steer.motion, "then", None), Brake)
        assert_smooth(steer, t, t + every, 0.5)


def test_the_script_runs_until_a_request_takes_over() -> None:
    def script(t: float):
        return SQUARE + [0.1 * t, 0.0], np.tile([0.1, 0.0], (4, 1))

    steer = Steering(script, LIMITS)
    np.testing.assert_allclose(steer.domain(3.0)[0], script(3.0)[0])
    reply = send(steer, SteerRequest("translate", dx=0.0, dy=0.0), 3.0)  # "stop"
    assert reply.accepted
    braking = brake_span(0.1)
    assert reply.duration == pytest.approx(braking)
    np.testing.assert_allclose(steer.domain(3.0)[1], script(3.0)[1])  # no jump in velocity
    # The script's S slows down along its path and stops a third of the brake further on.
    np.testing.assert_allclose(steer.domain(9.0)[0], script(3.0 + braking / 3.0)[0])
    assert np.all(steer.domain(9.0)[1] == 0.0)
    assert_smooth(steer, 3.0, 9.0, 0.1)


def test_braking_counts_against_the_longest_motion() -> None:
    def script(t: float):
        return SQUARE + [0.5 * t, 0.0], np.tile([0.5, 0.0], (4, 1))

    steer = Steering(script, Limits(0.5, None, 0.0))
    crawl = PEAK_RATE / 3599.5  # 1 m in 3599.5 s: fits alone, not after a 1 s brake
    reply = send(steer, SteerRequest("translate", dx=1.0, dy=0.0, speed=crawl), 1.0)
    assert not reply.accepted and reply.reason.startswith("too-slow")
    assert steer.motion is None


def test_chained_morphs_stay_within_the_wire_vertex_limit() -> None:
    rng = np.random.default_rng(7)
    steer = steering(limits=Limits(0.5, None, 0.0))
    for k in range(40):  # an operator dragging vertices: a new polygon every 0.1 s
        target = random_convex(rng, 12, (0.0, 0.0), 1.0)
        assert send(steer, SteerRequest("polygon", polygon=target), 0.1 * k).accepted
        vertices, _ = steer.domain(0.1 * k + 0.05)
        assert len(vertices) <= 64
        validate_polygon(vertices)
    assert steer.largest_jump < 0.05


def test_simplify_drops_the_least_important_vertices() -> None:
    circle = np.array([[math.cos(a), math.sin(a)] for a in np.linspace(0, 2 * math.pi, 80)[:-1]])
    fewer, jump = simplify(circle, 20)
    assert len(fewer) == 20
    validate_polygon(fewer)
    assert 0.0 < jump < 0.05
    assert Polygon(circle).contains(Polygon(fewer).buffer(-1e-9))


# --- refusals ----------------------------------------------------------------------------


NAN_POLYGON = msgpack.packb(
    {
        "v": 1, "kind": "polygon", "dx": 0.0, "dy": 0.0, "angle": 0.0, "factor": 1.0,
        "polygon": [[0.0, 0.0], [1.0, 0.0], [float("nan"), 1.0]],
    }
)  # fmt: skip


@pytest.mark.parametrize(
    ("payload", "code"),
    [
        (SteerRequest("polygon", polygon=[[0, 0], [1, 0], [0.2, 0.2], [0, 1]]), "non-convex"),
        (SteerRequest("polygon", polygon=[[0, 0], [1, 1], [1, 0], [0, 1]]), "self-intersecting"),
        (SteerRequest("polygon", polygon=[[0, 0], [1, 1], [2, 2]]), "degenerate"),
        (SteerRequest("polygon", polygon=[[0, 0], [0, 0], [1, 0], [0, 1]]), "degenerate"),
        (SteerRequest("polygon", polygon=[[2, 0], [4, 0], [3, 1]]), "outside-workspace"),
        (SteerRequest("translate", dx=2.7, dy=0.0), "outside-workspace"),
        # Back where it started, but half-way round it would cross the wall at y = -2:
        (SteerRequest("rotate", angle=2 * math.pi, about=(0.0, -1.2)), "outside-workspace"),
        (SteerRequest("polygon", polygon=[[0, 0], [0.3, 0], [0, 0.3]]), "too-small"),
        (SteerRequest("scale", factor=0.4), "too-small"),
        (SteerRequest("translate", dx=1.0, dy=0.0, speed=1e-4), "too-slow"),
        (NAN_POLYGON, "nonfinite"),
        (b"\xc1\x00", "undecodable"),
        (b"\x80" * 9000, "undecodable"),  # oversize
        (msgpack.packb({"v": 1, "kind": "translate"}), "undecodable"),  # missing fields
    ],
)
def test_infeasible_requests_are_refused_and_s_does_not_move(payload, code: str) -> None:
    steer = steering()
    assert send(steer, SteerRequest("translate", dx=0.5, dy=0.0, duration=2.0), 0.0).accepted
    motion = steer.motion
    before = steer.domain(1.0)
    raw = payload.encode() if isinstance(payload, SteerRequest) else payload
    reply = steer.handle(raw, 1.0, 1.7e9, True)
    assert not reply.accepted and reply.reason.startswith(f"{code}: ") and reply.duration == 0
    assert code in REFUSALS and steer.refused[code] == 1
    assert steer.motion is motion
    np.testing.assert_array_equal(steer.domain(1.0)[0], before[0])
    record = steer.records[-1]
    assert (record.accepted, record.reason, record.t) == (False, reply.reason, 1.0)


def test_requests_before_the_start_are_refused() -> None:
    steer = steering()
    reply = send(steer, SteerRequest("translate", dx=0.5, dy=0.0), 0.0, running=False)
    assert not reply.accepted and reply.reason.startswith("not-running")
    assert steer.motion is None


def test_translating_a_crowded_domain_is_not_too_small() -> None:
    steer = steering(limits=Limits(0.5, WORKSPACE, min_area=5.0))  # S is 1 m^2 already
    assert send(steer, SteerRequest("translate", dx=0.5, dy=0.0), 0.0).accepted
    assert not send(steer, SteerRequest("scale", factor=0.9), 1.0).accepted


# --- records -----------------------------------------------------------------------------


def test_the_error_plot_marks_every_request(tmp_path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covswarm.mission.report import _mark_steering, write_outputs

    steer = steering()
    send(steer, SteerRequest("translate", dx=0.5, dy=0.0, duration=2.0), 1.0)
    send(steer, SteerRequest("polygon", polygon=[[0, 0], [1, 1], [1, 0], [0, 1]]), 4.0)
    send(steer, SteerRequest("scale", factor=1.2), 6.0)
    events = [record.to_dict() for record in steer.records]
    fig, ax = plt.subplots()
    _mark_steering(ax, events)
    lines = [(line.get_xdata()[0], line.get_color()) for line in ax.get_lines()]
    assert lines == [(1.0, "tab:green"), (4.0, "tab:red"), (6.0, "tab:green")]
    assert len(ax.patches) == 2  # the bands while S moved
    # each until its motion's end or the next accepted request, which took S over
    spans = [(p.get_x(), p.get_x() + p.get_width()) for p in ax.patches]
    assert spans[0] == pytest.approx((1.0, 3.0)) and spans[1][0] == pytest.approx(6.0)
    fig2, ax2 = plt.subplots()
    cut = [dict(events[0], duration=3600.0), events[2]]  # a long motion cut short at t = 6
    _mark_steering(ax2, cut)
    assert ax2.patches[0].get_x() + ax2.patches[0].get_width() == pytest.approx(6.0)
    plt.close(fig2)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "steering request",
        "refused steering request",
    ]
    plt.close(fig)
    t = np.linspace(0.0, 10.0, 50)
    write_outputs(
        tmp_path,
        summary={"steering": events, "scenario": "live"},
        t=t,
        error=0.1 + 0.0 * t,
        trajectories=np.zeros((50, 2, 2)),
        polygons=[SQUARE] * 50,
    )
    assert (tmp_path / "error.png").stat().st_size > 0


def test_a_restarted_coordinator_replays_the_journal_exactly() -> None:
    steer, journal = steering(), []
    requests = [
        (SteerRequest("translate", dx=1.0, dy=0.2), 1.0),
        (SteerRequest("polygon", polygon=[[0, 0], [1, 1], [1, 0], [0, 1]]), 2.0),  # refused
        (SteerRequest("rotate", angle=0.7), 2.5),  # pre-empts the translation
        (SteerRequest("polygon", polygon=[[0, -1], [2, -1], [2, 0.5], [0.5, 1]]), 6.0),
    ]
    for request, t in requests:
        if send(steer, request, t).accepted:
            journal.append(steer.journal_line())
    assert len(journal) == 3
    again = steering()
    assert again.replay([*journal, "not json", '{"t": 1}']) == 3  # bad lines skipped
    for t in (0.5, 1.7, 3.0, 6.5, 30.0):
        np.testing.assert_array_equal(again.domain(t)[0], steer.domain(t)[0])
        np.testing.assert_array_equal(again.domain(t)[1], steer.domain(t)[1])


def test_too_small_is_twice_the_room_the_crowding_warning_asks() -> None:
    """One rule for "too small": a target is refused below MIN_ROOMS (2) robot rooms per
    robot, the room below which the crowding warning says the team cannot reach its CVT."""
    from covswarm.mission.crowding import robot_room, smallest_cell_area
    from covswarm.tvd.safety import DEFAULT_MARGIN

    limits = Limits.for_team(10, 0.5, None)
    room = robot_room(0.14, DEFAULT_MARGIN)
    assert limits.min_area == pytest.approx(10 * 2.0 * room)
    for scale, accepted in ((1.02, True), (0.98, False)):
        side = math.sqrt(scale * limits.min_area)
        target = [[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]]
        reply = send(steering(limits=limits), SteerRequest("polygon", polygon=target), 1.0)
        assert reply.accepted == accepted, reply.reason
        # The crowding estimate of the target agrees: twice the room, give or take the grid.
        estimate = smallest_cell_area(np.array(target), 10)
        assert estimate == pytest.approx(2.0 * scale * room, rel=0.03)


def test_a_motion_that_ends_after_the_mission_is_accepted_with_a_note() -> None:
    steer = Steering(still(SQUARE), LIMITS, end=10.0)
    early = send(steer, SteerRequest("translate", dx=1.0, dy=0.0, duration=4.0), 1.0)
    assert early.accepted and early.reason == ""
    late = send(steer, SteerRequest("translate", dx=1.0, dy=0.0, duration=4.0), 8.0)
    assert late.accepted and late.duration > 2.0
    assert late.reason.endswith(
        f"S arrives at t = {8.0 + late.duration:.1f} s, after the mission ends (10 s)"
    )
