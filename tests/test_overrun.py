"""A late brain's command driven past the hold it was computed for, to its robot's command
timeout (covswarm.deploy.netsim and scripts/overloaded_start.py: brains stepped every
0.45-1.15 s, robots stopping 1 s after a command, each command driven until the next or the
timeout). Its expected hold is the last gap between its turns; past ARC_HOLD its turn is
capped over the timeout, so the robot turns no further than its aim however long it drives
(AgentBrain._wheels), and the barrier's gain is sampled over the timeout on the rows of the
robots the command so driven would bring it within the safe distance of
(covswarm.agent.brain.filter_all). A brain whose process stops its robot earlier (a pack:
at the command's hold) plans for that instead (AgentBrain.may_drive). One brain stepped
twice ``gap`` apart, robot 1 standing still where robot 0 knows it, robot 0 driving its
command for the whole timeout."""

from __future__ import annotations

import math

import numpy as np
import pytest
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent import brain as brain_module
from covswarm.agent.brain import AgentBrain, AgentConfig, Filtering, overrun_rows
from covswarm.agent.pack import LocalBus, Pack
from covswarm.tvd.drive import KHEPERA_IV, integrate_one
from covswarm.tvd.safety import body_safe_distance

WALL = 1.7e9
START = (-0.2, 0.0)  # m: robot 0
# S 2.2 m to robot 0's right, robot 1 nearer it: robot 0's cell is empty, and it aims at S's
# centroid, along +x.
FAR_SQUARE = [[2.0, -1.0], [4.0, -1.0], [4.0, 1.0], [2.0, 1.0]]
SAFE = body_safe_distance(KHEPERA_IV.body_diameter, AgentConfig().safety_margin)  # 0.16 m


def drive_late(
    gap: float,
    heading: float,
    neighbour: tuple[float, float],
    timeout: float = 1.0,
    stop_after: float | None = None,
) -> tuple[AgentBrain, list[tuple[float, float, float]]]:
    """Brain 0 (its process stopping its robot ``stop_after`` s after a step: AgentBrain.
    stop_after) stepped twice ``gap`` s apart with its robot at START facing ``heading`` rad
    and robot 1 still at ``neighbour``; the poses (x, y, heading) of robot 0 driving the
    second command for ``timeout`` s, 10 ms apart."""
    brain = AgentBrain(0, AgentConfig(kappa=1.0, cmd_timeout=timeout))
    brain.stop_after = stop_after
    for k, t in enumerate((0.0, gap)):
        domain = domain_message(FAR_SQUARE, seq=k + 1, stamp=WALL + t)
        brain.receive("domain", domain.encode(), t, WALL + t)
        pose = protocol.Pose(id=0, x=START[0], y=START[1], theta=heading, stamp=WALL + t, seq=k)
        brain.receive("pose", pose.encode(), t, WALL + t, key_id=0)
        still = protocol.AgentState(1, neighbour[0], neighbour[1], WALL + t, neighbors=(0,))
        brain.receive("state", still.encode(), t, WALL + t, key_id=1)
        brain.pace(gap)
        decision = brain.step(t, WALL + t)
    assert decision.reason == "running" and brain.counters.arc_turned == 0
    path = [(*START, heading)]
    for _ in range(round(timeout / 0.01)):
        path.append(integrate_one(*path[-1], decision.left, decision.right, 0.01, KHEPERA_IV))
    return brain, path


def closest(path: list[tuple[float, float, float]], neighbour: tuple[float, float]) -> float:
    return min(math.hypot(x - neighbour[0], y - neighbour[1]) for x, y, _ in path)


def test_a_command_driven_to_the_timeout_turns_no_further_than_its_aim() -> None:
    # Robot 0 faces 0.5 rad to the right of its aim, robot 1 0.205 m away ahead on its left.
    # Capped to face its aim in the 0.55 s expected, the turn went on for the rest of the
    # 1 s the robot drove: 0.41 rad past its aim, towards robot 1, to 0.147 m of it (0.176
    # m when the command stopped at 0.55 s). As netsim circle-400 seed 1's robots 46 and
    # 396 (0.1386 m, docs/scaling.md).
    neighbour = (-0.05, 0.14)
    brain, path = drive_late(0.55, -0.5, neighbour)
    assert closest(path, neighbour) >= SAFE
    assert max(heading for _, _, heading in path) <= 1e-9  # towards the aim (0), not past it


