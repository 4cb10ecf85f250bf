"""End to end: ROS 2 nodes on rmw_zenoh's wire format and ``covswarm bridge ros2``, no mocks.

Two independent ROS 2 sides, each a real Zenoh session in its own process over a loopback
router (as ``rmw_zenohd`` would be): ``zenoh-ros2-sdk`` (someone else's implementation of
rmw_zenoh's keys, tokens and attachments; given the message definitions, so it never
reaches for the network), and ``scripts/ros2_robot_sim.py`` (written here from the format's
description with ``struct``, nothing of covswarm), whose robots drive a real mission of
``covswarm run --robots none``.
"""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from covswarm import protocol
from covswarm.bridge import rmw_zenoh
from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port
from covswarm.protocol import session_config

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[1]

ROUTER = """
import signal, sys, zenoh
from covswarm.protocol import session_config
with zenoh.open(session_config(None, [sys.argv[1]], mode="router")):
    print("ready", flush=True)
    signal.pause()  # until SIGTERM (default action: exit)
"""

# A ROS 2 node written with zenoh-ros2-sdk: subscribes to /robot5/cmd_vel (prints each Twist
# as a JSON line) and publishes /robot5/pose (PoseStamped at 20 Hz, yaw 0.3).
SDK_NODE = """
import json, math, sys, time
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber
from zenoh_ros2_sdk.session import ZenohSession

port, twist_hash, pose_hash = int(sys.argv[1]), sys.argv[2], sys.argv[3]
manager = ZenohSession.get_instance("127.0.0.1", port)
DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\\nuint32 nanosec",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\\nstring frame_id",
    "geometry_msgs/msg/Point": "float64 x\\nfloat64 y\\nfloat64 z",
    "geometry_msgs/msg/Quaternion": "float64 x 0\\nfloat64 y 0\\nfloat64 z 0\\nfloat64 w 1",
    "geometry_msgs/msg/Pose": "Point position\\nQuaternion orientation",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\\nPose pose",
    "geometry_msgs/msg/Vector3": "float64 x\\nfloat64 y\\nfloat64 z",
    "geometry_msgs/msg/Twist": "Vector3 linear\\nVector3 angular",
}
for name, text in DEFINITIONS.items():
    manager.register_message_type(text, name)
types = manager.store.types


def on_twist(msg):
    print(json.dumps({"v": msg.linear.x, "omega": msg.angular.z}), flush=True)


ROS2Subscriber("/robot5/cmd_vel", "geometry_msgs/msg/Twist", on_twist, router_port=port,
               msg_definition=DEFINITIONS["geometry_msgs/msg/Twist"], type_hash=twist_hash,
               node_name="sdk_driver")
publisher = ROS2Publisher("/robot5/pose", "geometry_msgs/msg/PoseStamped", router_port=port,
                          msg_definition=DEFINITIONS["geometry_msgs/msg/PoseStamped"],
                          type_hash=pose_hash, node_name="sdk_mocap")
print("ready", flush=True)
while True:
    now = time.time()
    stamp = types["builtin_interfaces/msg/Time"](sec=int(now), nanosec=int(now % 1 * 1e9))
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="map")
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=0.5, y=0.25, z=0.0),
        orientation=types["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(0.15), w=math.cos(0.15)),
    )
    publisher.publish(header=header, pose=pose)
    time.sleep(0.05)
"""

SDK_CONFIG = """{
  mode: "client",
  scouting: { multicast: { enabled: false }, gossip: { enabled: false } },
}
"""


@contextmanager
def process(argv: list[str], log: Path | None = None, **kwargs) -> Iterator[subprocess.Popen]:
    """A child process, stopped (SIGTERM, then SIGKILL) when the block ends."""
    out = log.open("wb") if log else subprocess.PIPE
    child = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, **kwargs)
    try:
        yield child
    finally:
        if child.poll() is None:
            child.terminate()
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        if log:
            out.close()


