"""Robots never touch a wall, end to end (issue 20 item 5): real processes over Zenoh.

The test's own session is the router and plays the coordinator: it publishes the World
(a block and the workspace) every half second and the Domain at 10 Hz. One `covswarm robot`
process simulates two robots: robot 0 has its `covswarm agent`, starts within the block's
reach with S's centroid straight through the block; robot 1 has no agent and the test drives
it into the workspace's left wall. Every pose either publishes is checked against shapely.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import threading
import time

import numpy as np
import pytest
import shapely
from live_runs import stop_children

from covswarm import protocol
from covswarm.deploy.plan import covswarm_argv
from covswarm.world.model import Obstacle, World, box_vertices
from covswarm.world.wire import to_message

RADIUS = 0.07  # m, a Khepera IV's body
WORKSPACE = (-1.5, 2.5, -2.0, 2.5)
BLOCK = (0.7, 1.3, -0.9, -0.05)
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]  # S, centroid (1, 1): beyond it
ARENA = World(WORKSPACE, (Obstacle("block", box_vertices(BLOCK)),))
STARTS = {0: (1.0, -1.1, math.pi / 2), 1: (-1.2, -1.6, math.pi)}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Trace:
    """Every pose of every robot, and the newest AgentState with stats, from callbacks."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.poses: dict[int, list[tuple[float, float]]] = {0: [], 1: []}
        self.stats: dict[str, float] = {}

    def pose(self, sample: object) -> None:
        pose = protocol.Pose.decode(sample.payload.to_bytes())
        with self.lock:
            self.poses.setdefault(pose.id, []).append((pose.x, pose.y))

    def state(self, sample: object) -> None:
        state = protocol.AgentState.decode(sample.payload.to_bytes())
        if state.stats is not None:
            with self.lock:
                self.stats = dict(state.stats)

    def of(self, rid: int) -> np.ndarray:
        with self.lock:
            return np.array(self.poses[rid], dtype=float).reshape(-1, 2)


def clearance(points: np.ndarray) -> np.ndarray:
    """m from each centre to the block or the nearest workspace wall (shapely)."""
    block = shapely.box(BLOCK[0], BLOCK[2], BLOCK[1], BLOCK[3])
    inside = shapely.box(WORKSPACE[0], WORKSPACE[2], WORKSPACE[1], WORKSPACE[3])
    pts = shapely.points(points)
    to_block = np.where(shapely.contains(block, pts), -1.0, shapely.distance(block, pts))
    to_walls = np.where(shapely.contains(inside, pts), shapely.distance(inside.exterior, pts), -1.0)
    return np.minimum(to_block, to_walls)


@pytest.mark.e2e
@pytest.mark.timeout(90)
def test_a_robot_started_within_a_walls_reach_never_touches_it() -> None:
    zenoh = pytest.importorskip("zenoh")
    swarm = protocol.new_swarm_name()
    for attempt in range(5):  # the port can be taken between probing and binding
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        try:
            session = zenoh.open(protocol.session_config(None, [endpoint], "router"))
            break
        except zenoh.ZError:
            if attempt == 4:
                raise
    children: list[subprocess.Popen] = []
    trace = Trace()
    try:
        session.declare_subscriber(protocol.all_poses_selector(swarm), trace.pose)
        session.declare_subscriber(protocol.agent_state_key(swarm, 0), trace.state)
        common = ["--connect", endpoint, "--swarm", swarm]
        poses = [arg for rid in (0, 1) for arg in ("--pose", ",".join(map(str, STARTS[rid])))]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        robots = [*covswarm_argv(), "robot", "--ids", "0-1", *poses, *common]
        children.append(subprocess.Popen(robots, env=env))
        children.append(
            subprocess.Popen([*covswarm_argv(), "agent", "--id", "0", *common], env=env)
        )
        world = to_message(ARENA, 1, time.time())
        seq = 0
        next_world = 0.0

        def broadcast(state: str, vertices: list = SQUARE) -> None:
            """One Domain (and the World when due), as the coordinator sends them."""
            nonlocal seq, next_world
            if time.monotonic() >= next_world:
                message = protocol.World(
                    seq=1, stamp=time.time(), obstacles=world.obstacles,
                    workspace=world.workspace, names=world.names,
                )  # fmt: skip
                session.put(protocol.world_key(swarm), message.encode())
                next_world = time.monotonic() + 0.5
            seq += 1
            domain = protocol.Domain(
                seq=seq, stamp=time.time(), t=0.0, state=state, vertices=vertices,
                velocities=[[0.0, 0.0]] * len(vertices), kappa=1.0,
            )  # fmt: skip
            session.put(protocol.domain_key(swarm), domain.encode())

        # Waiting until the agent reports (it hears its robot) and robot 1 publishes.
        deadline = time.monotonic() + 40.0
        while not (trace.stats and len(trace.of(1)) > 0):
            assert time.monotonic() < deadline, "the agent and robots did not come up"
            assert all(child.poll() is None for child in children), "a child exited"
            broadcast("waiting")
            time.sleep(0.1)
        # Two more World repeats: the first may have gone out before the agent listened.
        settle = time.monotonic() + 1.2
        while time.monotonic() < settle:
            broadcast("waiting")
            time.sleep(0.1)
        # One forged S over the block: the agent refuses and counts it.
        broadcast("waiting", [[0.0, -0.5], [2.0, -0.5], [2.0, 1.5], [0.0, 1.5]])
        start = time.time()
        end = time.monotonic() + 6.0
        while time.monotonic() < end:
            broadcast("running")
            wall = time.time()
            # Robot 1, without an agent: straight ahead (-x) into the workspace's left wall.
            command = protocol.WheelCommand(
                id=1, left=0.3, right=0.3, stamp=wall, seq=seq, pose_stamp=start
            )
            session.put(protocol.cmd_key(swarm, 1), command.encode())
            time.sleep(0.1)
        time.sleep(1.5)  # the last AgentState with stats
        first, second = trace.of(0), trace.of(1)
        # Robot 0 was pulled toward the block, into its reach, and never touched it.
        # (The robot process's solid walls alone would let it rest at RADIUS: the agent's
        # rows keep it a margin away.)
        assert clearance(first).min() >= RADIUS + 0.01, clearance(first).min()
        assert clearance(first).min() < clearance(first[:1])[0] - 0.05
        # Robot 1 drove into the wall and stopped at the contact.
        assert clearance(second).min() >= RADIUS - 1e-6
        assert second[-1, 0] == pytest.approx(WORKSPACE[0] + RADIUS, abs=1e-6)
        stats = trace.stats
        assert stats["drop_domain_in_obstacle"] >= 1
        assert stats["safety_active"] > 0
        assert all(stats[f"drop_{r}"] == 0 for r in ("bad_world", "old_world", "undecodable"))
    finally:
        codes = stop_children(children)
        session.close()
    assert codes == [0] * len(children), "children must exit cleanly on SIGTERM"