def test_at_ten_hertz_the_turn_stays_capped_for_the_period() -> None:
    # Under ARC_HOLD a command is not expected to outlast its period: its turn is sized for
    # 0.1 s, and held a whole second it would turn the robot past its aim, as before.
    brain, path = drive_late(0.1, -0.5, (-0.05, 0.14))
    assert brain.command_hold < brain_module.ARC_HOLD
    assert max(heading for _, _, heading in path) > 0.1
    assert brain.counters.overrun_gained == 0


@pytest.mark.parametrize(("heading", "ahead"), [(0.0, 0.05), (0.0, 0.1), (0.2, 0.05)])
def test_a_command_driven_to_the_timeout_keeps_the_safe_distance(
    heading: float, ahead: float
) -> None:
    # Robot 1 stands 0.25-0.3 m ahead of robot 0, which drives at it. Filtered with the gain
    # sampled for the 0.5 s expected (2/s: the margin to the safe distance may all go in
    # 0.5 s), the robot drove 1 s: to 0.138-0.139 m. As netsim circle-1000 seed 3's robots
    # 975 and 894 once the turn was capped over the timeout (0.139 m). Sampled over the
    # timeout on that one row, it stays 0.16 m away.
    neighbour = (ahead, 0.0)
    brain, path = drive_late(0.5, heading, neighbour)
    assert closest(path, neighbour) >= SAFE
    assert brain.counters.overrun_gained == 1


def test_a_packed_brain_plans_its_command_for_when_its_process_stops_the_robot() -> None:
    # A pack stops a late brain's robot once its last step is older than hold_after and
    # than the command's hold (Pack._hold): stepped every 0.55 s, at 0.55 s. The command is
    # planned for that, as before: the turn faces the aim by then, the gain is the hold's.
    brain = AgentBrain(0, AgentConfig())
    Pack(LocalBus(), "s", [brain], hold_after=0.3)
    assert brain.stop_after == 0.3
    neighbour = (0.05, 0.0)
    brain, path = drive_late(0.55, -0.5, neighbour, stop_after=0.3)
    assert brain.may_drive == pytest.approx(0.55, rel=1e-6)
    stopped = path[:56]  # to 0.55 s
    assert closest(stopped, neighbour) >= SAFE
    assert max(heading for _, _, heading in stopped) == pytest.approx(0.0, abs=0.02)
    assert brain.counters.overrun_gained == 0
    # Stopped at the robot's timeout (hold_after over it), it is planned for the timeout.
    brain, _ = drive_late(0.55, -0.5, neighbour, stop_after=2.0)
    assert brain.may_drive == 1.0


def test_only_the_rows_the_command_would_bring_within_the_safe_distance_change() -> None:
    # Robot 0 at the origin facing +x, aiming at +y, 0.1 m/s for 1 s, the safe distance
    # 0.16 m. Robot 1 0.25 m ahead: reached to 0.15 m. Robot 2 0.3 m ahead, driving away as
    # fast; robot 3 0.2 m to the right, robot 4 0.25 m behind: not. Robot 5 0.25 m along
    # its aim, where the command turns it: reached to 0.15 m. Robot 6 already inside the
    # safe distance (a smaller gain would ask less of it).
    near = np.array(
        [
            [0.25, 0.0, 0.0, 0.0],
            [0.3, 0.0, 0.1, 0.0],
            [0.0, -0.2, 0.0, 0.0],
            [-0.25, 0.0, 0.0, 0.0],
            [0.0, 0.25, 0.0, 0.0],
            [0.15, 0.0, 0.0, 0.0],
        ]
    )
    filtering = Filtering(
        begun=brain_module.Begun(None, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0),  # type: ignore[arg-type]
        nominal=np.array([0.0, 0.1]), near=near, safe_distance=0.16, gamma=2.0,
        velocity=(0.1, 0.0), obstacles=[], workspace=None, obstacle_distance=0.0,
        obstacle_gamma=1.0, overrun=1.0,
    )  # fmt: skip
    risk = overrun_rows(filtering, [0.1, 0.0])
    assert risk.tolist() == [True, False, False, False, True, False]
