"""The simulated robot process treats a world's obstacles and walls as solid."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from covswarm import protocol
from covswarm.sim_robot.process import RobotSim
from covswarm.world.model import Obstacle, World, box_vertices

WALL = (0.5, 0.8, -1.0, 1.0)
STAMP = 1.7e9


def command(left: float, right: float) -> bytes:
    return protocol.WheelCommand(
        id=1, left=left, right=right, stamp=STAMP, seq=1, pose_stamp=STAMP
    ).encode()


def drive(
    sim: RobotSim, left: float, right: float, seconds: float, start: float = 0.0
) -> list[np.ndarray]:
    """From ``start`` s, commands refreshed every 0.1 s, steps every 0.05 s; the poses after
    each step."""
    poses = []
    for k in range(round(seconds / 0.05)):
        if k % 2 == 0:
            assert sim.on_command(command(left, right), now=start + k * 0.05, now_wall=STAMP)
        poses.append(sim.step(start + (k + 1) * 0.05).copy())
    return poses


@pytest.mark.parametrize("heading", [0.0, 0.3, -0.6])
def test_robot_driving_into_an_obstacle_stops_at_the_contact(heading: float) -> None:
    world = World((-2.0, 2.0, -2.0, 2.0), (Obstacle("wall", box_vertices(WALL)),))
    sim = RobotSim(1, (0.0, 0.0, heading), world=world)
    poses = np.array(drive(sim, 0.3, 0.3, 4.0))
    wall = shapely.box(WALL[0], WALL[2], WALL[1], WALL[3])
    gaps = shapely.distance(wall, shapely.points(poses[:, :2])) - 0.07
    assert gaps.min() >= -1e-9
    assert gaps[-1] == pytest.approx(0.0, abs=1e-9)  # resting against it
    assert sim.counters.contact_stops > 0
    # Turning in place at the wall is free, and so is driving away from it.
    drive(sim, -0.2, 0.2, 0.5, start=4.0)
    assert sim.pose[2] != pytest.approx(poses[-1, 2])
    np.testing.assert_array_equal(sim.pose[:2], poses[-1, :2])
    before = sim.pose[:2].copy()
    away = -0.3 if np.cos(sim.pose[2]) > 0.0 else 0.3  # wheels that drive it toward -x
    drive(sim, away, away, 1.0, start=4.5)
    assert before[0] - sim.pose[0] > 0.05


def test_workspace_walls_are_solid_and_no_world_is_an_open_floor() -> None:
    walled = RobotSim(1, (0.0, 0.0, 0.0), world=World((-1.0, 1.0, -1.0, 1.0)))
    drive(walled, 0.3, 0.3, 5.0)
    assert walled.pose[0] == pytest.approx(1.0 - 0.07)
    open_floor = RobotSim(1, (0.0, 0.0, 0.0))
    drive(open_floor, 0.3, 0.3, 5.0)
    assert open_floor.pose[0] == pytest.approx(1.5)
    assert open_floor.counters.contact_stops == 0
