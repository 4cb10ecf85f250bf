"""The deploy hold (coordinator.pace, ``--deploy-error``), sans-IO: S waits at S(0) from the
mission's start until the team's e_a is low enough (or a timeout, or an operator's steering
request), then the script runs its whole duration with the exact velocities."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from live_runs import launch, new_swarm, swarm_pids

from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.coordinator import pace as pace_module
from covswarm.coordinator.config import CoordinatorConfig
from covswarm.coordinator.core import (
    DONE,
    RUNNING,
    WAITING,
    CoordinatorCore,
    CoordinatorSettings,
    PublishDomain,
    PublishStatus,
)
from covswarm.coordinator.main import coordinator_command
from covswarm.coordinator.outputs import build_summary
from covswarm.coordinator.pace import (
    DEPLOY_ALIGN,
    DEPLOY_GAIN_RAMP,
    DEPLOY_RAMP,
    PACE_FLOOR,
    Pace,
    ScriptClock,
    check_deploy_kappa,
    deploy_release,
    gain_ramp,
    hold_gain,
    pace_sentence,
    ramp_pace,
)
from covswarm.deploy.launcher import run_command
from covswarm.deploy.plan import RunConfig, agent_config, coordinator_config
from covswarm.deploy.simulate import build_summary as build_sim_summary
from covswarm.deploy.simulate import sim_command, simulate
from covswarm.mission.report import steady_state_mean
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import Domain, Pose, alive_key, pose_key
from covswarm.protocol.steering import SteerRequest
from covswarm.runtime.options import config_argv
from covswarm.tvd.control import affine_field, field_directions
from covswarm.tvd.coverage import aggregate_error, mass_centroid
from covswarm.tvd.drive import KHEPERA_IV

SWARM = "deploy-test"
WALL0 = 1.7e9
TICK = 0.05  # s: the core's broadcast period (20 Hz)


def make_core(
    deploy_error: float | None,
    timeout: float = 60.0,
    duration: float = 4.0,
    n: int = 6,
    deploy_kappa: float | None = None,
) -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=load_scenario("circle"), swarm=SWARM, agents=n, duration=duration,
        kappa=2.0, rate=1 / TICK, sample_rate=10.0, feedforward=True, tile_size=0.5,
        agent_rate=10.0, deploy_error=deploy_error, deploy_timeout=timeout,
        deploy_kappa=deploy_kappa,
    )  # fmt: skip
    core = CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)
    for i in range(n):
        for role in ("robot", "agent"):
            core.on_liveliness(alive_key(SWARM, role, i), True, 0.0, WALL0)
    return core


def lloyd(points: np.ndarray, polygon: np.ndarray, iterations: int) -> np.ndarray:
    """``iterations`` Lloyd steps (each robot to its cell's centroid) in ``polygon``."""
    for _ in range(iterations):
        points = mass_centroid(points, polygon)[1]
    return points


def start_points(core: CoordinatorCore, iterations: int) -> np.ndarray:
    """The team bunched off-centre in S(0), after ``iterations`` Lloyd steps."""
    polygon = core.settings.scenario.domain(0.0)[0]
    centre = polygon.mean(axis=0)
    rng = np.random.default_rng(3)
    points = centre + 0.05 * rng.standard_normal((core.settings.agents, 2)) + [0.15, 0.0]
    return lloyd(points, polygon, iterations)


def run(core: CoordinatorCore, points: np.ndarray, until: float, now: float = 0.0) -> tuple:
    """Tick ``core`` every TICK to ``until`` with the team standing at ``points``;
    (now, [(now, actions)])."""
    ticks = []
    while now < until - 1e-9:
        now = round(now + TICK, 9)
        for i, (x, y) in enumerate(points):
            pose = Pose(id=i, x=float(x), y=float(y), theta=0.0, stamp=WALL0 + now, seq=0)
            core.on_pose(pose_key(SWARM, i), pose.encode())
        ticks.append((now, core.tick(now, WALL0 + now)))
        if core.phase.state == DONE:
            break
    return now, ticks


def domains(ticks: list) -> list:
    return [
        (now, a.domain) for now, actions in ticks for a in actions if isinstance(a, PublishDomain)
    ]


def test_deploy_release_says_why_the_hold_ends() -> None:
    assert deploy_release(1.0, None, 0.01, 5.0) is None
    assert deploy_release(1.0, (0.9, 0.02), 0.01, 5.0) is None
    assert deploy_release(1.0, (0.9, 0.01), 0.01, 5.0) == "converged"
    assert deploy_release(5.0, (4.9, 0.02), 0.01, 5.0) == "timed out"
    assert deploy_release(5.0, None, 0.01, 5.0) == "timed out"
    assert deploy_release(1.0, (0.9, math.nan), 0.01, 5.0) is None  # NaN never converges


def test_a_held_script_waits_at_zero_then_runs_from_the_release() -> None:
    pace = Pace(asked=10.0, deploying=True)
    for t in (0.0, 0.5):
        assert pace.advance(t, []) == 0.0 and pace.pace == 0.0
    assert pace.mission_time(0.3) == math.inf  # not reached while held
    pace.release(0.9, "converged", 0.004)  # between ticks (a steering request)
    assert pace.advance(1.0, []) == 0.0  # the hold lasted to the next tick
    assert pace.released == (1.0, "converged", 0.004)  # when S started to move
    # S starts gently: the pace of each period is the ramp's at its end (0.5 s periods).
    taus, paces = [], [pace.pace]
    for t in (1.5, 2.0, 2.5, 3.0, 3.5):
        taus.append(pace.advance(t, []))
        paces.append(pace.pace)
    assert paces == pytest.approx([ramp_pace(0.5 * k) for k in range(1, 7)])
    assert paces[-2:] == [1.0, 1.0]
    assert taus == pytest.approx(np.cumsum([0.5 * p for p in paces[:5]]))
    # script_time and mission_time are inverse across the hold's end
    for tau in (0.1, 0.4, 0.5, 0.8, 1.5):
        assert pace.script_time(pace.mission_time(tau)) == pytest.approx(tau)
    assert pace.script_time(0.7) == 0.0
    summary = pace.summary({}, 3.5)
    assert summary["deploy"] == {
        "hold_s": 1.0, "released_because": "converged", "error_at_release": 0.004,
        "aligned_s": 0.0,
    }  # fmt: skip
    assert summary["pace_mean"] == pytest.approx(taus[-1] / 2.5)  # over the 2.5 s after
    assert "after a deploy hold of 1.0 s (converged)" in pace_sentence(summary)


def test_s_starts_gently_after_the_hold() -> None:
    assert ramp_pace(0.0) == PACE_FLOOR  # a valid pace from the first period
    assert ramp_pace(0.5 * DEPLOY_RAMP) == pytest.approx(0.5)
    assert ramp_pace(DEPLOY_RAMP) == ramp_pace(3 * DEPLOY_RAMP) == 1.0
    # A team that holds less than the ramp is paced by what it holds.
    pace = Pace(asked=10.0, deploying=True)
    pace.advance(0.0, [])
    pace.report(0, {"rate_hz": 3.0}, 100.0)
    pace.release(0.0, "converged", 0.01)
    pace.advance(0.5, [0])
    assert pace.pace == pytest.approx(min(ramp_pace(0.5), 0.3))
    pace.advance(1.5, [0])
    assert pace.pace == pytest.approx(0.3)


def test_without_pacing_s_reaches_full_speed_after_the_ramp() -> None:
    pace = Pace(asked=10.0, enabled=False, deploying=True)
    pace.advance(0.0, [])
    pace.release(0.0, "converged", 0.01)
    for t in (0.3, 1.0, 1.5, 1.6):  # irregular ticks: the ramp's last pace below 1
        pace.advance(t, [])
        assert pace.starting and pace.pace < 1.0
    pace.advance(2.6, [])  # 2.3 s after the hold's end
    assert pace.pace == 1.0 and not pace.starting


def test_a_script_clock_at_pace_zero_is_a_hold_and_resumes_held() -> None:
    clock = ScriptClock(3.0, 0.0, 0.0)
    assert ScriptClock.from_json(clock.to_json(SWARM), SWARM) == clock
    with pytest.raises(ValueError, match="0 only at script time 0"):
        ScriptClock(3.0, 0.5, 0.0)
    pace = Pace(asked=10.0)
    pace.resume(clock)
    assert pace.deploying
    assert pace.advance(4.0, []) == 0.0 and pace.pace == 0.0


def test_the_team_far_from_its_cvt_holds_s_still_until_it_converges(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="covswarm.coordinator")
    core = make_core(deploy_error=0.01)
    polygon0 = core.settings.scenario.domain(0.0)[0]
    bunched = start_points(core, 0)
    assert aggregate_error(bunched, polygon0) > 0.05
    now, ticks = run(core, bunched, 3.0)  # the mission starts after START_SETTLE (1.5 s)
    held = core.phase.mission_time(now)
    assert held > 1.0
    assert core.phase.state == RUNNING and core.pace.deploying
    for _, domain in domains(ticks):
        np.testing.assert_allclose(domain.vertices, polygon0, atol=1e-12)
        assert not np.any(domain.velocities)
    statuses = [a.status for _, acts in ticks for a in acts if isinstance(a, PublishStatus)]
    assert statuses[-1].pace == 0.0 and statuses[-1].script_t == 0.0
    # The team reaches S(0)'s CVT (Lloyd's iterations): the hold may end at the next
    # samples, and S holds still DEPLOY_ALIGN s more, announcing its start motion.
    settled = lloyd(bunched, polygon0, 200)
    assert aggregate_error(settled, polygon0) < 0.01
    now, ticks = run(core, settled, now + 1.0 + DEPLOY_ALIGN, now)
    assert not core.pace.deploying
    released_at, why, error = core.pace.released
    aligned_at = core.pace.aligned_from[0]
    assert why == "converged" and error <= 0.01 and held < aligned_at < held + 0.5
    assert released_at == pytest.approx(aligned_at + DEPLOY_ALIGN, abs=1e-9)
    start = core.settings.scenario.domain(0.0)[1]
    assert np.any(start)
    for _, domain in domains(ticks):
        if aligned_at - 1e-9 <= domain.t < released_at - 1e-9:
            assert not np.any(domain.velocities)
            np.testing.assert_allclose(domain.start_velocities, start, atol=1e-12)
        else:
            assert domain.start_velocities is None
    # From there S moves as the script says, with its exact velocities at the ramp's pace.
    now, more = run(core, settled, now + DEPLOY_RAMP + 0.5, now)
    after = [d for _, d in domains(ticks + more) if d.t >= released_at]
    paces = [core.pace.pace_log[core.pace.t_log.index(d.t)] for d in after]
    assert paces[0] < 0.1 and paces[-1] == 1.0 and np.all(np.diff(paces) >= 0)
    for _, domain in domains(ticks + more):
        tau = core.pace.script_time(domain.t)
        k = core.pace.t_log.index(domain.t)
        vertices, velocities = core.settings.scenario.domain(tau)
        np.testing.assert_allclose(domain.vertices, vertices, atol=1e-9)
        np.testing.assert_allclose(domain.velocities, velocities * core.pace.pace_log[k], atol=1e-9)
    # The mission lasts the hold, the ramp's lost half and the script's whole duration.
    now, ticks = run(core, settled, now + 10.0, now)
    assert core.phase.state == DONE
    # Said once, and the hold and the ramp are not taken for a team that cannot keep up.
    assert caplog.text.count("the deploy hold ends (converged") == 1
    assert "do not hold" not in caplog.text and "hold their rate again" not in caplog.text
    expected = released_at + 0.5 * DEPLOY_RAMP + 4.0
    assert core.phase.mission_time(now) == pytest.approx(expected, abs=2 * TICK)


def test_a_hold_times_out_and_the_summary_says_so() -> None:
    core = make_core(deploy_error=1e-4, timeout=1.0)
    bunched = start_points(core, 0)
    now, _ = run(core, bunched, 10.0)
    assert core.phase.state == DONE
    released_at, why, error = core.pace.released
    # Timed out at 1 s; S then held DEPLOY_ALIGN s more for the robots to face its start.
    assert why == "timed out" and core.pace.aligned_from[0] == pytest.approx(1.0, abs=TICK + 1e-9)
    assert released_at == pytest.approx(core.pace.aligned_from[0] + DEPLOY_ALIGN, abs=1e-9)
    assert error == pytest.approx(core.observed.record.error[0], rel=0.2)
    summary = build_summary(core.settings, core.observed)
    assert summary["pace"]["deploy"]["released_because"] == "timed out"
    assert summary["pace"]["deploy"]["aligned_s"] == pytest.approx(DEPLOY_ALIGN)
    t, e = np.array(core.observed.record.t), np.array(core.observed.record.error)
    scripted = t >= released_at
    expected = np.mean(e[scripted][t[scripted] >= t[scripted][0] + 0.5 * (t[-1] - t[scripted][0])])
    assert summary["steady_state_error_mean"] == pytest.approx(expected)


def test_a_steering_request_ends_the_hold() -> None:
    core = make_core(deploy_error=1e-4, timeout=30.0)
    now, _ = run(core, start_points(core, 0), 2.5)
    assert core.phase.state == RUNNING and core.pace.deploying
    request = SteerRequest(kind="translate", dx=0.1, dy=0.0, duration=2.0)
    actions = core.on_steer(request.encode(), now, WALL0 + now)
    assert actions[0].accepted
    assert core.pace.released[1] == "steered"
    # S then moves as steered from script time 0.
    now, ticks = run(core, start_points(core, 0), now + 1.0, now)
    last = domains(ticks)[-1][1]
    np.testing.assert_allclose(last.vertices, core.steering.domain(core.pace.tau)[0])
    assert np.abs(last.vertices - core.settings.scenario.domain(0.0)[0]).max() > 0.02


def test_without_a_deploy_error_there_is_no_hold() -> None:
    core = make_core(deploy_error=None)
    run(core, start_points(core, 0), 2.0)
    assert not core.pace.deploying and core.pace.released is None
    assert core.pace.tau > 0.3
    assert "deploy" not in core.pace.summary({}, 1.0)


def test_covswarm_run_passes_the_hold_to_its_coordinator() -> None:
    scenario = load_scenario("circle")
    run_config = RunConfig(swarm="s", out=Path("out"), deploy_error=0.02, deploy_timeout=30.0)
    config = coordinator_config(run_config, scenario, "tcp/127.0.0.1:1")
    assert (config.deploy_error, config.deploy_timeout) == (0.02, 30.0)
    argv = config_argv(config)
    assert argv[argv.index("--deploy-error") + 1] == "0.02"
    assert CoordinatorConfig(swarm="s", out=config.out).deploy_error is None


@pytest.mark.e2e
def test_a_live_team_spreads_over_s0_before_s_moves(tmp_path: Path) -> None:
    """5 robots over real Zenoh sessions: the agents reach S(0)'s CVT while S waits, at the
    hold's own gain (the agents take the one broadcast), then the script runs its whole
    duration (the hold measured 2.9 s for 10 robots at the scenario's gain)."""
    swarm, out = new_swarm(), tmp_path / "deploy"
    hold_args = ("--deploy-error", "0.02", "--deploy-timeout", "30", "--deploy-kappa", "6")
    team = ("--agents", "5", "--scenario", "circle", "--duration", "3")
    with launch(out, *team, *hold_args, swarm=swarm) as launcher:
        assert launcher.wait(timeout=150) == 0, (tmp_path / "deploy.launcher.log").read_text()
    summary = json.loads((out / "summary.json").read_text())
    deploy = summary["pace"]["deploy"]
    assert deploy["released_because"] == "converged", deploy
    assert deploy["kappa"] == 6.0  # the agents were broadcast the hold's gain
    assert deploy["kappa_ramp_s"] == 0.0  # below circle's 8: from the hold's start
    assert deploy["error_at_release"] <= 0.02 < 0.25 * summary["initial_error"]
    hold = deploy["hold_s"]
    assert 0.3 < hold < 30.0
    assert summary["pace"]["script_time"] == pytest.approx(3.0)
    # The script's whole 3 s after the hold, the ramp losing a second (more if the machine
    # could not hold the rate: the pace then slows the script too).
    assert summary["mission_time"] > hold + 0.5 * DEPLOY_RAMP + 3.0 - 0.3
    # S stood at S(0) through the hold, and had left it at the end.
    rows = np.loadtxt(out / "domain.csv", delimiter=",", skiprows=1)
    polygon0 = load_scenario("circle").domain(0.0)[0]
    held = rows[rows[:, 0] < hold - 0.1]
    assert len(held) >= len(polygon0)
    np.testing.assert_allclose(held[:, 2:], polygon0[held[:, 1].astype(int)], atol=1e-4)
    final = rows[rows[:, 0] == rows[-1, 0]]
    assert np.abs(final[:, 2:] - polygon0[final[:, 1].astype(int)]).max() > 0.05
    assert "after a deploy hold of" in (tmp_path / "deploy.launcher.log").read_text()
    assert swarm_pids(swarm) == set()


def test_covswarm_sim_holds_s0_as_the_coordinator_does() -> None:
    scenario = load_scenario("circle")
    common = {"agents": 6, "duration": 2.0, "dt": 0.05, "dynamics": "single", "seed": 1}
    plain = simulate(scenario, **common)
    assert plain.released is None
    # A hold the team already meets may end before the first step: S holds still
    # DEPLOY_ALIGN s more (single integrators stand still meanwhile), then starts gently.
    met = simulate(scenario, deploy_error=10.0, **common)
    assert met.released == (pytest.approx(DEPLOY_ALIGN), "converged", plain.error[0])
    aligned = round(DEPLOY_ALIGN / 0.05)
    for k in range(aligned + 1):
        np.testing.assert_array_equal(met.trajectories[k], plain.trajectories[0])
        np.testing.assert_array_equal(met.polygons[k], scenario.domain(0.0)[0])
    first = ramp_pace(0.05) * 0.05
    np.testing.assert_allclose(met.polygons[aligned + 1], scenario.domain(first)[0], atol=1e-12)
    assert met.t[-1] == pytest.approx(DEPLOY_ALIGN + 2.0 + 0.5 * DEPLOY_RAMP, abs=0.05)
    held = simulate(scenario, deploy_error=0.02, **common)
    hold, why, error = held.released
    assert why == "converged" and error <= 0.02 < plain.error[0] and hold > 0.2
    during = held.t < hold - 1e-9
    for k in np.flatnonzero(during):
        np.testing.assert_array_equal(held.polygons[k], scenario.domain(0.0)[0])
    assert held.error[during][-1] < 0.5 * held.error[0]  # the team spread over S(0)
    # Then the script's whole duration, S as scripted from tau = 0.
    assert held.t[-1] == pytest.approx(hold + 2.0 + 0.5 * DEPLOY_RAMP, abs=0.05)
    np.testing.assert_allclose(held.polygons[-1], scenario.domain(2.0)[0], atol=1e-12)
    # The last step moves S only to the script's end, and the robots with it: no jump.
    rover = simulate(scenario, agents=20, duration=8.0, dynamics="unicycle", deploy_error=0.02)
    # (measured: the last sample 0.98x the one before; 1.09x when S stopped short of it)
    assert rover.error[-1] < 1.04 * rover.error[-2]
    timed_out = simulate(scenario, deploy_error=1e-9, deploy_timeout=0.5, **common)
    assert timed_out.released[:2] == (pytest.approx(0.5 + DEPLOY_ALIGN), "timed out")
    summary = build_sim_summary(
        scenario, held, law="da", feedforward=True, kappa=scenario.kappa, dt=0.05,
        duration=2.0, seed=1, dynamics="single", deploy_error=0.02,
    )  # fmt: skip
    assert summary["deploy"]["hold_s"] == hold
    # as the run's: the hold's last DEPLOY_ALIGN s, S still for the robots to face its start
    assert summary["deploy"]["aligned_s"] == pytest.approx(DEPLOY_ALIGN, abs=0.05)
    assert timed_out.aligned_s == pytest.approx(DEPLOY_ALIGN, abs=0.05)
    scripted = held.t >= hold
    assert summary["steady_state_error_mean"] == pytest.approx(
        steady_state_mean(held.t[scripted], held.error[scripted])
    )


def test_the_hold_broadcasts_its_own_gain_then_the_missions() -> None:
    """--deploy-kappa: the Domains of the hold carry its gain, reached from the mission's
    linearly over DEPLOY_GAIN_RAMP s of mission time; those before the mission and after
    the hold carry the mission's; the summary says which gain the hold ran at and its ramp."""
    core = make_core(deploy_error=0.01, deploy_kappa=7.5)
    polygon0 = core.settings.scenario.domain(0.0)[0]
    bunched = start_points(core, 0)
    now, ticks = run(core, bunched, 3.0)
    assert core.pace.deploying
    held = [d for _, d in domains(ticks) if d.state == RUNNING]
    assert {d.kappa for _, d in domains(ticks) if d.state == WAITING} == {2.0}
    for d in held:  # the ramp, written out
        assert d.kappa == pytest.approx(2.0 + 5.5 * min(1.0, d.t / DEPLOY_GAIN_RAMP), abs=1e-12)
    assert min(d.kappa for d in held) < 2.5 and {7.5} < {d.kappa for d in held}
    assert any(2.5 < d.kappa < 7.0 for d in held)
    now, more = run(core, lloyd(bunched, polygon0, 200), now + 1.0 + DEPLOY_ALIGN, now)
    released_at = core.pace.released[0]
    gains = {d.kappa for _, d in domains(more) if d.t > released_at + 1e-9}
    assert gains == {2.0}
    assert {d.kappa for _, d in domains(more) if d.t < released_at - 1e-9} <= {7.5}
    deploy = build_summary(core.settings, core.observed)["pace"]["deploy"]
    assert deploy["kappa"] == 7.5 and deploy["kappa_ramp_s"] == DEPLOY_GAIN_RAMP
    plain = make_core(deploy_error=0.01)
    _, ticks = run(plain, bunched, 3.0)
    assert {d.kappa for _, d in domains(ticks)} == {2.0}
    deploy = build_summary(plain.settings, plain.observed)["pace"]["deploy"]
    assert deploy["kappa"] == 2.0 and deploy["kappa_ramp_s"] == 0.0


def test_the_holds_gain_ramps_up_from_the_missions_and_never_down() -> None:
    """hold_gain against the ramp written out, at random times and gains: from the mission's
    kappa at t = 0 to the hold's at DEPLOY_GAIN_RAMP, the hold's from then on; a hold's gain
    at or below the mission's holds from the start (no ramp)."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        kappa, hold = rng.uniform(0.5, 20.0, 2)
        t = rng.uniform(-1.0, 3.0 * DEPLOY_GAIN_RAMP)
        if hold > kappa:
            expected = kappa + (hold - kappa) * float(np.clip(t / DEPLOY_GAIN_RAMP, 0.0, 1.0))
            assert gain_ramp(kappa, hold) == DEPLOY_GAIN_RAMP
        else:
            expected = hold
            assert gain_ramp(kappa, hold) == 0.0
        assert hold_gain(t, kappa, hold) == pytest.approx(expected, rel=1e-12)
    assert hold_gain(0.0, 3.0, 8.0) == 3.0 and hold_gain(DEPLOY_GAIN_RAMP, 3.0, 8.0) == 8.0
    assert hold_gain(0.0, 3.0, 3.0) == 3.0 and hold_gain(0.0, 8.0, 3.0) == 3.0


def test_a_deploy_gain_needs_a_hold_and_is_positive(tmp_path: Path) -> None:
    check_deploy_kappa(None, None)
    check_deploy_kappa(0.05, None)
    check_deploy_kappa(0.05, 8.0)
    with pytest.raises(ValueError, match="needs --deploy-error"):
        check_deploy_kappa(None, 8.0)
    for bad in (0.0, -1.0, math.nan, math.inf, 1.0e4):
        with pytest.raises(ValueError, match="positive"):
            check_deploy_kappa(0.05, bad)
    scenario = load_scenario("circle")
    with pytest.raises(ValueError, match="needs --deploy-error"):
        simulate(scenario, agents=3, duration=0.1, deploy_kappa=8.0)
    config = CoordinatorConfig(swarm="s", out=tmp_path, deploy_kappa=8.0)
    with pytest.raises(ValueError, match="needs --deploy-error"):
        CoordinatorSettings.from_config(config, scenario)
    # Each command says so before it starts anything.
    for command, argv in (
        (sim_command, ["--scenario", "circle", "--agents", "3", "--out", str(tmp_path / "s")]),
        (run_command, ["--agents", "3", "--out", str(tmp_path / "r")]),
        (
            coordinator_command,
            ["--swarm", "s", "--connect", "tcp/127.0.0.1:1", "--out", str(tmp_path / "c")],
        ),
    ):
        result = CliRunner().invoke(command, [*argv, "--deploy-kappa", "8"])
        assert result.exit_code == 2 and "needs --deploy-error" in result.output, result.output
    assert not any(tmp_path.iterdir())


def test_with_a_deploy_gain_the_agents_take_the_broadcast_one() -> None:
    """covswarm run --deploy-kappa: its coordinator broadcasts the hold's gain, and its agents
    are started without a gain of their own so that they take the broadcast one."""
    scenario = load_scenario("circle")
    endpoint = "tcp/127.0.0.1:1"
    held = RunConfig(swarm="s", out=Path("out"), deploy_error=0.02, deploy_kappa=8.0)
    coordinator = coordinator_config(held, scenario, endpoint)
    argv = config_argv(coordinator)
    assert argv[argv.index("--deploy-kappa") + 1] == "8.0"
    assert argv[argv.index("--kappa") + 1] == str(scenario.kappa)
    agents = agent_config(held, scenario, endpoint, [0, 1], 0.0, True)
    assert agents.kappa is None and "--kappa" not in config_argv(agents)
    plain = RunConfig(swarm="s", out=Path("out"), deploy_error=0.02)
    assert agent_config(plain, scenario, endpoint, [0, 1], 0.0, True).kappa == scenario.kappa
    assert "--deploy-kappa" not in config_argv(coordinator_config(plain, scenario, endpoint))


def test_a_brain_without_a_gain_of_its_own_steps_with_the_broadcast_one() -> None:
    """The hold's gain reaches the law: a brain started without --kappa steps with the
    kappa of the Domain it holds; one started with it keeps its own."""
    square = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
    views = {}
    for own, broadcast in ((None, 1.0), (None, 6.0), (2.0, 6.0)):
        brain = AgentBrain(0, AgentConfig(kappa=own))
        brain.on_pose(Pose(id=0, x=0.5, y=1.0, theta=0.0, stamp=WALL0, seq=0), now=0.0)
        domain = Domain(
            seq=1, stamp=WALL0, t=0.0, state=RUNNING, vertices=square,
            velocities=[[0.0, 0.0]] * 4, kappa=broadcast,
        )  # fmt: skip
        assert brain.on_domain(domain, now=0.0)
        begun = brain.begin(0.05, WALL0 + 0.05)
        views[own, broadcast] = begun.view.kappa
    assert views == {(None, 1.0): 1.0, (None, 6.0): 6.0, (2.0, 6.0): 2.0}


def test_covswarm_sim_holds_at_the_deploy_gain_then_runs_at_the_missions(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """simulate(deploy_kappa=K): without its ramp the hold is the hold at gain K (the same
    steps, to the bit, as a run at gain K throughout), the script after it runs at the
    mission's gain; a team of 20 at a mission's gain of 2 holds 3-4x shorter at 8
    (measured over seeds 0-2: 3.9 / 6.2 / 4.1 s against 1.3 / 1.9 / 1.2 s). With it, the
    hold's first step is the mission's gain's (hold_gain at t = 0)."""
    scenario = load_scenario("circle")
    common = {"agents": 20, "duration": 1.0, "dt": 0.1, "dynamics": "unicycle", "seed": 1}
    common |= {"deploy_error": 0.03}
    ramped = simulate(scenario, kappa=2.0, deploy_kappa=8.0, **common)
    slow = simulate(scenario, kappa=2.0, **common)
    np.testing.assert_array_equal(ramped.trajectories[:2], slow.trajectories[:2])
    assert np.abs(ramped.trajectories[2] - slow.trajectories[2]).max() > 1e-6
    monkeypatch.setattr(pace_module, "DEPLOY_GAIN_RAMP", 0.0)
    held = simulate(scenario, kappa=2.0, deploy_kappa=8.0, **common)
    fast = simulate(scenario, kappa=8.0, **common)
    assert slow.released[1] == held.released[1] == "converged"
    assert held.released == fast.released and held.released[0] < 0.5 * slow.released[0]
    hold = round(held.released[0] / 0.1)
    np.testing.assert_array_equal(held.trajectories[: hold + 1], fast.trajectories[: hold + 1])
    assert np.abs(held.trajectories[hold + 2] - fast.trajectories[hold + 2]).max() > 1e-6
    same = simulate(scenario, kappa=8.0, deploy_kappa=8.0, **common)
    np.testing.assert_array_equal(same.trajectories, fast.trajectories)
    summary = build_sim_summary(
        scenario, held, law="da", feedforward=True, kappa=2.0, dt=0.1, duration=1.0, seed=1,
        dynamics="unicycle", deploy_error=0.03, deploy_kappa=8.0,
    )  # fmt: skip
    assert summary["deploy"]["kappa"] == 8.0 and summary["kappa"] == 2.0
    assert summary["deploy"]["kappa_ramp_s"] == 0.0


def test_the_holds_gain_ramp_spares_the_wheels(monkeypatch: pytest.MonkeyPatch) -> None:
    """At 4x the mission's gain at once, robots standing far from their centroids saturate
    their wheels in the hold's first second; ramped up over DEPLOY_GAIN_RAMP they barely do,
    and the hold is about as long. 20 robots, circle at kappa 2, --deploy-kappa 8, the
    safety filter on, seeds 0-7 measured (29 Nov 2026): 3.3-6.2 robot-s of saturated wheels
    at once, 0.0-0.8 ramped, at most 0.14x as much in every seed; holds 1.8-2.4 s ramped,
    1.7-2.2 s at once, at most 1.22x as long."""
    scenario = load_scenario("circle")
    common = {"agents": 20, "kappa": 2.0, "deploy_kappa": 8.0, "duration": 0.5, "dt": 0.1}
    common |= {"dynamics": "unicycle", "projection_distance": 0.05, "safety": True}
    common |= {"deploy_error": 0.05, "seed": 1}

    def hold_saturation(result) -> float:  # type: ignore[no-untyped-def]
        """Robot-s of the hold with a wheel at its limit."""
        limit = KHEPERA_IV.max_wheel_speed
        hold = result.t[: len(result.wheels)] <= result.released[0]
        peak = np.nanmax(np.abs(result.wheels[hold]), axis=2)
        return float(np.count_nonzero(peak >= limit - 1e-9) * 0.1)

    ramped = simulate(scenario, **common)
    monkeypatch.setattr(pace_module, "DEPLOY_GAIN_RAMP", 0.0)
    at_once = simulate(scenario, **common)
    assert hold_saturation(at_once) >= 2.0
    assert hold_saturation(ramped) <= 0.3 * hold_saturation(at_once)
    assert ramped.released[0] <= 1.5 * at_once.released[0]


def test_unicycles_face_s_start_before_it_moves_after_the_hold(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Once the hold may end, S holds still DEPLOY_ALIGN s while the unicycles turn in
    place to face the motion it will start with (no centre moves), so that as S starts
    they do not fall behind it while they turn: 30 robots at kappa 3, seeds 0-9 measured
    (29 Nov 2026), e_a at the release is the peak of the 3 s after it with it; without, that
    peak is 1.29-1.85x e_a at the release (seed 2: 1.84x) and the mean 1.3-2.1x (seed 2:
    1.6x)."""
    scenario = load_scenario("circle")
    common = {"agents": 30, "kappa": 3.0, "duration": 4.0, "dt": 0.1, "seed": 2}
    common |= {"dynamics": "unicycle", "deploy_error": 0.03}

    def after_release(result) -> np.ndarray:  # type: ignore[no-untyped-def]
        since = result.t - result.released[0]
        return result.error[(since >= 0.0) & (since < 3.0)]

    faced = simulate(scenario, **common)
    released = round(faced.released[0] / 0.1)
    aligned = released - round(DEPLOY_ALIGN / 0.1)
    np.testing.assert_array_equal(faced.trajectories[aligned], faced.trajectories[released])
    np.testing.assert_array_equal(faced.polygons[released], scenario.domain(0.0)[0])
    start = field_directions(affine_field(*scenario.domain(0.0)), faced.trajectories[aligned])
    off_before = np.abs(np.remainder(start - faced.headings[aligned] + np.pi, 2 * np.pi) - np.pi)
    off_after = np.abs(np.remainder(start - faced.headings[released] + np.pi, 2 * np.pi) - np.pi)
    assert off_before.mean() > 0.5 and off_after.mean() < 0.2 * off_before.mean()
    assert after_release(faced).max() <= after_release(faced)[0] * (1 + 1e-9)
    monkeypatch.setattr(pace_module, "DEPLOY_ALIGN", 0.0)
    unfaced = simulate(scenario, **common)
    assert unfaced.released[0] == pytest.approx(faced.released[0] - DEPLOY_ALIGN)
    assert after_release(unfaced).max() > 1.2 * after_release(unfaced)[0]
    assert after_release(faced).mean() < 0.85 * after_release(unfaced).mean()
