"""Faults (docs/faults.md): dead brains, dead robots, joins, a dead coordinator, a dead
router, lossy links. The pure parts are unit-tested; the behaviours run as real processes
over loopback Zenoh, no mocks (helpers from test_e2e), each on its own free port and swarm.

A test process watches a run through its own Zenoh client session (``Watch``), the way an
operator would, to time when robots stop and when the others drop a dead teammate.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from live_runs import launch, new_swarm, swarm_pids, wait_until

from covswarm import protocol
from covswarm.agent.brain import AgentBrain
from covswarm.agent.faults import PoseImpairment
from covswarm.coordinator.monitor import RECOVERY_FLOOR, reconvergence, team_of
from covswarm.deploy.plan import RunConfig, covswarm_argv, plan_children
from covswarm.deploy.router import free_port
from covswarm.mission.scenario_files import load_scenario

WALL = 1.7e9


# ---------------------------------------------------------------------------- pure logic


def test_team_is_robots_whose_robot_and_agent_are_alive() -> None:
    assert team_of({"robot": {0, 1, 2}, "agent": {0, 2, 3}}) == {0, 2}
    assert team_of({"robot": {0}}) == frozenset()


def test_reconvergence_time_is_measured_from_the_change_until_e_a_holds_below_the_bound() -> None:
    t = [i * 0.1 for i in range(101)]  # 0 .. 10 s
    # Steady 0.02 before t = 4, a jump to 0.2, linear decay back to 0.02 at t = 6.
    error = [0.02 if s < 4 else max(0.02, 0.2 - 0.09 * (s - 4)) for s in t]
    result = reconvergence(t, error, 4.0)
    assert result["level_before"] == pytest.approx(0.02)
    assert result["bound"] == pytest.approx(max(RECOVERY_FLOOR, 0.03))
    # 0.2 - 0.09 s <= bound from s = 1.89 (to the next 0.1 s sample), then holds.
    assert result["reconverged_after"] == pytest.approx(1.9, abs=0.11)
    # A change too close to the end to show that e_a holds: no claim.
    assert reconvergence(t, error, 9.5)["reconverged_after"] is None
    # No samples before the change (a join at the first tick): the floor is the bound.
    assert reconvergence(t, error, 0.0)["bound"] == RECOVERY_FLOOR


def test_pose_impairment_drops_the_given_fraction_and_delays_the_rest() -> None:
    impair = PoseImpairment(0.3, 0.2, np.random.default_rng(0))
    kept = 0
    for k in range(2000):
        out = impair.filter([("pose", "p", b"x"), ("domain", "d", b"y")], now=k * 0.1)
        assert ("domain", "d", b"y") in out  # only poses are impaired
        kept += sum(1 for item in out if item[0] == "pose")
    assert impair.dropped == pytest.approx(600, rel=0.1)
    assert kept + impair.dropped + len(impair._queue) == 2000
    late = PoseImpairment(0.0, 0.25, np.random.default_rng(0))
    assert late.filter([("pose", "p", b"1")], now=1.0) == []
    assert late.filter([], now=1.2) == []
    assert late.filter([], now=1.25) == [("pose", "p", b"1")]
    with pytest.raises(ValueError):
        PoseImpairment(1.0, 0.0, np.random.default_rng(0))


def test_impairment_args_only_when_asked() -> None:
    def agent_argv(**options) -> tuple[str, ...]:
        run = RunConfig(agents=1, seed=3, swarm="s", out=Path("out"), **options)
        return plan_children(run, load_scenario("passage"), endpoint="e", base=())[-1].argv

    assert not {"--pose-loss", "--pose-delay"} & set(agent_argv())
    argv = agent_argv(pose_loss=0.3, pose_delay=0.1)
    k = argv.index("--pose-loss")
    assert argv[k : k + 6] == ("--pose-loss", "0.3", "--pose-delay", "0.1", "--pose-seed", "3")


def _brain_with_team() -> AgentBrain:
    brain = AgentBrain(0)
    square = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
    brain.on_domain(
        protocol.Domain(seq=0, stamp=WALL, t=0.0, state="waiting", vertices=square,
                        velocities=[[0.0, 0.0]] * 4, kappa=1.0),
        0.0,
    )  # fmt: skip
    brain.on_pose(protocol.Pose(id=0, x=0.0, y=0.0, theta=0.0, stamp=WALL, seq=0), 0.0)
    for rid in (1, 2):
        brain.on_pose(protocol.Pose(id=rid, x=rid, y=0.0, theta=0.0, stamp=WALL, seq=0), 0.0)
    return brain


def test_a_teammate_whose_token_vanishes_leaves_the_diagram_at_once() -> None:
    brain = _brain_with_team()
    assert set(brain.neighborhood.candidates(0.1)) == {1, 2}
    brain.on_liveliness("agent", 1, alive=False)  # robot 1 keeps publishing its pose
    brain.on_pose(protocol.Pose(id=1, x=1.0, y=0.0, theta=0.0, stamp=WALL, seq=1), 0.2)
    assert set(brain.neighborhood.candidates(0.2)) == {2}
    # A brain for 1 again (its token, or its first AgentState) brings robot 1 back.
    brain.on_liveliness("agent", 1, alive=True)
    assert set(brain.neighborhood.candidates(0.3)) == {1, 2}
    brain.on_liveliness("robot", 2, alive=False)
    brain.on_agent_state(
        protocol.AgentState(id=2, x=2.0, y=0.0, stamp=WALL, neighbors=[], stats={}), 0.4
    )
    # a brain's state does not revive its robot
    assert set(brain.neighborhood.candidates(0.4)) == {1}
    brain.on_liveliness("agent", 0, alive=False)  # our own token: ignored
    assert 0 not in brain.neighborhood.dead


def test_an_agent_without_a_fresh_own_pose_goes_quiet() -> None:
    brain = _brain_with_team()
    assert brain.pose_fresh(0.5) and brain.beacon(0.5, WALL) is not None
    assert not brain.pose_fresh(1.5)
    assert brain.beacon(2.0, WALL) is None  # due, but our position is unknown
    assert brain.step(2.0, WALL).reason == "no-pose"


# ---------------------------------------------------------------------------- real processes


class Watch:
    """A Zenoh client on a run's router recording poses, commands and agent states."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        import zenoh

        self.swarm = swarm
        self.poses: dict[int, list[tuple[float, float, float]]] = {}  # id -> [(wall, x, y)]
        self.cmds: dict[int, list[tuple[float, float, float]]] = {}  # id -> [(wall, l, r)]
        # (stamp, id, neighbours): when its agent sent it, by the stamp (the same host's
        # clock), not when this watcher's callback ran, which lags by seconds on a loaded
        # machine (a state listing a robot killed 2.0 s earlier, read in the full suite)
        self.states: list[tuple[float, int, list[int]]] = []
        self.domain_t: list[tuple[float, float, str]] = []  # (wall, mission t, state)
        self.stats: dict[int, dict] = {}  # id -> the stats of its latest AgentState with any
        self._lock = threading.Lock()
        self.session = zenoh.open(protocol.session_config([endpoint]))
        self._subs = [
            self.session.declare_subscriber(protocol.all_poses_selector(swarm), self._pose),
            self.session.declare_subscriber(protocol.all_cmds_selector(swarm), self._cmd),
            self.session.declare_subscriber(protocol.all_agent_states_selector(swarm), self._state),
            self.session.declare_subscriber(protocol.domain_key(swarm), self._domain),
        ]

    def _pose(self, sample) -> None:
        m = protocol.Pose.decode(sample.payload.to_bytes())
        with self._lock:
            self.poses.setdefault(m.id, []).append((time.time(), m.x, m.y))

    def _cmd(self, sample) -> None:
        m = protocol.WheelCommand.decode(sample.payload.to_bytes())
        with self._lock:
            self.cmds.setdefault(m.id, []).append((time.time(), m.left, m.right))

    def _state(self, sample) -> None:
        m = protocol.AgentState.decode(sample.payload.to_bytes())
        with self._lock:
            self.states.append((m.stamp, m.id, list(m.neighbors)))
            if m.stats:
                self.stats[m.id] = dict(m.stats)

    def _domain(self, sample) -> None:
        m = protocol.Domain.decode(sample.payload.to_bytes())
        with self._lock:
            self.domain_t.append((time.time(), m.t, m.state))

    def displacement(self, rid: int, start: float, end: float) -> float:
        """How far robot ``rid`` moved between two wall times (its poses in between)."""
        with self._lock:
            track = [(x, y) for w, x, y in self.poses.get(rid, []) if start <= w <= end]
        assert len(track) >= 2, f"no poses of robot {rid} in [{start}, {end}]"
        return float(np.hypot(track[-1][0] - track[0][0], track[-1][1] - track[0][1]))

    def mean_speed(self, start: float, end: float) -> float:
        """Mean over robots of the distance driven per second between two wall times."""
        with self._lock:
            ids = list(self.poses)
        return float(np.mean([self.displacement(i, start, end) for i in ids])) / (end - start)

    def closest(self, a: int, b: int) -> float:
        """Robots ``a`` and ``b``'s closest approach, m: each pose of ``a`` against the
        newest pose of ``b`` by then (inf before they were both heard)."""
        with self._lock:
            tracks = sorted([(w, 0, x, y) for w, x, y in self.poses.get(a, [])]
                            + [(w, 1, x, y) for w, x, y in self.poses.get(b, [])])  # fmt: skip
        last: list[tuple[float, float] | None] = [None, None]
        closest = math.inf
        for _, which, x, y in tracks:
            last[which] = (x, y)
            if last[0] is not None and last[1] is not None:
                closest = min(closest, math.hypot(last[0][0] - last[1][0], last[0][1] - last[1][1]))
        return closest

    def neighbor_mentions(self, dead: int) -> list[tuple[float, int]]:
        """(stamp, sender) of every AgentState of another agent that listed ``dead``."""
        with self._lock:
            return [(w, i) for w, i, nb in self.states if i != dead and dead in nb]

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.session.close()


