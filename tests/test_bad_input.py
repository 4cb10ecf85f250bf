"""Bad input policy: stamps, drop counting and logging, message size, duplicate robot ids."""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from live_runs import alive_tokens, open_router, wait_until
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.protocol.inbound import COMMAND_REASONS, DropLog, accept_command, check_stamp
from covswarm.sim_robot.process import RobotSim

WALL = 1.7e9
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
REPO = Path(__file__).resolve().parent.parent
COVSWARM = str(Path(sys.executable).with_name("covswarm"))


def pose(rid: int, stamp: float) -> bytes:
    return protocol.Pose(id=rid, x=0.5, y=0.5, theta=0.0, stamp=stamp, seq=0).encode()


def domain(stamp: float, seq: int = 0) -> bytes:
    return domain_message(SQUARE, seq=seq, stamp=stamp).encode()


def command(stamp: float) -> bytes:
    return protocol.WheelCommand(
        id=1, left=0.2, right=0.2, stamp=stamp, seq=0, pose_stamp=stamp
    ).encode()


# --- clock policy -----------------------------------------------------------------------


def test_stamp_policy_edges() -> None:
    check_stamp(WALL + 0.5, WALL, max_age=1.0, max_skew=0.5)
    check_stamp(WALL - 1.5, WALL, max_age=1.0, max_skew=0.5)
    with pytest.raises(protocol.ProtocolError, match="ahead") as future:
        check_stamp(WALL + 0.51, WALL, max_age=1.0, max_skew=0.5)
    assert future.value.reason == "stamp_future"
    with pytest.raises(protocol.ProtocolError, match="old") as old:
        check_stamp(WALL - 1.51, WALL, max_age=1.0, max_skew=0.5)
    assert old.value.reason == "stamp_old"


def test_accept_command_counts_each_reason_and_returns_valid_commands() -> None:
    drops = DropLog(logging.getLogger("test"), "robot 1", COMMAND_REASONS)
    accepted = accept_command(command(WALL), 1, WALL, 0.5, 0.5, drops)
    assert accepted is not None and (accepted.left, accepted.right) == (0.2, 0.2)
    assert accept_command(command(WALL), 2, WALL, 0.5, 0.5, drops) is None  # not ours
    assert accept_command(command(WALL - 1.01), 1, WALL, 0.5, 0.5, drops) is None
    assert accept_command(command(WALL + 0.51), 1, WALL, 0.5, 0.5, drops) is None
    assert accept_command(b"\xc1", 1, WALL, 0.5, 0.5, drops) is None
    nonzero = {reason: n for reason, n in drops.counts.items() if n}
    assert nonzero == {"wrong_id": 1, "stamp_old": 1, "stamp_future": 1, "undecodable": 1}


def test_a_domain_from_the_future_cannot_pin_the_agent() -> None:
    brain = AgentBrain(0)
    assert not brain.receive("domain", domain(WALL + 3600.0), 0.0, WALL)
    assert brain.receive("domain", domain(WALL), 0.0, WALL)  # accepted: not "older than held"
    assert brain.receive("domain", domain(WALL + 0.3, seq=1), 0.0, WALL)  # within the skew
    assert brain.drops.counts["stamp_future"] == 1
    assert brain.stats()["drop_stamp_future"] == 1


def test_old_or_future_own_pose_is_not_driven_on() -> None:
    brain = AgentBrain(0)
    assert brain.receive("domain", domain(WALL), 0.0, WALL)
    assert not brain.receive("pose", pose(0, WALL - 10.0), 0.0, WALL, key_id=0)
    assert not brain.receive("pose", pose(0, WALL + 10.0), 0.0, WALL, key_id=0)
    assert brain.step(0.0, WALL).reason == "no-pose"
    assert (brain.drops.counts["stamp_old"], brain.drops.counts["stamp_future"]) == (1, 1)
    assert brain.receive("pose", pose(0, WALL - 0.05), 0.0, WALL, key_id=0)
    assert brain.step(0.0, WALL).reason == "running"


