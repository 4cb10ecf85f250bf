"""Map single-integrator velocities to differential-drive wheel speeds (controller side).

The coverage laws output a planar velocity per robot; a Khepera IV can only drive forwards
and turn. The near-identity diffeomorphism (the Robotarium's ``si_to_uni`` mapping) makes a
point at ``projection_distance`` ahead of the wheel axle follow the commanded velocity
exactly; the axle centre then lags by at most that distance, so the distance trades turning
aggressiveness (small distance -> large turn rates -> wheel saturation) against tracking
error (large distance).

``DEFAULT_PROJECTION_DISTANCE`` was picked in ``covswarm sim --scenario passage --dynamics
unicycle`` (10 robots, random headings, seed 0), mean e_a over the whole run against the
single-integrator run's 0.0506 m: 0.01 m -> 0.0514 (0.15% of commands saturated), 0.02 m ->
0.0521, 0.03 m -> 0.0530 (0.07%), 0.05 m -> 0.0552, 0.08 m -> 0.0592; the steady-state means
differ by under 5% across the range. 0.03 m (a fifth of the body diameter) tracks within ~5%
of an ideal integrator, while smaller distances buy little and turn harder, which a real
robot with command latency pays for.

``integrate`` is the robot side: the exact arcs a differential-drive robot drives under
held wheel speeds (what ``sim_robot`` simulates and what an agent predicts its robot
does with the commands it sent).

Pure numpy, no I/O: imported by agent and robot processes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from covswarm.tvd.arrays import as_rows, as_values

DEFAULT_PROJECTION_DISTANCE = 0.03  # m; see the module docstring for how it was chosen
MAX_WHEEL_SPEED = 0.8  # m/s rim speed; the Khepera IV is quoted 0.8-1.0 m/s
# A robot that a safety filter holds back while it still moves passes beside its aim, on
# the side away from the robot that holds it back (:func:`steer`, :func:`pass_sides`): by
# up to PASS_ANGLE rad, most where its forward speed is cut to PASS_STOPPED of what it asks
# for, none below that (stopped dead: it faces its aim and waits) nor from PASS_BELOW up;
# it turns toward that heading by PASS_DAMPING of the angle each period. Picked on
# circle-1000 (covswarm sim, 3 seeds, with and without --face-start) and
# tests/test_overload_heading.py's starved team; docs/scaling.md has the figures.
PASS_ANGLE = 1.0
PASS_BELOW = 0.5
PASS_STOPPED = 0.05
PASS_DAMPING = 0.5
# A robot stopped dead by a safety filter turns toward its slide (:func:`steer`'s
# ``slides``) when the slide keeps at least SLIDE_MIN of its aim's speed (callers then try
# its aim turned a quarter: a still robot dead ahead); below that it is boxed in, and it
# faces its aim and waits.
SLIDE_MIN = 0.1
# ... once it has been stopped dead for SLIDE_AFTER s on end: a robot waits its turn in a
# file that sets off, and takes a slide only where it would otherwise wait for ever.
SLIDE_AFTER = 1.0
# ... or at once when no robot that stops it is ahead of it (:func:`stopped_beside`): every
# robot within BESIDE_REACH m beyond the safe distance more than BESIDE_ANGLE rad off its
# heading. Two robots side by side whose aims converge stop each other dead, neither in
# the other's way, and waited out SLIDE_AFTER together while S's edge passed the robots
# queued behind them (tests/data/square-200.toml in deploy.netsim with brains stepped every
# 0.08-0.14 s, phase seeds 0-5: e_a's second half 0.061-0.130 m, mean 0.076; 0.036-0.064 m,
# mean 0.052 with this rule: scripts/beside_slide.py, 3 Dec 2026).
BESIDE_ANGLE = math.pi / 3
BESIDE_REACH = 0.01
# A slide is taken for safe distances SLIDE_CLEARANCE (m) larger than the filter's: at the
# safe distance the slide runs along it, which a robot turning toward it reaches only in the
# limit, its forward speed held at zero all the while; a little farther out, the slide
# leads away and the robot drives as soon as it faces past the tangent.
SLIDE_CLEARANCE = 0.005
# m/s: a forward speed the filter cuts to this or less is stopped dead. Not 0: a robot the
# barrier holds at the safe distance gets +-1e-17 m/s from one step to the next, and a test
# of <= 0 restarted its SLIDE_AFTER wait at every positive one, so robots queued behind a
# dead robot waited for ever (covswarm sim --scenario scenarios/circle-400.toml --still
# 0,...,9: 56 and 120 robots outside S at the end in seeds 0 and 1; 9 and 43 with 1 mm/s).
STOPPED_SPEED = 1e-3


@dataclass(frozen=True)
class DiffDrive:
    """Geometry and limits of a differential-drive robot (SI units: m, m/s)."""

    wheel_radius: float = 0.021
    wheel_separation: float = 0.1054
    body_diameter: float = 0.14
    max_wheel_speed: float = MAX_WHEEL_SPEED

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "wheel_separation", "body_diameter", "max_wheel_speed"):
            value = getattr(self, name)
            number = not isinstance(value, bool) and isinstance(value, (int, float))
            if not (number and 0.0 < value < math.inf):
                raise ValueError(f"DiffDrive: {name} must be a finite number > 0, got {value!r}")


KHEPERA_IV = DiffDrive()


def wheel_speeds(
    headings: np.ndarray,
    velocities: np.ndarray,
    robot: DiffDrive = KHEPERA_IV,
    projection_distance: float = DEFAULT_PROJECTION_DISTANCE,
    hold: float | np.ndarray = 0.0,
    aims: np.ndarray | None = None,
    sides: np.ndarray | None = None,
    slides: np.ndarray | None = None,
) -> np.ndarray:
    """Rim speeds (left, right) in m/s that make each robot follow a planar velocity:
    :func:`steer`'s wheels."""
    return steer(headings, velocities, robot, projection_distance, hold, aims, sides, slides)[0]