@contextmanager
def watching(endpoint: str, swarm: str) -> Iterator[Watch]:
    watch = Watch(endpoint, swarm)
    try:
        yield watch
    finally:
        watch.close()


def mission_started(out: Path) -> float:
    """Wall time the mission started (the coordinator's mission.json), once it exists."""
    path = out / "mission.json"
    assert wait_until(path.exists, timeout=90), "the mission did not start"
    return json.loads(path.read_text())["started_wall"]


def sleep_until(wall: float) -> None:
    time.sleep(max(0.0, wall - time.time()))


@contextmanager
def router(endpoint: str) -> Iterator[subprocess.Popen]:
    """A stand-alone Zenoh router process on ``endpoint``, killed by pid on exit."""
    process = subprocess.Popen(
        [*covswarm_argv(), "router", "--listen", endpoint], stdout=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout.readline().startswith("router listening on")
        yield process
    finally:
        process.kill()
        process.wait()


@contextmanager
def processes(*argvs: tuple[str, ...], log_dir: Path) -> Iterator[list[subprocess.Popen]]:
    """Start covswarm processes (logs in ``log_dir``); SIGKILLed by pid on exit."""
    log_dir.mkdir(parents=True, exist_ok=True)
    started: list[subprocess.Popen] = []
    try:
        for k, argv in enumerate(argvs):
            with (log_dir / f"process-{k}.log").open("wb") as log:
                started.append(
                    subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL)
                )  # fmt: skip
        yield started
    finally:
        for process in started:
            if process.poll() is None:
                process.kill()
            process.wait()


