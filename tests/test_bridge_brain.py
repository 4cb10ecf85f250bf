"""The bridge's sans-IO state: commands to Twists, timeouts, poses in, drops per reason."""

from __future__ import annotations

import math
import subprocess
import sys

import msgpack
import numpy as np
import pytest
from click.testing import CliRunner

from covswarm import protocol
from covswarm.bridge import cdr
from covswarm.bridge.brain import RobotBrain
from covswarm.bridge.mission_view import MissionView
from covswarm.bridge.process import bridge_group
from covswarm.bridge.rmw_zenoh import encode_attachment
from covswarm.tvd.drive import DiffDrive, integrate, twist_from_wheels

WALL = 1_700_000_000.0


def command(rid: int, left: float, right: float, stamp: float = WALL) -> bytes:
    return protocol.WheelCommand(
        id=rid, left=left, right=right, stamp=stamp, seq=1, pose_stamp=stamp
    ).encode()


def unicycle(pose: np.ndarray, v: float, omega: float, dt: float, steps: int = 20000) -> np.ndarray:
    """Reference: forward Euler of x' = v cos(theta), y' = v sin(theta), theta' = omega."""
    x, y, theta = pose
    h = dt / steps
    for _ in range(steps):
        x, y, theta = x + h * v * math.cos(theta), y + h * v * math.sin(theta), theta + h * omega
    return np.array([x, y, theta])


