"""``covswarm sim``: the deterministic in-process simulator (no Zenoh, no processes).

Fixed-step over the whole team: at each step the domain S(t) comes from the scenario, the
centralised (TVD-C), one-hop (TVD-D1) or domain-motion feedforward (TVD-DA, the default) law
gives every robot's velocity, and robots move as single integrators or as Khepera IV
unicycles (wheel mapping + exact arc integration). Every guard and fallback the law takes is
counted (``SimResult.guarded``, ``fallbacks``) and reported in summary.json. Obstacles and
the workspace walls are solid: a robot driving into one stops at the contact
(covswarm.world.contact), counted in ``SimResult.contact_stops``.
Same seed, same options -> byte-identical summary.json and error.csv.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np

from covswarm.coordinator.config import DEPLOY_TIMEOUT
from covswarm.mission.crowding import Crowding, crowding
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import SCENARIO_HELP, Scenario, route_lines
from covswarm.protocol.keys import parse_ids
from covswarm.runtime.options import (
    agents_option,
    check_deploy_options,
    check_new_folder,
    count_option,
    default_out,
    deploy_options,
    float_option,
    kappa_option,
    law_option,
    out_option,
    refuse_unused,
)
from covswarm.tvd.control import DAMPING, LAWS, PRIORS

DYNAMICS = ("single", "unicycle")
MAX_STEPS = 1.0e7  # steps of one simulation: a day of mission at 10 ms


@dataclass(frozen=True, eq=False)
class SimResult:
    """One simulated run. T = number of samples (steps + 1, t[0] = 0), n = team size."""

    t: np.ndarray  # (T,) s
    error: np.ndarray  # (T,) e_a = ||p - c(p, t)|| in m
    trajectories: np.ndarray  # (T, n, 2)
    headings: np.ndarray  # (T, n), zeros for single integrators
    polygons: list[np.ndarray]  # T arrays (k, 2): S(t) at each sample
    positions: np.ndarray  # (n, 2) final positions
    guarded: int = 0  # robot-steps whose row the amplification guard rescaled
    fallbacks: int = 0  # steps on which the law's team-wide fallback was taken (TVD-C)
    wheels: np.ndarray | None = None  # (T, n, 2) rim speeds commanded (unicycle), NaN at the end
    safety_active: int = 0  # robot-steps on which the safety filter changed the velocity
    safety_relaxed: int = 0  # robot-steps on which it could not hold every pair (boxed in)
    contact_stops: int = 0  # robot-steps on which an obstacle or wall stopped a robot
    slid: int = 0  # robot-steps stopped dead by the filter that turned toward their slide
    # the deploy hold's end: t (s), why (coordinator.pace.deploy_release), e_a (m) then;
    # None without a hold
    released: tuple[float, str, float] | None = None
    aligned_s: float = 0.0  # s of the hold S stayed still for the robots to face its start

    @property
    def final_polygon(self) -> np.ndarray:
        return self.polygons[-1]

    @property
    def script_start(self) -> float | None:
        """t (s) S started moving after the deploy hold; None without a hold."""
        return None if self.released is None else self.released[0]


def simulate(
    scenario: Scenario,
    *,
    agents: int | None = None,
    law: str = "da",
    feedforward: bool = True,
    kappa: float | None = None,
    dt: float | None = None,
    duration: float | None = None,
    seed: int = 0,
    dynamics: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    damping: float | None = None,
    prior: str = "affine",
    projection_distance: float | None = None,
    safety: bool = False,
    heading: float | None = None,
    face_start: bool = False,
    deploy_error: float | None = None,
    deploy_timeout: float = DEPLOY_TIMEOUT,
    deploy_kappa: float | None = None,
    still: Sequence[int] = (),
) -> SimResult:
    """Run the scenario; None options take the scenario's defaults.

    heading: the unicycles' initial heading, rad, the same for every robot (None: uniform at
    random per robot, from the seed, as ``covswarm run`` places them). face_start: each
    unicycle starts facing S's motion at the start where it stands
    (covswarm.tvd.control.field_directions, its random heading where S barely moves), as
    ``covswarm run``'s robots turn to while the mission waits (covswarm.agent.brain).
    deploy_error (m), deploy_timeout (s): the deploy hold of ``covswarm run --deploy-error``
    (covswarm.coordinator.pace): S(0) held still until e_a is at most deploy_error, at most
    deploy_timeout s, then the script's whole duration (``SimResult.released``), with
    deploy_kappa (1/s; None: kappa) the gain while it holds, as the coordinator broadcasts;
    once it may end, S holds still DEPLOY_ALIGN s more while the unicycles turn in place to
    face S's start, as the agents do (covswarm.tvd.drive.turn_in_place, held for the robots'
    command timeout).

    progress(step, steps) is called after every step. damping, prior: TVD-C's (law "c";
    covswarm.tvd.control.team_step), damping None (not given) for covswarm.tvd.control.DAMPING,
    0 for the paper's exact TVD-C with its fallback to TVD-D1, as in team_step. safety:
    filter every robot's velocity as the agents do (covswarm.tvd.safety, against the robots
    within its SAFETY_RADIUS, reciprocal split with the centres' last velocities, the
    scenario's robot diameter), before the wheel mapping, with rows for the obstacles and
    walls within that radius too. Obstacles and walls are solid for every robot, filtered
    or not (covswarm.world.contact.stop_at_contacts on each step's move, the chord of a
    unicycle's arc); a run that never touches one is exactly what it was without them.

    still: indices of robots whose brains are dead: each stands where it starts, facing
    as it starts, a generator of the diagram that the law never moves (covswarm.tvd.control's
    ``still``: the others' cells end where its cell begins) and out of e_a, while the other
    robots' safety filters keep it as a still row (velocity 0), as the agents keep a
    stranded robot (covswarm.agent.brain.AgentBrain.stranded). At least one robot moves.
    """
    from covswarm.coordinator.pace import (
        aligned_by,
        check_deploy_kappa,
        deploy_release,
        hold_gain,
        paced_density,
        ramp_pace,
    )
    from covswarm.deploy.plan import COMMAND_TIMEOUT
    from covswarm.tvd import control
    from covswarm.tvd.coverage import aggregate_error
    from covswarm.tvd.drive import DEFAULT_PROJECTION_DISTANCE as DEFAULT_L
    from covswarm.tvd.drive import (
        KHEPERA_IV,
        SLIDE_AFTER,
        integrate,
        pass_sides,
        stopped_beside,
        stopped_dead,
        turn_in_place,
        twist_from_wheels,
        wheel_speeds,
    )
    from covswarm.tvd.safety import (
        DEFAULT_GAMMA,
        SAFETY_RADIUS,
        barrier_gain,
        body_safe_distance,
        team_safe_velocities,
        wall_distance,
    )
    from covswarm.world.contact import stop_at_contacts

    n = scenario.agents if agents is None else agents
    kappa = scenario.kappa if kappa is None else kappa
    dt = scenario.dt if dt is None else dt
    duration = scenario.duration if duration is None else duration
    dynamics = scenario.dynamics if dynamics is None else dynamics
    if law not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, not {law!r}")
    if dynamics not in DYNAMICS:
        raise ValueError(f"dynamics must be one of {DYNAMICS}, not {dynamics!r}")
    if n < 1 or kappa <= 0 or dt <= 0 or duration <= 0:
        raise ValueError("agents, kappa, dt and duration must be positive")
    check_steps(dt, duration)
    if damping is None:
        damping = control.DAMPING
    if not (math.isfinite(damping) and damping >= 0):
        raise ValueError(f"damping must be a finite number >= 0, not {damping!r}")

    moving = moving_robots(n, still)
    every = bool(moving.all())
    standing = None if every else ~moving  # the laws' and e_a's ``still``

    steps = max(1, round(duration / dt))
    positions = scenario.initial_positions(n, seed)
    # Headings from their own stream so positions match the single-integrator run.
    headings = np.random.default_rng([seed, 1]).uniform(-np.pi, np.pi, size=n)
    if heading is not None:
        if not math.isfinite(heading):
            raise ValueError(f"heading must be a finite angle, not {heading!r}")
        if face_start:
            raise ValueError("a heading for every robot, or each facing S's start: not both")
        headings = np.full(n, float(heading))
    # S's motion at the start, which a robot faces before it (face_start, the deploy hold's
    # end): the direction at each point, NaN where S barely moves.
    start_field = control.affine_field(*scenario.domain(0.0))
    if face_start:
        facing = control.field_directions(start_field, positions)
        headings = np.where(np.isnan(facing), headings, facing)
    if dynamics == "single":
        headings = np.zeros(n)

    # The deploy hold (coordinator.pace): S(0) still until e_a <= deploy_error, at most
    # hold_steps steps; then the script's steps. Samples are appended: the hold's length is
    # not known in advance.
    holding = deploy_error is not None
    if holding and not (math.isfinite(deploy_error) and deploy_error > 0 and deploy_timeout > 0):
        raise ValueError("deploy_error and deploy_timeout must be positive")
    check_deploy_kappa(deploy_error, deploy_kappa)
    hold_kappa = kappa if deploy_kappa is None else deploy_kappa
    hold_steps = round(deploy_timeout / dt) if holding else 0
    released: tuple[float, str, float] | None = None
    aligned: tuple[float, str, float] | None = None  # when the hold could end, why, e_a
    facing: np.ndarray | None = None  # (n,) rad: S's start motion at each robot
    t_log: list[float] = []
    error_log: list[float] = []
    trajectory_log: list[np.ndarray] = []
    heading_log: list[np.ndarray] = []
    wheel_rows: list[np.ndarray] = []
    polygons: list[np.ndarray] = []
    guarded = fallbacks = safety_active = safety_relaxed = contact_stops = slid = 0
    world = scenario.world
    walls = {
        "nearby_obstacles": world.nearby,
        "workspace": world.workspace,
        "obstacle_distance": wall_distance(scenario.robot_diameter),
    }
    centre_velocity = np.zeros((n, 2))  # the last step's, for the filter's reciprocal split
    # the side each robot aiming at its slide passes on (covswarm.agent.brain.slide_of); NaN:
    # not sliding
    slide_side = np.full(n, np.nan)
    stopped_since = np.full(n, np.inf)  # s: since when the filter stops each one dead
    safe_distance = body_safe_distance(scenario.robot_diameter)
    k = scripted = 0  # steps taken, of them the script's
    tau = 0.0
    while True:
        tk = k * dt
        if released is None:
            tau = scripted * dt
        polygon, polygon_velocity = scenario.domain(tau)
        density = scenario.density(tau)
        polygons.append(polygon)
        t_log.append(tk)
        trajectory_log.append(positions.copy())
        heading_log.append(np.array(headings, dtype=float))
        # e_a at these positions: the control step's cells give it (TeamStep.error); the
        # steps that take none tessellate for it.
        error = None
        if holding and aligned is None:
            error = aggregate_error(positions, polygon, density, standing)
            why = deploy_release(tk, (tk, error), deploy_error, hold_steps * dt)
            if why is not None:
                aligned = (tk, why, error)
                facing = control.field_directions(start_field, positions)
        if holding and aligned is not None and aligned_by(tk, aligned[0]):
            holding, released = False, (tk, aligned[1], aligned[2])
        if holding:
            pace = 0.0  # S held at S(0), as the coordinator holds it
        elif released is not None:  # S starts gently, as the coordinator starts it (ramp_pace)
            # the last step ends on the script's end: S moves only what is left of it
            pace = min(ramp_pace(tk - released[0] + dt), (duration - tau) / dt)
        else:
            pace = 1.0
        if pace < 1.0:
            polygon_velocity = polygon_velocity * pace
            density = None if density is None else paced_density(density, pace, tau)
        finished = scripted == steps if released is None else tau >= duration - 1e-9 * dt
        facing_only = holding and aligned is not None  # S still a while more: face its start
        if finished or facing_only:
            error_log.append(
                aggregate_error(positions, polygon, density, standing) if error is None else error
            )
        if finished:
            break
        if facing_only:
            if dynamics != "single":
                assert facing is not None
                pairs = zip(headings.tolist(), facing.tolist(), strict=True)
                wheels = np.array([turn_in_place(h, d, COMMAND_TIMEOUT) for h, d in pairs])
                wheels[~moving] = 0.0
                wheel_rows.append(wheels)
                poses = integrate(np.column_stack([positions, headings]), wheels, dt)
                headings = poses[:, 2]  # turning in place: the centres stay
            centre_velocity = np.zeros((n, 2))
            k += 1
            if progress is not None:
                progress(scripted, steps)
            continue
        gain = hold_gain(tk, kappa, hold_kappa) if holding else kappa
        step = control.team_step(
            law, positions, polygon, polygon_velocity, gain, feedforward=feedforward,
            density=density, damping=damping, prior=prior, still=standing,
        )  # fmt: skip
        error_log.append(step.error if error is None else error)
        velocity = aim = step.velocity
        guarded += int(step.guarded.sum())
        fallbacks += int(step.fallback)
        if not np.all(np.isfinite(velocity)):
            raise RuntimeError(f"non-finite velocity from tvd_{law} at t = {tk:.4g} s")
        filtered = functools.partial(
            team_safe_velocities, positions, gamma=barrier_gain(DEFAULT_GAMMA, dt),
            radius=SAFETY_RADIUS, velocities=centre_velocity,
        )  # fmt: skip
        if safety and np.isfinite(slide_side).any():
            # Aiming at their slides since the filter stopped them dead, until the rows
            # no longer bend their aims (covswarm.agent.brain.AgentBrain._safety_inputs).
            ids = np.flatnonzero(np.isfinite(slide_side))
            along, bent, _ = filtered(aim, safe_distance, subset=ids, **walls)
            bent_ids = ids[bent[ids] > 0]
            slide = _slides(filtered, aim, slide_side, bent_ids, safe_distance, walls, along)
            keep = np.isfinite(slide).all(axis=1)
            slide_side[~keep] = np.nan
            velocity = aim = np.where(keep[:, None], slide, aim)
            slid += int(np.count_nonzero(keep))
        if safety:
            velocity, active, relaxed = team_safe_velocities(
                positions, velocity, safe_distance, barrier_gain(DEFAULT_GAMMA, dt),
                SAFETY_RADIUS, headings=None if dynamics == "single" else headings,
                velocities=centre_velocity, **walls,
            )  # fmt: skip
            if not every:  # a dead brain's robot is nobody's to filter
                velocity = np.where(moving[:, None], velocity, 0.0)
                active, relaxed = np.where(moving, active, 0), relaxed & moving
            safety_active += int(np.count_nonzero(active))
            safety_relaxed += int(np.count_nonzero(relaxed))
        start = positions
        if dynamics == "single":
            positions = positions + dt * velocity
            centre_velocity = velocity
        else:
            # Held for a step, as an agent's command is for its period (AgentBrain._hold):
            # uncapped, a robot far from its goal at a long step spins instead of driving.
            sides = slides = None
            if safety:  # held back only by an active row; passing away from who holds it
                sides = np.ones(n)
                held = np.flatnonzero(active)
                sides[held] = pass_sides(positions[held], aim[held], positions, SAFETY_RADIUS)
                # stopped dead for SLIDE_AFTER s, or with no robot that stops it ahead of it,
                # toward the slide (covswarm.tvd.drive.steer), as an agent
                stopped = stopped_dead(headings, velocity, aim) & (active > 0) & moving
                stopped_since = np.where(stopped, np.fmin(stopped_since, tk), np.inf)
                waited = tk - stopped_since >= SLIDE_AFTER - 1e-9
                for i in np.flatnonzero(stopped & ~waited & np.isnan(slide_side)):
                    waited[i] = stopped_beside(positions[i], headings[i], positions, safe_distance)
                dead = np.flatnonzero(stopped & waited & np.isnan(slide_side))
                if len(dead):
                    slides = _slides(filtered, aim, sides, dead, safe_distance, walls)
            wheels = wheel_speeds(
                headings, velocity, projection_distance=projection_distance or DEFAULT_L,
                hold=dt, aims=aim, sides=sides, slides=slides,
            )  # fmt: skip
            wheels[~moving] = 0.0
            if slides is not None:
                taken = np.isfinite(slides).all(axis=1)
                slide_side[taken] = sides[taken]
                slid += int(np.count_nonzero(taken))
            wheel_rows.append(wheels)
            if safety:
                forward, _ = twist_from_wheels(
                    wheels[:, 0], wheels[:, 1], KHEPERA_IV.wheel_separation
                )
                centre_velocity = forward[:, None] * np.column_stack(
                    [np.cos(headings), np.sin(headings)]
                )
            poses = integrate(np.column_stack([positions, headings]), wheels, dt)
            positions, headings = poses[:, :2], poses[:, 2]
        # A robot stopped by a wall still turns (a disk turning in place moves nothing).
        positions, hit = stop_at_contacts(start, positions, 0.5 * scenario.robot_diameter, world)
        contact_stops += int(np.count_nonzero(hit))
        k += 1
        scripted += not holding
        if released is not None:
            tau = min(tau + pace * dt, duration)
        if progress is not None:
            progress(scripted, steps)
    wheel_log = None
    if dynamics == "unicycle":  # the last sample commands nothing
        wheel_log = np.concatenate(
            [np.array(wheel_rows).reshape(-1, n, 2), np.full((1, n, 2), np.nan)]
        )
    return SimResult(
        np.array(t_log), np.array(error_log), np.array(trajectory_log), np.array(heading_log),
        polygons, positions, guarded, fallbacks, wheel_log, safety_active, safety_relaxed,
        contact_stops, slid, released,
        0.0 if released is None or aligned is None else released[0] - aligned[0],
    )  # fmt: skip


def check_steps(dt: float, duration: float) -> None:
    """ValueError unless a mission of ``duration`` s takes at least one step of ``dt`` s and
    at most MAX_STEPS."""
    if dt > duration:
        raise ValueError(f"a step of {dt:g} s is longer than the mission ({duration:g} s)")
    if duration / dt > MAX_STEPS:
        raise ValueError(
            f"{duration:g} s in steps of {dt:g} s is more than {MAX_STEPS:g} steps "
            f"({duration / dt:.3g}): give a longer --dt or a shorter --duration"
        )


def robot_indices(text: str) -> tuple[int, ...]:
    """``--still``'s robot indices from "I,J,..." or ranges as ``--ids`` takes them
    (protocol.keys.parse_ids: "0-4,10"); "" for none."""
    if not text:
        return ()
    try:
        return tuple(parse_ids(text))
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


def moving_robots(n: int, still: Sequence[int]) -> np.ndarray:
    """(n,) bool: the robots of a team of ``n`` that are not in ``still`` (indices of
    robots whose brains are dead); refuses an index out of range and a team all still."""
    moving = np.ones(n, dtype=bool)
    for index in still:
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise ValueError(f"still: robot indices are integers, not {index!r}")
        if not 0 <= index < n:
            raise ValueError(f"still: robot {index} is not in a team of {n} (0 to {n - 1})")
        moving[index] = False
    if not moving.any():
        raise ValueError("still: every robot would be still; at least one must move")
    return moving


def _slides(
    filtered: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]],
    aims: np.ndarray,
    sides: np.ndarray,
    ids: np.ndarray,
    safe_distance: float,
    walls: dict[str, Any],
    along: np.ndarray | None = None,
) -> np.ndarray:
    """(n, 2) m/s: the slide each robot of ``ids`` takes, covswarm.agent.brain.slide_of for
    the team at once (``filtered``: team_safe_velocities bound to the team's positions, gain
    and velocities; ``sides`` (n,) +1 or -1; ``along``: the aims' slides at the safe
    distance on the rows of ``ids``, when already known); NaN rows for the others and where
    none is SLIDE_MIN of the aim long."""
    from covswarm.tvd.drive import SLIDE_CLEARANCE, SLIDE_MIN

    out = np.full(aims.shape, np.nan)
    least = SLIDE_MIN * np.hypot(aims[:, 0], aims[:, 1])
    turned = np.column_stack([-sides * aims[:, 1], sides * aims[:, 0]])
    wide = walls | {"obstacle_distance": walls["obstacle_distance"] + SLIDE_CLEARANCE}
    todo = np.asarray(ids, dtype=int)
    for aimed in (aims, turned):
        if not len(todo):
            break
        if aimed is turned or along is None:
            along = filtered(aimed, safe_distance, subset=todo, **walls)[0]
        long = todo[np.hypot(along[todo, 0], along[todo, 1]) >= least[todo]]
        if len(long):
            out[long] = filtered(aimed, safe_distance + SLIDE_CLEARANCE, subset=long, **wide)[0][
                long
            ]
        todo = np.setdiff1d(todo, long)
    return out


def guard_counts(result: SimResult) -> dict[str, Any]:
    """How often the law's guards acted: rows rescaled per robot-step, team fallbacks per step."""
    steps = int(result.t.size - 1)
    robot_steps = steps * int(result.positions.shape[0])
    return {
        "robot_steps": robot_steps,
        "rows_rescaled": result.guarded,
        "rows_rescaled_rate": result.guarded / max(1, robot_steps),
        "fallback_steps": result.fallbacks,
        "fallback_rate": result.fallbacks / max(1, steps),
    }


def build_summary(
    scenario: Scenario,
    result: SimResult,
    *,
    law: str,
    feedforward: bool,
    kappa: float,
    dt: float,
    duration: float,
    seed: int,
    dynamics: str,
    without: SimResult | None = None,
    damping: float | None = None,
    prior: str = "affine",
    safety: bool = False,
    projection_distance: float | None = None,
    goals: Sequence[Sequence[float]] = (),
    heading: float | None = None,
    face_start: bool = False,
    deploy_error: float | None = None,
    deploy_timeout: float = DEPLOY_TIMEOUT,
    deploy_kappa: float | None = None,
    still: Sequence[int] = (),
) -> dict[str, Any]:
    """summary.json contents: run parameters and error statistics, no timestamps; the keys
    every run has come from coordinator.outputs.mission_summary, as ``covswarm run``'s.

    goals: [(x, y), ...] m, the places S's centroid should visit in order
    (covswarm.mission.world_metrics: ``goals``, ``goals_reached``).
    """
    # Deferred: coordinator.outputs pulls in matplotlib (mission.report), which simulate()
    # alone (covswarm bench, the tests) never needs.
    from covswarm.coordinator.outputs import mission_summary
    from covswarm.coordinator.pace import gain_ramp
    from covswarm.mission.physical import wheel_figures
    from covswarm.mission.report import steady_state_mean
    from covswarm.mission.world_metrics import world_summary
    from covswarm.tvd.drive import DEFAULT_PROJECTION_DISTANCE, KHEPERA_IV

    n = int(result.positions.shape[0])
    summary: dict[str, Any] = mission_summary(
        scenario,
        law=law,
        feedforward=feedforward,
        kappa=kappa,
        duration=duration,
        dynamics=dynamics,
        t=result.t,
        error=result.error,
        final_positions=result.positions,
        final_polygon=result.final_polygon,
        trajectories=result.trajectories,
        # Without the safety filter (the default here) a crowded mission shows as
        # overlapping robots; with it, as robots held apart and off their centroids.
        crowding=crowding(scenario, n, duration),
        # Single integrators have no wheels: null, not a made-up figure.
        wheels=(
            wheel_figures(result.t, result.wheels, KHEPERA_IV.max_wheel_speed)
            if result.wheels is not None
            else dict.fromkeys(("max_wheel_speed_used", "saturated_time", "saturated_fraction"))
        ),
        script_start=result.script_start,
    )
    summary.update(
        {
            "dt": float(dt),
            "seed": int(seed),
            # m, the wheel mapping's (unicycles only)
            "projection_distance": (
                (projection_distance or DEFAULT_PROJECTION_DISTANCE)
                if dynamics == "unicycle"
                else None
            ),
            # rad, every unicycle's at the start (None: at random per robot), or "start":
            # each facing S's motion at the start
            "heading": (None if dynamics != "unicycle" else "start" if face_start else heading),
            "steps": int(result.t.size - 1),
            "guards": guard_counts(result),
            # Every step, not only the recorded ones: a touch between two frames still counts.
            **world_summary(
                result.t,
                result.trajectories,
                result.polygons,
                0.5 * scenario.robot_diameter,
                scenario.world,
                goals,
            ),
            "contact_stops": result.contact_stops,
            # robots whose brains are dead (simulate's ``still``): out of e_a, in the
            # distances between robots
            "still": sorted(int(i) for i in still),
            "safety": {
                "on": safety,
                "active_robot_steps": result.safety_active,
                "relaxed_robot_steps": result.safety_relaxed,
                "slid_robot_steps": result.slid,
            },
        }
    )
    if result.released is not None:
        hold, why, error = result.released
        hold_kappa = kappa if deploy_kappa is None else deploy_kappa
        summary["deploy"] = {
            "error": deploy_error, "timeout": deploy_timeout, "hold_s": float(hold),
            "released_because": why, "error_at_release": float(error),
            "aligned_s": float(result.aligned_s), "kappa": hold_kappa,
            "kappa_ramp_s": gain_ramp(kappa, hold_kappa),
        }  # fmt: skip
    if law == "c":
        from covswarm.tvd.control import DAMPING

        summary["damping"] = float(DAMPING if damping is None else damping)
        summary["prior"] = prior
    if without is not None:
        summary["guards_without_feedforward"] = guard_counts(without)
        ss_without = steady_state_mean(without.t, without.error)
        summary["steady_state_error_mean_without_feedforward"] = ss_without
        summary["final_error_without_feedforward"] = float(without.error[-1])
        summary["improvement"] = (ss_without - summary["steady_state_error_mean"]) / ss_without
    return summary


def physical_line(summary: dict[str, Any]) -> str:
    """The physical figures of summary.json (mission.physical) on one console line."""
    closest = summary.get("min_pairwise_distance")
    line = (f"closest robots {closest:.3f} m" if closest is not None else "closest robots -") + (
        f"; {summary['close_approaches']} close approaches (< {summary['robot_diameter']:g} m),"
        f" {summary['close_approach_time']:.1f} pair-s"
    )
    if summary.get("max_wheel_speed_used") is not None:
        line += (
            f"; wheels up to {summary['max_wheel_speed_used']:.2f} m/s,"
            f" saturated {summary['saturated_time']:.1f} robot-s"
            f" ({summary['saturated_fraction']:.1%} of commands)"
        )
    return line


@click.command("sim")
@click.option(
    "--scenario",
    "scenario_name",
    default="circle",
    show_default=True,
    help=SCENARIO_HELP,
)
@agents_option("Team size [scenario default].")
@law_option(
    "da: domain-motion feedforward (docs/tracking.md), c: centralised TVD-C, d1: one-hop TVD-D1.",
    LAWS,
)
@float_option(
    "--damping",
    low=0,
    help=f"TVD-C's feedforward damping [{DAMPING:g}]; 0: the paper's exact "
    "TVD-C, falling back to TVD-D1 when unusable.",
)
@click.option(
    "--prior",
    type=click.Choice(PRIORS),
    default="affine",
    show_default=True,
    help="What TVD-C's damped feedforward is pulled toward: S's affine field, or zero.",
)
@click.option("--no-feedforward", is_flag=True, help="Drop the dc/dt feedforward term.")
@kappa_option("Gain [scenario default].")
@float_option("--dt", low=0, low_open=True, help="Step, s [scenario default].")
@float_option("--duration", low=0, low_open=True, help="Mission length, s [scenario default].")
@count_option("--seed", default=0, low=0, help="Initial positions/headings.")
@click.option("--dynamics", type=click.Choice(DYNAMICS), help="Robot model [scenario default].")
@out_option("out_dir", help="Output folder [runs/sim-<scenario>-<timestamp>].")
@click.option("--compare", is_flag=True, help="Also run without feedforward and compare.")
@float_option(
    "--projection-distance",
    low=0,
    low_open=True,
    help="Unicycles: the wheel mapping's projection distance, m [covswarm.tvd.drive's 0.03; "
    "the agents of covswarm run use 0.05].",
)
@click.option(
    "--safety",
    is_flag=True,
    help="Filter velocities for collision avoidance as covswarm run's agents do (off here by "
    "default, as in the paper).",
)
@float_option(
    "--heading",
    help="Unicycles: every robot's initial heading, rad [uniform at random per robot, from "
    "--seed, as covswarm run places them].",
)
@click.option(
    "--face-start",
    is_flag=True,
    help="Unicycles: each robot starts facing S's motion at the start, as covswarm run's "
    "robots turn to while the mission waits.",
)
@click.option(
    "--still",
    default="",
    callback=lambda _ctx, _param, text: robot_indices(text),
    metavar="I,J,...",
    help="Robots (indices from 0, e.g. 1,4 or 0-9) whose brains are dead: they stand where "
    "they start, keep "
    "their cells (the others' end where theirs begin), out of e_a, a still obstacle for the "
    "others' --safety filters.",
)
@deploy_options(DEPLOY_TIMEOUT)
def sim_command(
    scenario_name: str,
    agents: int | None,
    law: str,
    damping: float | None,
    prior: str,
    no_feedforward: bool,
    kappa: float | None,
    dt: float | None,
    duration: float | None,
    seed: int,
    dynamics: str | None,
    out_dir: Path | None,
    compare: bool,
    projection_distance: float | None,
    safety: bool,
    heading: float | None,
    face_start: bool,
    deploy_error: float | None,
    deploy_timeout: float,
    deploy_kappa: float | None,
    still: tuple[int, ...],
) -> None:
    """Simulate coverage of a moving domain in-process and write plots and a summary."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from covswarm.coordinator.broadcastable import check_broadcastable
    from covswarm.coordinator.pace import check_deploy_kappa
    from covswarm.deploy.display import PlainLines, world_line
    from covswarm.mission.report import write_outputs
    from covswarm.mission.world_metrics import DOMAIN_FILE, write_domain_csv
    from covswarm.records.recorder import record_simulation

    if heading is not None and face_start:
        raise click.UsageError("--heading or --face-start, not both")
    if compare and no_feedforward:
        raise click.UsageError("--compare already runs without feedforward; drop --no-feedforward")
    try:
        scenario = load_scenario(scenario_name, agents)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    options = {
        "agents": scenario.agents if agents is None else agents,
        "law": law,
        "kappa": scenario.kappa if kappa is None else kappa,
        "dt": scenario.dt if dt is None else dt,
        "duration": scenario.duration if duration is None else duration,
        "seed": seed,
        "dynamics": scenario.dynamics if dynamics is None else dynamics,
        "damping": damping,
        "prior": prior,
        "safety": safety,
        "projection_distance": projection_distance,
        "heading": heading,
        "face_start": face_start,
        "deploy_error": deploy_error,
        "deploy_timeout": deploy_timeout,
        "deploy_kappa": deploy_kappa,
        "still": still,
    }
    try:
        moving_robots(options["agents"], still)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--still") from None
    try:
        check_steps(options["dt"], options["duration"])
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--dt") from None
    ctx = click.get_current_context()
    refuse_unused(ctx, ("damping", "prior"), law == "c", "--law c (TVD-C)")
    refuse_unused(
        ctx,
        ("projection_distance", "heading", "face_start"),
        options["dynamics"] == "unicycle",
        "unicycles (--dynamics unicycle, or a scenario of them)",
    )
    check_deploy_options(ctx, deploy_error)
    try:
        check_broadcastable(scenario, options["kappa"], options["duration"])
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--scenario") from None
    try:
        check_deploy_kappa(deploy_error, deploy_kappa)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    if out_dir is not None:
        check_new_folder(out_dir)  # before the simulation, which may take minutes
    runs = [not no_feedforward] + ([False] if compare else [])
    console = Console()
    for line in route_lines(scenario.motion):  # the plan, before the mission is simulated
        console.print(line, markup=False, highlight=False)
    results: list[SimResult] = []
    started, cpu_started = time.perf_counter(), time.process_time()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>5.1f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=False,
    ) as bar:
        plain = PlainLines(console)  # a pipe or a file: the bar shows nothing until the end
        for feedforward in runs:
            label = f"{scenario.name} tvd_{law} {'with' if feedforward else 'without'} dc/dt"
            task = bar.add_task(label, total=max(1, round(options["duration"] / options["dt"])))

            def report(step: int, total: int, task: Any = task, label: str = label) -> None:
                bar.update(task, completed=step)
                plain(lambda: f"{label}: step {step} of {total}")

            results.append(simulate(scenario, feedforward=feedforward, progress=report, **options))
    elapsed, cpu = time.perf_counter() - started, time.process_time() - cpu_started

    summary = build_summary(
        scenario, results[0], feedforward=runs[0], without=results[1] if compare else None,
        goals=scenario.goals,
        **{k: v for k, v in options.items() if k != "agents"},
    )  # fmt: skip
    if (crowd := Crowding.from_dict(summary["crowding"])).crowded:
        console.print(f"[yellow]warning: {crowd.warning(summary['agents'], safety=safety)}")
    if out_dir is None:
        out_dir = default_out("sim", scenario.name)
    obstacles = [o.vertices for o in scenario.world.obstacles]  # whatever their shape
    write_outputs(
        out_dir,
        summary=summary,
        t=results[0].t,
        error=results[0].error,
        trajectories=results[0].trajectories,
        polygons=results[0].polygons,
        error_compare=results[1].error if compare else None,
        obstacles=obstacles,
        workspace=scenario.workspace,
        density=scenario.density(options["duration"]),  # the script's end
        script_start=results[0].script_start,
    )
    stride = record_simulation(
        out_dir, t=results[0].t, error=results[0].error, trajectories=results[0].trajectories,
        headings=results[0].headings, polygons=results[0].polygons, dt=options["dt"],
        run_metadata={"source": "sim", "scenario": scenario.name, "feedforward": runs[0],
                      **options},
        workspace=scenario.workspace, obstacles=obstacles,
    )  # fmt: skip
    # S at the instants of trajectories.csv, to check it against the map with other tools.
    recorded = range(0, len(results[0].t), stride)
    write_domain_csv(
        out_dir / DOMAIN_FILE, results[0].t[recorded], [results[0].polygons[k] for k in recorded]
    )
    console.print(f"steady-state mean e_a: {summary['steady_state_error_mean']:.4g} m", end="")
    if compare:
        console.print(
            f", without dc/dt {summary['steady_state_error_mean_without_feedforward']:.4g} m"
            f" ({100 * summary['improvement']:.1f}% better with it)",
            end="",
        )
    console.print(
        f"\nfinal e_a {summary['final_error']:.4g} m; wall time {elapsed:.1f} s (CPU {cpu:.1f} s)"
    )
    if (deploy := summary.get("deploy")) is not None:
        console.print(
            f"deploy hold {deploy['hold_s']:.1f} s ({deploy['released_because']}, e_a "
            f"{deploy['error_at_release']:.4g} m), then the script's {options['duration']:g} s"
        )
    console.print(physical_line(summary))
    console.print(world_line(summary))
    console.print(
        f"wrote {out_dir}/ (summary.json, error.csv, error.png, trajectories.png, run.mcap, "
        "trajectories.csv, domain.csv)"
    )