@pytest.mark.e2e
def test_dead_brain_dead_robot_and_a_newcomer(tmp_path: Path) -> None:
    """5 robots on the passage: agent 3 is SIGKILLed at t = 4 s, robot 1 at t = 8 s, and a
    sixth robot + agent join at t = 12 s; the run finishes normally and re-converges each
    time.

    Every change happens while S is still or narrows slowly (until t = 17 s): from then on
    S crosses the gap at 0.16 m/s and a 4-robot team tracks it at e_a ~0.04 m, above the
    0.03 m bound, whatever its history (measured with and without faults), so a join just
    before then could not show re-convergence at all."""
    swarm, out = new_swarm(), tmp_path / "faults"
    scenario = load_scenario("passage")
    # 12 s after the newcomer starts: its imports alone take seconds on a loaded machine
    # (at load 8 it joined 1.4 s after its start and the team re-converged 2.4 s later; e_a
    # then stayed at 0.003-0.004 m from 20 s to 29 s).
    with launch(out, "--agents", "5", "--duration", "24", swarm=swarm) as launcher:
        start = mission_started(out)
        endpoint = json.loads((out / "launch.json").read_text())["endpoint"]
        with watching(endpoint, swarm) as watch:
            sleep_until(start + 4.0)
            (brain,) = swarm_pids(swarm, "agent", "--id", "3")
            os.kill(brain, signal.SIGKILL)
            killed_brain = time.time()
            sleep_until(start + 8.0)
            (robot,) = swarm_pids(swarm, "robot", "--id", "1")
            os.kill(robot, signal.SIGKILL)
            killed_robot = time.time()
            sleep_until(start + 12.0)
            # The newcomer starts near the middle of S(t), like a robot carried in by hand.
            x, y = (float(v) for v in scenario.domain(12.0)[0].mean(axis=0) + [0.05, 0.02])
            common = ("--id", "5", "--connect", endpoint, "--swarm", swarm)
            newcomer = (
                (*covswarm_argv(), "robot", *common, "--x", repr(x), "--y", repr(y)),
                (*covswarm_argv(), "agent", *common),
            )
            with processes(*newcomer, log_dir=tmp_path / "newcomer"):
                assert launcher.wait(timeout=90) == 0, (
                    tmp_path / "faults.launcher.log"
                ).read_text()
            # The brainless robot stopped within its command timeout (0.5 s) plus a pose period.
            assert watch.displacement(3, killed_brain + 0.6, killed_brain + 4.0) < 0.005
            # Robot 1's living agent commanded (0, 0) once its pose was stale (1 s).
            late = [c for c in watch.cmds[1] if killed_robot + 1.2 < c[0] < killed_robot + 4.0]
            assert late and all(left == 0.0 and right == 0.0 for _, left, right in late)
            # The newcomer never heard agent 3, whose robot stands where it stopped: it
            # followed that robot's own poses as a still row of its filter (stranded).
            assert watch.stats[5].get("stranded_followed", 0) >= 1, watch.stats[5]
            assert watch.closest(5, 3) >= 0.14  # (a body diameter)
    summary = json.loads((out / "summary.json").read_text())
    # The others dropped both from their neighbourhoods (liveliness: at once). On failure:
    # who still named them and how long after the kill, and when the coordinator saw the
    # tokens go (this failed twice in full local runs, at 1.9 and 2.1 s: the stale path).
    for dead, killed in ((3, killed_brain), (1, killed_robot)):
        late = [(round(w - killed, 2), i) for w, i in watch.neighbor_mentions(dead)]
        late = [mention for mention in late if mention[0] >= 0.5]
        assert not late, (dead, late, summary["team_changes"], summary["lost_processes"])
    changes = [(c["lost"], c["joined"]) for c in summary["team_changes"]]
    assert changes == [([3], []), ([1], []), ([], [5])], summary["team_changes"]
    for change in summary["team_changes"]:
        assert change["reconverged_after"] is not None, change
        # A newcomer joins while S narrows for the gap: 2.8-3.5 s measured on 2 cores.
        assert change["reconverged_after"] < 12.0, change
    assert summary["final_error"] < 0.05
    assert sorted(summary["agent_stats"]["per_agent"]) == ["0", "1", "2", "3", "4", "5"]
    assert {(e["role"], e["id"]) for e in summary["lost_processes"]} == {("agent", 3), ("robot", 1)}
    assert swarm_pids(swarm) == set()