@pytest.mark.parametrize("axle", [0.1054, 0.16, 0.287])
def test_twist_drives_a_unicycle_like_the_wheels_drive_the_robot_model(axle: float) -> None:
    rng = np.random.default_rng(int(axle * 1000))
    robot = DiffDrive(wheel_separation=axle, max_wheel_speed=10.0)
    for left, right in rng.uniform(-0.5, 0.5, (5, 2)):
        v, omega = twist_from_wheels(left, right, axle)
        start = np.array([0.3, -0.2, 1.0])
        expected = integrate(start[None], np.array([[left, right]]), 0.7, robot)[0]
        got = unicycle(start, v, omega, 0.7)
        got[2] = (got[2] + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_allclose(got, expected, atol=1e-4)
    assert twist_from_wheels(0.2, 0.2, axle) == (0.2, 0.0)
    assert twist_from_wheels(-0.1, 0.1, axle) == (0.0, pytest.approx(0.2 / axle))


def test_a_command_is_sent_once_then_the_timeout_sends_zero_twists_for_a_while() -> None:
    brain = RobotBrain(
        3, cdr.POSE_STAMPED, axle=0.1, cmd_timeout=0.5, stop_hold=1.0, stop_period=0.1
    )
    assert brain.twist(0.0) is None  # never commanded: nothing to say
    assert brain.on_command(command(3, 0.1, 0.3), 0.0, WALL)
    assert brain.twist(0.01) == pytest.approx((0.2, 2.0))
    assert brain.twist(0.02) is None and brain.twist(0.5) is None
    sent = [(t, brain.twist(t)) for t in np.arange(0.51, 2.0, 0.02)]
    zeros = [t for t, twist in sent if twist is not None]
    assert all(twist in (None, (0.0, 0.0)) for _, twist in sent)
    assert zeros[0] == pytest.approx(0.51) and zeros[-1] <= 0.51 + 1.0
    assert 9 <= len(zeros) <= 11  # every 0.1 s for 1 s
    assert brain.stops == 1
    assert brain.on_command(command(3, 0.2, 0.2, WALL + 2.0), 2.0, WALL + 2.0)
    assert brain.twist(2.0) == (0.2, 0.0)


def test_bad_commands_are_dropped_and_counted_and_never_sent() -> None:
    brain = RobotBrain(1, cdr.POSE_STAMPED, max_clock_skew=0.5, cmd_timeout=0.5)
    nan = msgpack.packb(
        {"v": 1, "id": 1, "left": math.nan, "right": 0.0, "stamp": WALL, "seq": 1,
         "pose_stamp": WALL}
    )  # fmt: skip
    bad = {
        "undecodable": b"\xc1garbage",
        "nonfinite": nan,
        "wrong_id": command(2, 0.1, 0.1),
        "stamp_old": command(1, 0.1, 0.1, WALL - 5.0),
        "stamp_future": command(1, 0.1, 0.1, WALL + 5.0),
    }
    for payload in bad.values():
        assert not brain.on_command(payload, 0.0, WALL)
    assert brain.twist(0.0) is None and brain.commands == 0
    assert {r: n for r, n in brain.drops.counts.items() if n} == dict.fromkeys(bad, 1)


def test_poses_become_covswarm_poses_with_the_message_stamp() -> None:
    brain = RobotBrain(4, cdr.POSE_STAMPED, pose_max_age=0.5, pose_timeout=1.0)
    assert not brain.visible(0.0) and brain.take_pose(0) is None
    payload = cdr.encode_pose_stamped(1.0, -0.5, 0.25, WALL - 0.1, "map")
    assert brain.on_pose(payload, encode_attachment(1, int(WALL * 1e9), bytes(16)), 10.0, WALL)
    pose = brain.take_pose(7)
    assert (pose.id, pose.x, pose.y, pose.seq) == (4, 1.0, -0.5, 7)
    assert pose.theta == pytest.approx(0.25) and pose.stamp == pytest.approx(WALL - 0.1)
    assert brain.take_pose(8) is None  # forwarded once
    assert brain.visible(10.9) and not brain.visible(11.1)


def test_a_pose_without_a_stamp_takes_the_attachment_or_the_time_of_receipt() -> None:
    brain = RobotBrain(0, cdr.POSE_2D)
    attachment = encode_attachment(1, int((WALL - 0.2) * 1e9), bytes(16))
    assert brain.on_pose(cdr.encode_pose2d(0.1, 0.2, 0.3), attachment, 0.0, WALL)
    assert brain.take_pose(0).stamp == pytest.approx(WALL - 0.2)
    assert brain.on_pose(cdr.encode_pose2d(0.1, 0.2, 0.3), None, 0.0, WALL)
    assert brain.take_pose(0).stamp == WALL
    receive = RobotBrain(0, cdr.POSE_STAMPED, stamp_source="receive")
    old = cdr.encode_pose_stamped(0.0, 0.0, 0.0, 1000.0, "map")  # a clock of its own
    assert receive.on_pose(old, None, 0.0, WALL) and receive.take_pose(0).stamp == WALL


def test_bad_poses_are_dropped_with_their_reason() -> None:
    brain = RobotBrain(2, cdr.ODOMETRY, pose_max_age=0.5, max_clock_skew=0.5)
    good = cdr.encode_odometry(1.0, 1.0, 0.0, WALL, "odom")
    bad = {
        "stamp_old": (cdr.encode_odometry(1.0, 1.0, 0.0, WALL - 2.0, "odom"), None),
        "stamp_future": (cdr.encode_odometry(1.0, 1.0, 0.0, WALL + 2.0, "odom"), None),
        "undecodable": (good[:40], None),
        "attachment": (good, b"\x01\x02"),
        "value": (cdr.encode_odometry(1e6, 0.0, 0.0, WALL, "odom"), None),  # beyond MAX_COORD
    }
    for payload, attachment in bad.values():
        assert not brain.on_pose(payload, attachment, 0.0, WALL)
    assert brain.take_pose(0) is None and not brain.visible(0.0)
    assert {r: n for r, n in brain.drops.counts.items() if n} == dict.fromkeys(bad, 1)
    assert brain.on_pose(good, None, 0.0, WALL) and brain.poses == 1


def test_invalid_settings_are_refused() -> None:
    for kwargs in ({"axle": 0.0}, {"axle": math.nan}, {"cmd_timeout": -1.0},
                   {"stamp_source": "gps"}):  # fmt: skip
        with pytest.raises(ValueError):
            RobotBrain(0, cdr.POSE_STAMPED, **kwargs)
    with pytest.raises(ValueError):
        RobotBrain(0, cdr.TWIST)


def test_mission_view_keeps_the_newest_domain_error_and_fresh_poses() -> None:
    view = MissionView(pose_timeout=1.0)
    assert view.polygon() is None and view.error() is None and view.poses(0.0).shape == (0, 3)
    square = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))
    view.on_domain(
        protocol.Domain(
            seq=1, stamp=WALL, t=0.0, state="running", vertices=square,
            velocities=((0.0, 0.0),) * 4, kappa=2.0,
        ).encode()
    )  # fmt: skip
    view.on_status(
        protocol.Status(
            stamp=WALL, t=1.0, state="running", error=0.05, alive_agents=2, alive_robots=2
        ).encode()
    )
    for rid, t in ((1, 0.0), (0, 0.5)):
        view.on_pose(protocol.Pose(id=rid, x=rid, y=0.0, theta=0.0, stamp=WALL, seq=0).encode(), t)
    view.on_pose(b"junk", 0.5)
    np.testing.assert_array_equal(view.polygon(), np.array(square))
    assert view.error() == 0.05
    np.testing.assert_array_equal(view.poses(0.9)[:, 0], [0.0, 1.0])
    np.testing.assert_array_equal(view.poses(1.2)[:, 0], [0.0])  # robot 1's pose went stale
    assert view.drops.total == 1


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--cmd-topic", "/robot/cmd_vel", "must contain {id}"),
        ("--pose-topic", "/robot{id}/po se", "invalid ROS 2 topic name"),
        ("--domain-id", "233", "outside 0..232"),
        ("--node-name", "covswarm-bridge", "invalid ROS 2 node name"),
        ("--ids", "3-1", "invalid id range"),
        ("--ids", "0-70000", "robot id 70000 outside 0..65535"),
        ("--swarm", "a/b", "invalid swarm name"),
    ],
)
def test_the_command_refuses_bad_options_with_the_reason(
    option: str, value: str, message: str
) -> None:
    args = {"--ids": "0-2", "--connect": "tcp/127.0.0.1:9", "--swarm": "lab", option: value}
    result = CliRunner().invoke(bridge_group, ["ros2", *(a for kv in args.items() for a in kv)])
    assert result.exit_code == 2 and message in result.output, result.output
    if option in ("--cmd-topic", "--pose-topic"):
        assert f"Invalid value for {option}:" in result.output  # which option says it


