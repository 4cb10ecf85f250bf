"""The simulated robot process hears the coordinator's World (pure logic, no Zenoh).

WorldHeld turns World payloads into the model World that RobotSim's contact check uses;
with it, a robot commanded into a wall stops at the contact.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from covswarm import protocol
from covswarm.sim_robot import process
from covswarm.sim_robot.process import RobotSim, WorldHeld
from covswarm.world.model import Obstacle, World, box_vertices
from covswarm.world.wire import to_message

STAMP = 1.7e9
WALL = (0.5, 0.8, -1.0, 1.0)
ARENA = World((-2.0, 2.0, -2.0, 2.0), (Obstacle("wall", box_vertices(WALL)),))


def command(left: float, right: float) -> bytes:
    return protocol.WheelCommand(
        id=1, left=left, right=right, stamp=STAMP, seq=1, pose_stamp=STAMP
    ).encode()


def test_a_robot_commanded_into_a_wall_of_the_heard_world_stops_at_contact() -> None:
    held = WorldHeld()
    assert held.on_payload(to_message(ARENA, 1, STAMP).encode(), now=0.0)
    sim = RobotSim(1, (0.0, 0.3, 0.2))
    sim.world = held.world  # what run_robots does for every robot of the process
    poses = []
    for k in range(80):  # 4 s at 20 Hz, a command every 0.1 s
        if k % 2 == 0:
            assert sim.on_command(command(0.3, 0.3), now=k * 0.05, now_wall=STAMP)
        poses.append(sim.step((k + 1) * 0.05)[:2].copy())
    wall = shapely.box(WALL[0], WALL[2], WALL[1], WALL[3])
    gaps = shapely.distance(wall, shapely.points(np.array(poses))) - 0.07
    assert gaps.min() >= -1e-9
    assert gaps[-1] == pytest.approx(0.0, abs=1e-9)  # it drove on until it rests on it
    assert sim.counters.contact_stops > 0


def test_world_payloads_newest_by_seq_repeats_and_drops() -> None:
    held = WorldHeld()
    assert not held.on_payload(b"\xc1", now=0.0)
    assert held.drops.counts["undecodable"] == 1 and held.world is None
    first = to_message(ARENA, 3, STAMP).encode()
    assert held.on_payload(first, now=0.0)
    world = held.world
    assert world is not None and world.obstacles[0].name == "wall"
    assert held.on_payload(first, now=1.0) and held.world is world  # the repeat
    empty = to_message(World((-2.0, 2.0, -2.0, 2.0)), 2, STAMP).encode()
    assert not held.on_payload(empty, now=1.5)  # older, its sender still talks
    assert held.drops.counts["old_world"] == 1 and held.world is world
    later = 1.0 + process.WORLD_RESTART_SILENCE
    assert held.on_payload(empty, now=later)  # a restarted coordinator
    assert held.world.obstacles == ()
    bad = protocol.World(seq=9, stamp=STAMP, obstacles=(((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)),))
    object.__setattr__(bad, "names", ("",))  # past the sender's checks: the wire refuses
    assert not held.on_payload(bad.encode(), now=later + 0.1)
    assert held.drops.counts["value"] == 1
    assert held.world.obstacles == ()