@pytest.mark.e2e
def test_coordinator_restart_holds_the_team_then_resumes_the_mission(tmp_path: Path) -> None:
    """Coordinator SIGKILLed at t = 7 s (the domain is moving), restarted with --resume 5 s
    later: robots hold still meanwhile and the mission continues on the original clock."""
    swarm, out = new_swarm(), tmp_path / "coord"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = RunConfig(
        scenario="passage", agents=4, seed=0, swarm=swarm, rate=10.0, kappa=2.0,
        feedforward=True, duration=20.0, out=out,
    )  # fmt: skip
    specs = plan_children(run, load_scenario("passage"), endpoint=endpoint, base=covswarm_argv())
    coordinator_argv, team = specs[0].argv, [s.argv for s in specs[1:]]
    with router(endpoint), watching(endpoint, swarm) as watch:
        with processes(*team, log_dir=tmp_path / "team"):
            with processes(coordinator_argv, log_dir=tmp_path / "first") as (first,):
                start = mission_started(out)
                sleep_until(start + 7.0)
                first.kill()
                killed = time.time()
            moving = watch.mean_speed(killed - 2.0, killed)
            time.sleep(5.0)
            # Extrapolated for 1 s, then the domain holds still and the robots settle.
            held = watch.mean_speed(killed + 3.0, killed + 5.0)
            assert held < 0.25 * moving, (held, moving)
            with processes((*coordinator_argv, "--resume"), log_dir=tmp_path / "second") as (
                second,
            ):
                assert second.wait(timeout=60) == 0
    resumed = [(w, t) for w, t, state in watch.domain_t if w > killed + 5.0 and state == "running"]
    assert resumed, "no broadcasts after the restart"
    assert resumed[0][1] == pytest.approx(resumed[0][0] - start, abs=0.5)  # the original clock
    summary = json.loads((out / "summary.json").read_text())
    # The script's end (a team that held less than its rate would have slowed it down).
    assert summary["pace"]["script_time"] == pytest.approx(20.0)
    assert summary["mission_time"] >= 20.0 - 1e-6
    assert summary["final_error"] < 0.05
    (rejoin,) = summary["team_changes"]  # the restarted coordinator sees the team appear
    assert rejoin["joined"] == [0, 1, 2, 3] and rejoin["reconverged_after"] is not None