def stopped_dead(headings: np.ndarray, velocities: np.ndarray, aims: np.ndarray) -> np.ndarray:
    """(n,) bool: the robots whose forward speed a safety filter cut to STOPPED_SPEED or less
    while their aim lies ahead (headings (n,) rad; velocities, aims (n, 2) m/s, after and
    before the filter): those :func:`steer` turns toward their slide, and the only ones whose slide
    it reads. Non-finite rows are not."""
    headings = np.asarray(headings, dtype=float).reshape(-1)
    velocities = np.asarray(velocities, dtype=float).reshape(-1, 2)
    aims = np.asarray(aims, dtype=float).reshape(-1, 2)
    e = np.stack([np.cos(headings), np.sin(headings)], axis=1)
    with np.errstate(invalid="ignore"):
        ahead = np.einsum("ij,ij->i", aims, e)
        forward = np.einsum("ij,ij->i", velocities, e)
        return (ahead > 0.0) & (forward <= STOPPED_SPEED)


def stopped_dead_one(heading: float, vx: float, vy: float, aim: tuple[float, float]) -> bool:
    """:func:`stopped_dead` for one robot in plain floats."""
    cos, sin = math.cos(heading), math.sin(heading)
    return aim[0] * cos + aim[1] * sin > 0.0 and vx * cos + vy * sin <= STOPPED_SPEED