def test_beacons_age_out_on_their_own_timeout() -> None:
    brain = AgentBrain(0, AgentConfig(beacon_timeout=3.0, max_clock_skew=0.5))
    beacon = protocol.Beacon(id=4, x=1.0, y=1.0, stamp=WALL - 3.2).encode()
    assert brain.receive("beacon", beacon, 0.0, WALL, key_id=4)
    beacon = protocol.Beacon(id=4, x=1.0, y=1.0, stamp=WALL - 3.6).encode()
    assert not brain.receive("beacon", beacon, 0.0, WALL, key_id=4)


def test_robot_drops_delayed_and_future_commands() -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), cmd_timeout=0.5, max_clock_skew=0.5)
    assert not sim.on_command(command(WALL - 1.2), now=0.0, now_wall=WALL)
    assert not sim.on_command(command(WALL + 1.0), now=0.0, now_wall=WALL)
    assert not sim.wheels.any()
    assert sim.drops.counts["stamp_old"] == sim.drops.counts["stamp_future"] == 1
    assert sim.on_command(command(WALL - 0.9), now=0.0, now_wall=WALL)


# --- counting and logging ---------------------------------------------------------------


def test_a_robot_placed_beyond_the_protocols_reach_is_refused_at_start() -> None:
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    RobotSim(1, (1.0e4, -1.0e4, 0.0))  # the edge is still publishable
    with pytest.raises(ValueError, match=r"\(20000, 0\) m is beyond the protocol's \+-10000 m"):
        RobotSim(1, (2.0e4, 0.0, 0.0))
    args = ["robot", "--id", "3", "--connect", "tcp/127.0.0.1:1", "--swarm", "s", "--x", "1e5"]
    done = CliRunner().invoke(main, args)
    assert done.exit_code == 2 and "beyond the protocol's" in done.output, done.output


