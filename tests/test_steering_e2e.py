"""Steering a running swarm end to end: real processes over loopback Zenoh, no mocks.

A ``covswarm run --scenario live`` team is steered with the Python client and with
``covswarm steer``; the test watches S on the wire (the coordinator's Domain broadcasts)
and the robots' poses, as any other process of the swarm would.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from live_runs import launch, mission_started, new_swarm, steer_cli, swarm_pids, wait_until

from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port

pytestmark = pytest.mark.e2e


class Watcher:
    """A client session that keeps the newest Domain and every robot's newest pose."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        import zenoh

        from covswarm.protocol import all_poses_selector, domain_key, session_config

        self.session = zenoh.open(session_config([endpoint]))
        self._domain = self.session.declare_subscriber(
            domain_key(swarm), zenoh.handlers.RingChannel(1)
        )
        self._poses = self.session.declare_subscriber(
            all_poses_selector(swarm), zenoh.handlers.RingChannel(256)
        )
        self.domain = None
        self.poses: dict[int, tuple[float, float]] = {}

    def poll(self):
        from covswarm.protocol import Domain, Pose

        while (sample := self._domain.try_recv()) is not None:
            self.domain = Domain.decode(sample.payload.to_bytes())
        while (sample := self._poses.try_recv()) is not None:
            pose = Pose.decode(sample.payload.to_bytes())
            self.poses[pose.id] = (pose.x, pose.y)
        return self.domain

    def vertices(self) -> np.ndarray:
        self.poll()
        return np.array(self.domain.vertices)

    def robots(self) -> np.ndarray:
        self.poll()
        return np.array([self.poses[i] for i in sorted(self.poses)])


def test_steering_moves_s_the_robots_follow_and_bad_polygons_are_refused(
    tmp_path: Path,
) -> None:
    from covswarm.coordinator.steer_client import SteeringClient
    from covswarm.tvd.coverage import aggregate_error

    swarm, out = new_swarm(), tmp_path / "live"
    args = ("--scenario", "live", "--agents", "3", "--duration", "60", "--max-domain-speed", "0.4")
    with launch(out, *args, swarm=swarm) as run:
        endpoint = mission_started(run, out)
        watcher = Watcher(endpoint, swarm)
        try:
            assert wait_until(lambda: watcher.poll() is not None and len(watcher.poses) == 3, 20)
            time.sleep(3.0)  # the team settles in the still S
            start, robots_start = watcher.vertices(), watcher.robots()
            time.sleep(1.0)
            np.testing.assert_array_equal(watcher.vertices(), start)  # live: S holds still

            reply = SteeringClient(watcher.session, swarm).translate(0.8, 0.0, duration=2.0)
            assert reply.accepted, reply.reason
            # 2 s would be too fast: stretched to the limit's 15/8 x 0.8 m / 0.4 m/s.
            assert reply.duration == pytest.approx(1.875 * 0.8 / 0.4)
            assert "stretched" in reply.reason
            assert wait_until(lambda: np.abs(watcher.poll().velocities).max() > 0.0, 2.0)
            time.sleep(reply.duration + 0.5)
            moved = watcher.vertices()
            np.testing.assert_allclose(moved, start + [0.8, 0.0], atol=1e-9)
            assert np.abs(np.array(watcher.domain.velocities)).max() == 0.0

            # The robots follow: they moved with S and cover the moved S (at a CVT of it,
            # e_a within a few cm; the team may settle into another CVT than before).
            def followed() -> bool:
                robots = watcher.robots()
                shift = robots.mean(axis=0)[0] - robots_start.mean(axis=0)[0]
                return shift > 0.6 and aggregate_error(robots, moved) < 0.03

            assert wait_until(followed, 10.0), (robots_start, watcher.robots())

            refused = steer_cli(endpoint, swarm, "--polygon", "0,0;1,0;0.2,0.2;0,1")
            assert refused.returncode == 1, refused.stderr
            assert refused.stdout.startswith("refused: non-convex"), refused.stdout
            time.sleep(0.5)
            np.testing.assert_array_equal(watcher.vertices(), moved)  # S did not move

            # (A 20 degree turn here would now be refused: S's corner would touch obstacle 2.)
            accepted = steer_cli(endpoint, swarm, "--scale", "0.9", "--duration", "3")
            assert accepted.returncode == 0 and accepted.stdout.startswith("accepted"), (
                accepted.stdout + accepted.stderr
            )
        finally:
            watcher.session.close()
        run.send_signal(signal.SIGTERM)
        assert run.wait(timeout=60) == 128 + signal.SIGTERM
    summary = json.loads((out / "summary.json").read_text())
    assert summary["max_domain_speed"] == 0.4
    records = summary["steering"]
    assert [(r["request"]["kind"], r["accepted"]) for r in records] == [
        ("translate", True),
        ("polygon", False),
        ("scale", True),
    ]
    assert records[1]["reason"].startswith("non-convex")
    assert summary["steering_refused"] == {"non-convex": 1}
    assert 0.0 < records[0]["t"] < records[1]["t"] < records[2]["t"]
    assert swarm_pids(swarm) == set()


def test_steer_without_a_coordinator_exits_non_zero(tmp_path: Path) -> None:
    import zenoh

    from covswarm.protocol import session_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(session_config(None, [endpoint], mode="router")):
        done = steer_cli(endpoint, "nobody-here", "--translate", "1,0", "--timeout", "1")
    assert done.returncode == 3
    assert "no coordinator" in done.stderr


def test_steering_a_secured_swarm_needs_the_credentials(tmp_path: Path) -> None:
    import zenoh

    from covswarm.protocol import session_config
    from covswarm.protocol.security import make_test_credentials

    secure = make_test_credentials(tmp_path / "secure")
    endpoint = f"tls/127.0.0.1:{free_port()}"
    swarm = new_swarm()
    with zenoh.open(session_config(None, [endpoint], "router", secure=secure)) as router:
        coordinator = subprocess.Popen(
            [*covswarm_argv(), "coordinator", "--connect", endpoint, "--swarm", swarm,
             "--agents", "1", "--out", str(tmp_path / "out"), "--secure", str(secure)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            from covswarm.protocol import alive_key

            assert wait_until(
                lambda: any(
                    r.ok is not None
                    for r in router.liveliness().get(alive_key(swarm, "coordinator", 0))
                ),
                60,
            )
            # With the credentials the request reaches the coordinator, which is still
            # waiting for its team and says so; without them nothing gets through.
            member = steer_cli(endpoint, swarm, "--translate", "1,0", "--secure", str(secure))
            assert member.returncode == 1 and member.stdout.startswith("refused: not-running")
            outsider = steer_cli(endpoint, swarm, "--translate", "1,0")
            assert outsider.returncode == 2 and "needs --secure" in outsider.stderr
        finally:
            coordinator.send_signal(signal.SIGTERM)
            coordinator.wait(timeout=30)