def stopped_beside(
    position: tuple[float, float],
    heading: float,
    others: np.ndarray,
    safe_distance: float,
    reach: float = BESIDE_REACH,
    angle: float = BESIDE_ANGLE,
) -> bool:
    """Whether a robot at ``position`` (m) facing ``heading`` (rad) is held back beside the
    robots near it, none ahead: at least one of ``others`` ((m, 2) m, or rows whose first
    two columns are positions) lies within ``safe_distance`` + ``reach`` m of it, and every
    such one more than ``angle`` rad off its heading. A robot of ``others`` at its own
    position is itself. Such a robot stopped dead takes its slide at once (SLIDE_AFTER)."""
    others = np.asarray(others, dtype=float)
    if len(others) == 0:
        return False
    rel = others.reshape(len(others), -1)[:, :2] - np.asarray(position, dtype=float)
    distance = np.hypot(rel[:, 0], rel[:, 1])
    close = (distance > 0.0) & (distance <= safe_distance + reach)
    if not close.any():
        return False
    along = rel[close] @ np.array([math.cos(heading), math.sin(heading)])
    return bool(np.all(along < math.cos(angle) * distance[close]))


def takes_slide(
    headings: np.ndarray, velocities: np.ndarray, aims: np.ndarray, slides: np.ndarray
) -> np.ndarray:
    """(n,) bool: the robots :func:`steer` turns toward their ``slides`` (n, 2) m/s: those
    :func:`stopped_dead` whose slide keeps at least SLIDE_MIN of their aim's speed."""
    aims = np.asarray(aims, dtype=float).reshape(-1, 2)
    slides = np.asarray(slides, dtype=float).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        long = np.hypot(slides[:, 0], slides[:, 1]) >= SLIDE_MIN * np.hypot(aims[:, 0], aims[:, 1])
    return stopped_dead(headings, velocities, aims) & long


def takes_slide_one(
    heading: float, vx: float, vy: float, aim: tuple[float, float], slide: tuple[float, float]
) -> bool:
    """:func:`takes_slide` for one robot in plain floats."""
    if not stopped_dead_one(heading, vx, vy, aim):
        return False
    return math.hypot(*slide) >= SLIDE_MIN * math.hypot(*aim)


