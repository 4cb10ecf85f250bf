"""The arena end to end: real processes over loopback Zenoh, no mocks.

``covswarm run --scenario warehouse`` (6 robots, 3 per process: the machine is shared): a
client that joins after the start receives the World within a second or so; a request
straight through the dividing wall is refused ``obstacle`` naming the wall; ``covswarm steer
--goto`` is accepted with its route, S arrives at the goal, no robot body touches an
obstacle or wall (every pose seen is checked), and e_a is back under 2 cm once S stops.
"""

from __future__ import annotations

import json
import math
import re
import signal
from pathlib import Path

import numpy as np
import pytest
from live_runs import launch, mission_started, new_swarm, steer_cli, swarm_pids, wait_until

pytestmark = pytest.mark.e2e

RADIUS = 0.07  # m, a Khepera IV's body
GOAL = (-2.4, -0.5)  # m, in the warehouse's left room


class Watcher:
    """A late-joining client: the newest Domain and World, every robot's newest pose, and
    the smallest body clearance to the arena of every pose received."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        import zenoh

        from covswarm.protocol import all_poses_selector, domain_key, session_config, world_key

        self.session = zenoh.open(session_config([endpoint]))
        ring = zenoh.handlers.RingChannel
        self._domain = self.session.declare_subscriber(domain_key(swarm), ring(1))
        self._world = self.session.declare_subscriber(world_key(swarm), ring(1))
        self._poses = self.session.declare_subscriber(all_poses_selector(swarm), ring(512))
        self.domain = self.world = self.arena = None
        self.poses: dict[int, tuple[float, float]] = {}
        self.clearance = math.inf  # m, body edge to the nearest obstacle or wall

    def poll(self) -> None:
        from covswarm.protocol import Domain, Pose, World
        from covswarm.world.wire import from_message

        while (sample := self._domain.try_recv()) is not None:
            self.domain = Domain.decode(sample.payload.to_bytes())
        while (sample := self._world.try_recv()) is not None:
            self.world = World.decode(sample.payload.to_bytes())
            self.arena = from_message(self.world)
        while (sample := self._poses.try_recv()) is not None:
            pose = Pose.decode(sample.payload.to_bytes())
            self.poses[pose.id] = (pose.x, pose.y)
            if self.arena is not None:
                gap = float(self.arena.clearance(np.array([[pose.x, pose.y]]))[0]) - RADIUS
                self.clearance = min(self.clearance, gap)

    def stopped_at(self, goal: tuple[float, float]) -> bool:
        from covswarm.world.route import centroid

        self.poll()
        vertices = np.array(self.domain.vertices)
        return (
            np.abs(np.array(self.domain.velocities)).max() == 0.0
            and np.linalg.norm(centroid(vertices) - goal) < 1e-3
        )

    def error(self) -> float:
        from covswarm.tvd.coverage import aggregate_error

        self.poll()
        robots = np.array([self.poses[i] for i in sorted(self.poses)])
        return aggregate_error(robots, np.array(self.domain.vertices))


def test_warehouse_world_goto_and_a_wall(tmp_path: Path) -> None:
    swarm, out = new_swarm(), tmp_path / "warehouse"
    args = ("--scenario", "warehouse", "--agents", "6", "--agents-per-process", "3",
            "--duration", "120")  # fmt: skip
    with launch(out, *args, swarm=swarm) as run:
        endpoint = mission_started(run, out)
        watcher = Watcher(endpoint, swarm)  # joins after the start
        try:
            assert wait_until(lambda: watcher.poll() or watcher.world is not None, 3.0)
            names = list(watcher.world.names)
            assert names[:3] == ["wall south", "wall north", "shelf 1"]
            assert watcher.world.workspace == (-4.0, 4.0, -2.5, 2.5)

            # Straight east through the dividing wall (S is in the left room).
            wall = steer_cli(endpoint, swarm, "--translate", "5,0")
            assert wall.returncode == 1, wall.stdout + wall.stderr
            assert wall.stdout.startswith("refused: obstacle: S would touch obstacle 'wall "), (
                wall.stdout
            )

            goto = steer_cli(endpoint, swarm, "--goto", f"{GOAL[0]},{GOAL[1]}")
            assert goto.returncode == 0, goto.stdout + goto.stderr
            assert goto.stdout.startswith(f"accepted: goto ({GOAL[0]:g}, {GOAL[1]:g})")
            assert "route: (" in goto.stdout
            duration = float(re.search(r"\), ([0-9.]+) s", goto.stdout)[1])
            assert wait_until(lambda: watcher.stopped_at(GOAL), duration + 5.0)
            # The team covers the S it stopped in: e_a under 2 cm.
            assert wait_until(lambda: watcher.error() < 0.02, 30.0), watcher.error()
            watcher.poll()
            assert len(watcher.poses) == 6
            assert watcher.clearance > 1e-3, watcher.clearance  # no body touched anything
        finally:
            watcher.session.close()
        run.send_signal(signal.SIGTERM)
        assert run.wait(timeout=60) == 128 + signal.SIGTERM
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steering_refused"] == {"obstacle": 1}
    assert summary["obstacle_contacts"] == 0 and summary["min_obstacle_clearance"] > 1e-3
    assert summary["domain_obstacle_overlap"] == 0.0
    assert summary["goal_list"][-1] == list(GOAL) and summary["goal_times"][-1] is not None
    assert summary["unexpected"]["total"] == 0
    rows = np.loadtxt(out / "domain.csv", delimiter=",", skiprows=1)
    assert rows.shape[1] == 4 and len(rows) > 100
    # The README's resume files: the accepted goto journaled (the refused request is not),
    # beside the mission's start and the script's clock.
    journal = (out / "steering.jsonl").read_text().splitlines()
    assert [json.loads(line)["request"]["goal"] for line in journal] == [list(GOAL)]
    for name in ("mission.json", "script.json"):
        assert json.loads((out / name).read_text())["swarm"] == swarm, name
    # The planned route, said before the mission (the log is a file: logged once).
    assert "route to goal (2.7, 0.1): " in (out.parent / "warehouse.launcher.log").read_text()
    assert swarm_pids(swarm) == set()