@pytest.mark.e2e
def test_router_restart_every_session_reconnects_and_the_run_goes_on(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "router"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with router(endpoint) as first:
        # The router is back 8 s in; the sessions reconnect and e_a is back below 0.05 m a
        # few seconds later (one run at load 10: 0.28 m at 10 s, 0.01 m at 12 s): 17 s
        # leaves that 5 s more.
        with launch(out, "--agents", "4", "--duration", "17", "--connect", endpoint,
                    swarm=swarm) as launcher:  # fmt: skip
            start = mission_started(out)
            sleep_until(start + 6.0)
            first.kill()
            first.wait()
            time.sleep(2.0)
            with router(endpoint):
                back = time.time() - start
                assert launcher.wait(timeout=90) == 0, (
                    tmp_path / "router.launcher.log"
                ).read_text()
    summary = json.loads((out / "summary.json").read_text())
    rows = [line.split(",") for line in (out / "error.csv").read_text().splitlines()[1:]]
    after = [float(e) for t, e in rows if float(t) > back + 1.5]
    assert after, "no e_a samples after the router came back"
    assert summary["final_error"] < 0.05
    assert summary["alive_at_end"] == {"agents": 4, "robots": 4}
    assert swarm_pids(swarm) == set()


@pytest.mark.e2e
def test_lossy_late_poses_keep_e_a_bounded(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "lossy"
    with launch(out, "--agents", "4", "--duration", "15", "--pose-loss", "0.3",
                swarm=swarm) as launcher:  # fmt: skip
        assert launcher.wait(timeout=120) == 0, (tmp_path / "lossy.launcher.log").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert "--pose-loss" in json.loads((out / "launch.json").read_text())["argv"][2]
    assert summary["steady_state_error_mean"] < 0.05
    assert summary["final_error"] < 0.05