def steer(
    headings: np.ndarray,
    velocities: np.ndarray,
    robot: DiffDrive = KHEPERA_IV,
    projection_distance: float = DEFAULT_PROJECTION_DISTANCE,
    hold: float | np.ndarray = 0.0,
    aims: np.ndarray | None = None,
    sides: np.ndarray | None = None,
    slides: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rim speeds (left, right) in m/s that make each robot follow a planar velocity, and
    which robots' turn rate was capped for ``hold``.

    headings: (n,) rad; velocities: (n, 2) m/s; hold: s the command will stay in force,
    scalar or (n,) (0: not known, no cap); aims: (n, 2) m/s, the velocities the robots
    want before a safety filter bounded their forward speed (None: ``velocities``); sides:
    (n,) +1 or -1, the side each robot held back passes on (None: all +1, the left);
    slides: (n, 2) m/s, the velocities the same filter leaves a robot that could move
    sideways (covswarm.tvd.safety.safe_velocity without a heading; read only where
    :func:`stopped_dead`, NaN elsewhere is fine; None: none).
    Returns wheels (n, 2) [left, right] and capped (n,) bool.

    Forward speed v = vx cos th + vy sin th, turn rate w = (-vx sin th + vy cos th) / l.
    That turn rate is the derivative of a continuous loop: held for ``hold`` s it turns the
    robot by w * hold = |u| sin(e) hold / l, e the angle from the heading to the velocity.
    Once |u| hold / l exceeds 2 (0.8 m/s held 0.13 s at l = 0.05 m) the heading overshoots
    the velocity's direction by more than it was off, and a robot far from its goal spins
    in place instead of driving (issue 24: an overloaded team, ~3 Hz, left robots behind
    spinning). So |w| is capped at |e| / hold: the held command at most turns the robot to
    face the velocity.

    The velocity to face is the aim, not the filtered velocity: a filter for unicycles
    (covswarm.tvd.safety.unicycle_rows) bounds only the forward speed and keeps the
    sideways part, so a robot blocked ahead (forward speed clipped to 0) was asked for a
    velocity square to its heading at every step, a quarter turn each time: it swung about
    its aim with its wheels at their limit for as long as it stayed blocked (circle-1000 in
    covswarm sim: 48 robot-s saturated, a straggler outside S for 21 s, docs/scaling.md).
    Capped by the angle to the aim it faces where it wants to go and stops turning there.
    But a robot that only ever faces its aim follows the robot ahead of it at that robot's
    pace, a file that the swing had broken up (tests/test_overload_heading.py's starved
    team, all heading for one point: e_a 0.60 m against 0.25 m). So a robot held back while
    it still moves, its forward speed v cut to a fraction r = v / a of the aim's forward
    part a, aims PASS_ANGLE * g(r) beside its aim, g(r) = min(1, r / PASS_STOPPED)
    * max(0, 1 - r / PASS_BELOW): it passes a slower robot ahead. To the left (``sides``
    +1, the default) or the right (-1): :func:`pass_sides` picks the side away from the
    robot holding it back. Always to the left, a robot whose blocker was ahead on its left
    turned into it and trailed it at its pace: behind S's trailing edge, robots left
    outside stayed out (circle-1000, covswarm sim with the agents' robot model and filter,
    seeds 0-7: e_a's second half 0.066 m on average, 0.039 m passing away; scripts/
    pass_side.py). (To the side of each one's heading, robots following one another
    veered into each other and stayed there: circle-1000's e_a rose to 30 m.) Not held
    back (r >= PASS_BELOW: following a team that moves, as S's trailing edge does) or
    stopped dead (r = 0: boxed in, where a veer only points the robot at the next robot
    along) it faces its aim. Toward a veered heading it turns PASS_DAMPING of the angle per
    period: r changes with the heading, and a full turn each period swung between the aim
    and the veer. The turn rate toward a veered aim a' is |a| sin(e') / l, capped as above.

    Stopped dead with a ``slides`` row (callers give one once it has been stopped dead for
    SLIDE_AFTER s), a robot turns toward its slide s instead, at
    |s| sin(e_s) / l capped at |e_s| / hold (e_s the angle to s), its forward speed as
    filtered: facing its aim it would wait for ever beside a robot that does not move (a
    stranded one, an obstacle held), its aim and the filter's row in balance: 0.16 m from
    a still robot 10-60 degrees off its aim, it waited all 6 s (tests/test_slide.py).
    Facing s, the filter lets it drive, since s meets every row. The caller then aims it
    at its slide until the rows no longer bend its aim (covswarm.agent.brain.AgentBrain.
    _safety_inputs, and the simulator alike), and it goes round the robot. Not where
    |s| < SLIDE_MIN |a|: boxed in, it faces its aim and waits as before (for a still robot
    within asin(SLIDE_MIN), 5.7 degrees, of dead ahead, callers give the slide of the aim
    turned a quarter: covswarm.agent.brain.slide_of).

    Saturation then scales both wheels of a robot by the same factor so the curvature (the
    path) is kept and only the speed along it drops. A robot with a non-finite heading or
    velocity gets (0, 0): a stopped robot is safer than a NaN on the wire.
    """
    if projection_distance <= 0.0:
        raise ValueError(f"projection_distance must be positive, got {projection_distance}")
    velocities = as_rows(velocities, "velocities")
    headings = as_values(headings, "headings", len(velocities))
    hold = np.broadcast_to(np.asarray(hold, dtype=float), headings.shape)
    if not np.all(hold >= 0.0):
        raise ValueError(f"hold must be >= 0 s, got {hold}")
    aims = velocities if aims is None else as_rows(aims, "aims", len(velocities))
    half_track = 0.5 * robot.wheel_separation
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        # non-finite rows are zeroed below
        cos, sin = np.cos(headings), np.sin(headings)
        vx, vy = velocities[:, 0], velocities[:, 1]
        v = vx * cos + vy * sin
        lateral = -vx * sin + vy * cos
        w = lateral / projection_distance
        # e the angle to the aim, veered to the left by a robot held back (see above)
        ax, ay = aims[:, 0], aims[:, 1]
        ahead = ax * cos + ay * sin
        error = np.arctan2(-ax * sin + ay * cos, ahead)
        ratio = np.where(ahead > 0.0, v / np.where(ahead > 0.0, ahead, 1.0), 1.0)
        veer = PASS_ANGLE * (
            np.clip(ratio / PASS_STOPPED, 0.0, 1.0) * np.clip(1.0 - ratio / PASS_BELOW, 0.0, 1.0)
        )
        veering = veer > 0.0
        if sides is not None:
            veer = veer * np.asarray(sides, dtype=float).reshape(-1)
        error = np.where(veering, error + veer, error)
        w = np.where(veering, np.hypot(ax, ay) * np.sin(error) / projection_distance, w)
        if slides is not None:
            slides = np.asarray(slides, dtype=float).reshape(-1, 2)
            if slides.shape != velocities.shape:
                raise ValueError(f"{slides.shape[0]} slides for {velocities.shape[0]} velocities")
            sx, sy = slides[:, 0], slides[:, 1]
            slid = takes_slide(headings, velocities, aims, slides)
            error = np.where(slid, np.arctan2(-sx * sin + sy * cos, sx * cos + sy * sin), error)
            w = np.where(slid, (-sx * sin + sy * cos) / projection_distance, w)
            veering &= ~slid  # (crawling under STOPPED_SPEED, it veered as well)
        # |e| / hold (damped toward a veer), and no cap (inf) where the hold is not known
        limit = np.abs(error) / np.where(hold > 0.0, hold, np.nan)
        limit = np.where(hold > 0.0, np.where(veering, PASS_DAMPING * limit, limit), np.inf)
        capped = np.abs(w) > limit
        w = np.where(capped, np.copysign(limit, w), w)
        wheels = np.stack([v - w * half_track, v + w * half_track], axis=1)
    bad = ~np.isfinite(wheels).all(axis=1)
    wheels[bad] = 0.0
    peak = np.abs(wheels).max(axis=1, initial=0.0)
    scale = np.where(
        peak > robot.max_wheel_speed, robot.max_wheel_speed / np.maximum(peak, 1e-300), 1.0
    )
    return wheels * scale[:, None], capped & ~bad


def steer_one(
    heading: float, vx: float, vy: float, robot: DiffDrive = KHEPERA_IV,
    projection_distance: float = DEFAULT_PROJECTION_DISTANCE, hold: float = 0.0,
    aim: tuple[float, float] | None = None, side: float = 1.0,
    slide: tuple[float, float] | None = None,
) -> tuple[float, float, bool]:  # fmt: skip
    """:func:`steer` for one robot in plain floats: rim speeds (left, right) m/s for the
    planar velocity (vx, vy) m/s from ``heading`` rad, and whether the turn rate was capped
    for ``hold`` s toward ``aim`` (m/s; None: (vx, vy)), or toward ``slide`` (m/s) when
    stopped dead; the same arithmetic, guards and errors. An agent steers its one robot
    every step, where numpy's per-call overhead was ~40 us of steer's cost for a single row
    (tests/test_drive_model.py checks both agree on random, capped and non-finite input)."""
    if projection_distance <= 0.0:
        raise ValueError(f"projection_distance must be positive, got {projection_distance}")
    if not hold >= 0.0:
        raise ValueError(f"hold must be >= 0 s, got {hold}")
    if not math.isfinite(heading):
        return 0.0, 0.0, False  # math.cos raises on inf; steer zeroes the row
    cos, sin = math.cos(heading), math.sin(heading)
    v = vx * cos + vy * sin
    lateral = -vx * sin + vy * cos
    w = lateral / projection_distance
    damping = 1.0
    if aim is None:
        error = math.atan2(lateral, v)
    else:
        ax, ay = aim
        ahead = ax * cos + ay * sin
        error = math.atan2(-ax * sin + ay * cos, ahead)
        ratio = v / ahead if ahead > 0.0 else 1.0
        veer = PASS_ANGLE * (
            min(max(ratio / PASS_STOPPED, 0.0), 1.0) * min(max(1.0 - ratio / PASS_BELOW, 0.0), 1.0)
        )
        if slide is not None and takes_slide_one(heading, vx, vy, aim, slide):
            sx, sy = slide
            error = math.atan2(-sx * sin + sy * cos, sx * cos + sy * sin)
            w = (-sx * sin + sy * cos) / projection_distance
        elif veer > 0.0:
            error += side * veer
            w = math.hypot(ax, ay) * math.sin(error) / projection_distance
            damping = PASS_DAMPING
    capped = False
    if hold > 0.0:
        limit = damping * (abs(error) / hold)
        if abs(w) > limit:
            capped, w = True, math.copysign(limit, w)
    half_track = 0.5 * robot.wheel_separation
    left, right = v - w * half_track, v + w * half_track
    if not (math.isfinite(left) and math.isfinite(right)):
        return 0.0, 0.0, False
    peak = max(abs(left), abs(right))
    if peak > robot.max_wheel_speed:
        scale = robot.max_wheel_speed / max(peak, 1e-300)
        left, right = left * scale, right * scale
    return left, right, capped


# Turning in place toward a direction (:func:`turn_in_place`): at most TURN_RATE (rad/s:
# rims at +-0.17 m/s on a Khepera IV), and nothing within TURN_TOLERANCE (rad).
TURN_RATE = math.pi
TURN_TOLERANCE = 0.1


def turn_in_place(
    heading: float,
    direction: float,
    hold: float,
    robot: DiffDrive = KHEPERA_IV,
    max_rate: float = TURN_RATE,
    tolerance: float = TURN_TOLERANCE,
) -> tuple[float, float]:
    """Rim speeds (left, right) m/s that turn a robot about its axle centre from
    ``heading`` toward ``direction`` (rad), the shorter way, at the heading error over
    ``hold`` (s the command stays in force if nothing follows it: the robot's command
    timeout), up to ``max_rate`` rad/s; (0, 0) within ``tolerance`` rad of it or for
    non-finite input. Held alone, the command turns the robot no further than to face
    ``direction``, however late the next one comes; sent every period, it closes the error
    by period / hold each time. The centre does not move: no one's safety is at stake."""
    if not (math.isfinite(heading) and math.isfinite(direction) and hold > 0.0):
        return 0.0, 0.0
    error = math.remainder(direction - heading, math.tau)
    if abs(error) <= tolerance:
        return 0.0, 0.0
    rate = max(-max_rate, min(max_rate, error / hold))
    rim = 0.5 * rate * robot.wheel_separation
    return -rim, rim


def twist_from_wheels(
    left: float | np.ndarray, right: float | np.ndarray, wheel_separation: float
) -> tuple[float | np.ndarray, float | np.ndarray]:
    """Differential-drive kinematics: rim speeds (m/s) -> (v m/s, omega rad/s).

    v = (left + right) / 2 along the heading, omega = (right - left) / wheel_separation
    (wheel_separation in m). Floats or arrays of one shape; arithmetic only, so the robot
    side (``integrate``, ``integrate_one``), an agent's report of its centre velocity and the
    ROS 2 bridge's Twist all use the same figures.
    """
    if not wheel_separation > 0.0:  # NaN too
        raise ValueError(f"wheel_separation must be > 0 m, got {wheel_separation!r}")
    return 0.5 * (left + right), (right - left) / wheel_separation


def integrate(
    poses: np.ndarray, wheels: np.ndarray, dt: float, robot: DiffDrive = KHEPERA_IV
) -> np.ndarray:
    """Poses after driving the wheel speeds for dt seconds.

    poses: (n, 3) [x, y, heading]; wheels: (n, 2) [left, right] m/s. Returns a new (n, 3).
    Each wheel is clamped to +-max_wheel_speed on its own, like a motor controller would;
    a non-finite wheel command counts as 0 (the robot stops rather than vanishing).
    dt: s, one for all or (n,) one per robot; ValueError unless finite and >= 0.
    """
    try:
        steps = np.asarray(dt, dtype=np.float64)
    except (TypeError, ValueError):
        steps = None
    if steps is None or isinstance(dt, str) or not (np.isfinite(steps) & (steps >= 0.0)).all():
        raise ValueError(f"dt must be a finite number of seconds >= 0, got {dt!r}")
    poses = as_rows(poses, "poses", width=3)
    wheels = as_rows(wheels, "wheels", len(poses))
    wheels = np.where(np.isfinite(wheels), wheels, 0.0)
    wheels = np.clip(wheels, -robot.max_wheel_speed, robot.max_wheel_speed)
    v, w = twist_from_wheels(wheels[:, 0], wheels[:, 1], robot.wheel_separation)
    heading = poses[:, 2]
    turn = w * dt
    # Chord of the arc: length v dt sin(turn/2)/(turn/2), direction heading + turn/2.
    # np.sinc(x) = sin(pi x)/(pi x) is exact at turn = 0, so no straight-line special case.
    chord = v * dt * np.sinc(turn / (2.0 * np.pi))
    mid = heading + 0.5 * turn
    out = np.empty_like(poses)
    out[:, 0] = poses[:, 0] + chord * np.cos(mid)
    out[:, 1] = poses[:, 1] + chord * np.sin(mid)
    out[:, 2] = (heading + turn + np.pi) % (2.0 * np.pi) - np.pi
    return out


def integrate_one(
    x: float, y: float, heading: float, left: float, right: float, dt: float,
    robot: DiffDrive = KHEPERA_IV,
) -> tuple[float, float, float]:  # fmt: skip
    """:func:`integrate` for one robot in plain floats: (x m, y m, heading rad) after
    driving rim speeds ``left``, ``right`` (m/s) for ``dt`` s, with the same clamping and
    the same arc. An agent predicts its pose along a few such segments every step, where
    numpy's per-call overhead is most of integrate's cost for a single row."""
    limit = robot.max_wheel_speed
    left = min(max(left, -limit), limit) if math.isfinite(left) else 0.0
    right = min(max(right, -limit), limit) if math.isfinite(right) else 0.0
    v, w = twist_from_wheels(left, right, robot.wheel_separation)
    turn = w * dt
    half = 0.5 * turn
    chord = v * dt * (math.sin(half) / half if half != 0.0 else 1.0)
    mid = heading + half
    return (
        x + chord * math.cos(mid),
        y + chord * math.sin(mid),
        (heading + turn + math.pi) % (2.0 * math.pi) - math.pi,
    )


def pass_sides(
    positions: np.ndarray, aims: np.ndarray, others: np.ndarray, radius: float
) -> np.ndarray:
    """(n,) the side each robot held back passes on (:func:`steer`'s ``sides``): +1 left,
    -1 right, away from the robot that holds it back: the nearest of ``others`` (m, 2) m
    within ``radius`` m ahead of it along its aim (positions, aims: (n, 2) m, m/s; a robot
    of ``others`` at its own position is itself). Left when none is ahead."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    aims = np.asarray(aims, dtype=float).reshape(-1, 2)
    others = np.asarray(others, dtype=float).reshape(-1, 2)
    sides = np.ones(len(positions))
    if len(others) == 0:
        return sides
    rel = others[None, :, :] - positions[:, None, :]  # (n, m, 2)
    d2 = np.einsum("nmk,nmk->nm", rel, rel)
    ahead = np.einsum("nmk,nk->nm", rel, aims)
    d2 = np.where((d2 > 0.0) & (d2 <= radius * radius) & (ahead > 0.0), d2, np.inf)
    nearest = np.argmin(d2, axis=1)
    rows = np.arange(len(positions))
    blocker = rel[rows, nearest]
    left = aims[:, 0] * blocker[:, 1] - aims[:, 1] * blocker[:, 0] > 0.0
    return np.where(np.isfinite(d2[rows, nearest]) & left, -1.0, 1.0)