@contextmanager
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with process([sys.executable, "-c", ROUTER, endpoint], text=True) as child:
        assert child.stdout.readline().strip() == "ready"
        yield endpoint


def wait_until(predicate, timeout: float, period: float = 0.2) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


def bridge_argv(endpoint: str, swarm: str, ids: str, *extra: str) -> list[str]:
    return [*covswarm_argv(), "bridge", "ros2", "--ids", ids, "--connect", endpoint,
            "--swarm", swarm, "--verbose", *extra]  # fmt: skip


def test_a_zenoh_ros2_sdk_node_and_the_bridge_understand_each_other(tmp_path: Path) -> None:
    swarm = f"e2e-{secrets.token_hex(4)}"
    config = tmp_path / "sdk.json5"
    config.write_text(SDK_CONFIG)
    env = {**os.environ, "ZENOH_SESSION_CONFIG_URI": str(config)}
    hashes = [rmw_zenoh.type_hash(t) for t in ("geometry_msgs/msg/Twist",
                                               "geometry_msgs/msg/PoseStamped")]  # fmt: skip
    with (
        router() as endpoint,
        process(
            [sys.executable, "-c", SDK_NODE, endpoint.rsplit(":", 1)[1], *hashes],
            text=True,
            env=env,
        ) as sdk,  # fmt: skip
        process(bridge_argv(endpoint, swarm, "5", "--publish-state"), tmp_path / "bridge.log"),
        zenoh.open(session_config([endpoint])) as session,
    ):
        assert sdk.stdout.readline().strip() == "ready"
        poses = session.declare_subscriber(
            protocol.pose_key(swarm, 5), zenoh.handlers.RingChannel(64)
        )
        # ROS 2 -> covswarm: the SDK's PoseStamped (with its attachment) becomes a Pose, and
        # the robot's liveliness token appears with it.
        assert wait_until(lambda: poses.try_recv() is not None, 20)
        pose = protocol.Pose.decode(poses.recv().payload.to_bytes())
        assert (pose.id, pose.x, pose.y) == (5, 0.5, 0.25)
        assert pose.theta == pytest.approx(0.3) and abs(pose.stamp - time.time()) < 1.0
        alive = session.liveliness().get(protocol.alive_key(swarm, "robot", 5), timeout=2)
        assert [r.ok is not None for r in alive] == [True]

        # The ROS graph: the bridge's node and entities, parsed with rmw_zenoh's rules.
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
        entities = [rmw_zenoh.parse_token_key(key) for key in tokens]
        ours = {(e.kind, e.topic) for e in entities if e.node_name == "covswarm_bridge"}
        assert ours == {
            ("NN", None),
            ("MP", "/robot5/cmd_vel"),
            ("MS", "/robot5/pose"),
            ("MP", "/covswarm/domain"),
            ("MP", "/covswarm/poses"),
            ("MP", "/covswarm/error"),
        }
        assert {(e.kind, e.topic) for e in entities if e.node_name == "sdk_driver"} >= {
            ("MS", "/robot5/cmd_vel")
        }

        # covswarm -> ROS 2: wheel commands become Twists that the SDK decodes.
        commands = session.declare_publisher(protocol.cmd_key(swarm, 5))
        for seq in range(5):
            now = time.time()
            commands.put(protocol.WheelCommand(id=5, left=0.1, right=0.2, stamp=now, seq=seq,
                                               pose_stamp=now).encode())  # fmt: skip
            time.sleep(0.1)
        twist = json.loads(sdk.stdout.readline())
        assert twist["v"] == pytest.approx(0.15)
        assert twist["omega"] == pytest.approx(0.1 / 0.1054)
        # No command for 0.5 s: the bridge stops the robot with a zero Twist.
        deadline = time.monotonic() + 5
        while (twist := json.loads(sdk.stdout.readline())) != {"v": 0.0, "omega": 0.0}:
            assert time.monotonic() < deadline, twist
    log = (tmp_path / "bridge.log").read_text()
    assert "robot 5: 5 commands" in log and "dropped none" in log, log