def test_drops_are_counted_per_reason_and_logged_rate_limited(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = [0.0]
    drops = DropLog(
        logging.getLogger("test.drops"), "agent 7", ["nonfinite"], 10.0, lambda: clock[0]
    )
    with caplog.at_level(logging.WARNING, logger="test.drops"):
        for _ in range(1000):
            drops.drop("nonfinite", "pose: x: not finite (nan)")
        clock[0] = 10.5
        drops.drop("version", "pose: schema version 7, expected 1")
    assert drops.counts == {"nonfinite": 1000, "version": 1}
    assert [r.getMessage() for r in caplog.records] == [
        "agent 7 dropped input (1 nonfinite); latest: pose: x: not finite (nan)",
        "agent 7 dropped input (999 nonfinite, 1 version); latest: pose: schema version 7, "
        "expected 1",
    ]
    assert drops.summary() == "1000 nonfinite, 1 version"


def test_every_drop_reason_is_reported_in_a_sendable_agent_state() -> None:
    brain = AgentBrain(0)
    brain.receive("pose", pose(0, WALL), 0.0, WALL, key_id=0)
    stats = brain.agent_state(WALL).stats
    assert {f"drop_{r}" for r in brain_module.DROP_REASONS} <= stats.keys()
    assert len(stats) <= protocol.messages.MAX_STATS


def test_failing_control_step_logs_once_per_interval(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise ValueError("polygon is self-intersecting: edge 0 crosses edge 2")

    monkeypatch.setattr(brain_module, "local_steps", boom)
    brain = AgentBrain(0)
    brain.receive("pose", pose(0, WALL), 0.0, WALL, key_id=0)
    brain.receive("domain", domain(WALL), 0.0, WALL)
    with caplog.at_level(logging.WARNING, logger="covswarm.agent"):
        reasons = {brain.step(0.01 * k, WALL).reason for k in range(50)}
    assert reasons == {"error"} and brain.counters.step_errors == 50
    assert len(caplog.records) == 1


# --- over Zenoh ---------------------------------------------------------------------------


@pytest.fixture
def router() -> Iterator[tuple[object, str]]:
    """A router-mode session on a free loopback port: (session, endpoint)."""
    pytest.importorskip("zenoh")
    session, endpoint = open_router()
    yield session, endpoint
    session.close()


@pytest.mark.timeout(60)
@pytest.mark.e2e
def test_a_second_claim_on_an_id_is_refused(router: tuple) -> None:
    import zenoh

    from covswarm.runtime.claims import claim

    _, endpoint = router
    swarm = protocol.new_swarm_name()
    with (
        zenoh.open(protocol.session_config([endpoint])) as first,
        zenoh.open(protocol.session_config([endpoint])) as second,
    ):
        token = claim(first, swarm, "agent", 3)
        assert token is not None
        assert claim(second, swarm, "agent", 3) is None
        assert claim(second, swarm, "robot", 3) is not None  # another role: no conflict
        assert claim(second, swarm, "agent", 4) is not None  # another id: no conflict
        token.undeclare()
        time.sleep(0.2)
        assert claim(second, swarm, "agent", 3) is not None  # free again


@pytest.mark.e2e
@pytest.mark.timeout(180)
def test_second_robot_or_agent_process_with_the_same_id_is_refused(router: tuple) -> None:
    session, endpoint = router
    swarm = protocol.new_swarm_name()
    common = ["--id", "3", "--connect", endpoint, "--swarm", swarm]
    first = [subprocess.Popen([COVSWARM, role, *common], cwd=REPO) for role in ("robot", "agent")]
    try:
        deadline = time.monotonic() + 120.0
        for role in ("robot", "agent"):
            selector = protocol.claim_selector(swarm, role, 3)
            while not alive_tokens(session, selector):
                assert time.monotonic() < deadline, f"first {role} did not come up"
                assert all(p.poll() is None for p in first), "a first process exited"
                time.sleep(0.2)
        for role in ("robot", "agent"):
            second = subprocess.run(
                [COVSWARM, role, *common], cwd=REPO, capture_output=True, text=True, timeout=120
            )
            assert second.returncode == 1
            assert f"{role} 3 is already running in swarm '{swarm}'" in second.stderr
        assert all(p.poll() is None for p in first)  # the first ones keep running
    finally:
        for p in first:
            p.terminate()
        for p in first:
            p.wait(timeout=30)


@pytest.mark.timeout(60)
@pytest.mark.e2e
def test_exclusive_claims_started_together_leave_exactly_one(router: tuple) -> None:
    """Five sessions claim the coordinator's id at the same instant, ten times over: each
    time exactly one wins (claim alone may let all back off), and a later claimant loses
    to the running winner."""
    import threading

    import zenoh

    from covswarm.runtime.claims import claim_exclusive

    _, endpoint = router
    sessions = [zenoh.open(protocol.session_config([endpoint])) for _ in range(5)]
    try:
        for _ in range(10):
            swarm = protocol.new_swarm_name()
            tokens: list = [None] * len(sessions)
            start = threading.Barrier(len(sessions))

            def contend(k: int, swarm: str = swarm, start=start, tokens=tokens) -> None:
                start.wait()
                tokens[k] = claim_exclusive(sessions[k], swarm, "coordinator", 0)

            threads = [threading.Thread(target=contend, args=(k,)) for k in range(5)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            winners = [t for t in tokens if t is not None]
            assert len(winners) == 1, tokens
            assert claim_exclusive(sessions[0], swarm, "coordinator", 0) is None
            winners[0].undeclare()
    finally:
        for session in sessions:
            session.close()


@pytest.mark.timeout(120)
@pytest.mark.e2e
def test_two_coordinators_started_together_leave_exactly_one_running(
    router: tuple, tmp_path: Path
) -> None:
    _, endpoint = router
    swarm = protocol.new_swarm_name()
    coordinators = [
        subprocess.Popen(
            [COVSWARM, "coordinator", "--scenario", "passage", "--connect", endpoint,
             "--swarm", swarm, "--out", str(tmp_path / f"c{k}")],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        for k in range(2)
    ]  # fmt: skip
    try:
        assert wait_until(lambda: any(c.poll() is not None for c in coordinators), 60.0)
        time.sleep(3.0)  # the survivor is past its claim: it stays
        alive = [c for c in coordinators if c.poll() is None]
        assert len(alive) == 1
        [loser] = [c for c in coordinators if c.poll() is not None]
        assert loser.returncode != 0
        assert "already has a coordinator" in loser.stderr.read()
    finally:
        for c in coordinators:
            if c.poll() is None:
                c.kill()
            c.wait()