def test_without_the_ros2_extra_the_command_says_what_to_install() -> None:
    script = (
        "import sys; sys.modules['rosbags'] = sys.modules['rosbags.typesys'] = None\n"
        "from click.testing import CliRunner\n"
        "from covswarm.bridge.process import bridge_group\n"
        "r = CliRunner().invoke(bridge_group, ['ros2', '--ids', '0', '--connect', "
        "'tcp/127.0.0.1:9', '--swarm', 'lab'])\n"
        "print(r.exit_code, r.output)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True).stdout
    assert out.startswith("1 ") and "pip install 'covswarm[ros2]'" in out, out


def test_a_robot_that_sent_no_pose_is_named_with_the_topic_and_type_listened_on() -> None:
    # A TurtleBot's Odometry on /odom while the bridge listens for PoseStamped on
    # /robot<id>/pose: nothing arrives, and the bridge said nothing without --verbose.
    from covswarm.bridge.process import Ros2Options, unheard_robots

    heard, silent = RobotBrain(4, cdr.POSE_STAMPED), RobotBrain(5, cdr.POSE_STAMPED)
    payload = cdr.encode_pose_stamped(1.0, -0.5, 0.25, WALL - 0.1, "map")
    assert heard.on_pose(payload, encode_attachment(1, int(WALL * 1e9), bytes(16)), 10.0, WALL)
    (line,) = unheard_robots([heard, silent], Ros2Options(domain_id=7))
    assert line.startswith(
        "robot 5: no pose on /robot5/pose (geometry_msgs/msg/PoseStamped) in ROS 2 domain 7"
    )
    assert "--pose-topic, --pose-type, --domain-id: the robots' ROS_DOMAIN_ID" in line


def test_a_second_publisher_under_one_id_is_dropped_while_the_first_is_live() -> None:
    """Two robots (or trackers) publishing /robot0/pose: their poses mixed made robot 0
    jump between x = -1.7 and x = 1.5 with no word. The robot follows the publisher heard
    first; the other's poses are dropped and counted (second_source, a warning) until the
    first is quiet for pose_timeout, when the robot follows the one still there."""
    brain = RobotBrain(0, cdr.POSE_STAMPED, pose_timeout=1.0)
    first, second = bytes(range(16)), bytes(range(16, 32))

    def pose(x: float, gid: bytes, now: float) -> bool:
        payload = cdr.encode_pose_stamped(x, 0.0, 0.0, WALL + now - 0.01, "map")
        return brain.on_pose(
            payload, encode_attachment(1, int((WALL + now) * 1e9), gid), now, WALL + now
        )

    taken = []
    for k in range(20):  # both at 20 Hz for 1 s
        now = 0.05 * k
        if pose(-1.7, first, now):
            taken.append(brain.take_pose(k).x)
        assert not pose(1.5, second, now + 0.01)
    assert taken == [-1.7] * 20 and brain.drops.counts["second_source"] == 20
    assert pose(1.5, second, 2.1)  # the first quiet for more than pose_timeout: the second
    assert brain.take_pose(21).x == 1.5
    assert not pose(-1.7, first, 2.2)  # and now the first is the second source
