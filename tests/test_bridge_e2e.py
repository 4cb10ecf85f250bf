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
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import zenoh
from live_runs import stop_process, swarm_pids, wait_until
from rosbags.typesys import Stores, get_typestore

from covswarm import protocol
from covswarm.bridge import cdr, rmw_zenoh
from covswarm.deploy.plan import covswarm_argv, initial_poses
from covswarm.deploy.router import free_port
from covswarm.mission.scenario_files import load_scenario
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
        stop_process(child)
        if log:
            out.close()


@contextmanager
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with process([sys.executable, "-c", ROUTER, endpoint], text=True) as child:
        assert child.stdout.readline().strip() == "ready"
        yield endpoint


def next_sample(subscriber: zenoh.Subscriber, timeout: float) -> zenoh.Sample:
    deadline = time.monotonic() + timeout
    while (sample := subscriber.try_recv()) is None:
        assert time.monotonic() < deadline, "no sample"
        time.sleep(0.05)
    return sample


def decode(sample: zenoh.Sample, ros_type: str) -> object:
    """A ROS 2 sample as rosbags reads it (an independent CDR reader)."""
    return get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(sample.payload.to_bytes(), ros_type)


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
        ) as sdk,
        process(
            bridge_argv(endpoint, swarm, "5", "--publish-state", "--cmd-timeout", "2"),
            tmp_path / "bridge.log",
        ) as bridge,
        zenoh.open(session_config([endpoint])) as session,
    ):
        assert sdk.stdout.readline().strip() == "ready"
        poses = session.declare_subscriber(
            protocol.pose_key(swarm, 5), zenoh.handlers.RingChannel(64)
        )
        # ROS 2 -> covswarm: the SDK's PoseStamped (with its attachment) becomes a Pose, and
        # the robot's liveliness token appears with it.
        pose = protocol.Pose.decode(next_sample(poses, 20).payload.to_bytes())
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

        # --publish-state: the robots' poses as a PoseArray, with attachments, for RViz.
        state = session.declare_subscriber(
            rmw_zenoh.topic_key(0, "/covswarm/poses", cdr.POSE_ARRAY),
            zenoh.handlers.RingChannel(4),
        )
        deadline = time.monotonic() + 10
        # Until the bridge's own view has heard robot 5's pose back, the array is empty.
        while not (array := decode(sample := next_sample(state, 10), cdr.POSE_ARRAY)).poses:
            assert time.monotonic() < deadline, "only empty PoseArrays"
        assert array.header.frame_id == "map"
        assert [(p.position.x, p.position.y) for p in array.poses] == [(0.5, 0.25)]
        assert rmw_zenoh.decode_attachment(sample.attachment.to_bytes()).sequence_number >= 1

        # covswarm -> ROS 2: wheel commands become Twists that the SDK decodes.
        commands = session.declare_publisher(protocol.cmd_key(swarm, 5))

        def drive(first: int) -> None:
            for seq in range(first, first + 5):
                now = time.time()
                commands.put(protocol.WheelCommand(id=5, left=0.1, right=0.2, stamp=now,
                                                   seq=seq, pose_stamp=now).encode())  # fmt: skip
                time.sleep(0.1)

        def seconds_to_zero_twist() -> float:
            start = time.monotonic()
            while (twist := json.loads(sdk.stdout.readline())) != {"v": 0.0, "omega": 0.0}:
                assert twist["v"] == pytest.approx(0.15), twist
                assert time.monotonic() - start < 10, twist
            return time.monotonic() - start

        drive(0)
        twist = json.loads(sdk.stdout.readline())
        assert twist["v"] == pytest.approx(0.15)
        assert twist["omega"] == pytest.approx(0.1 / 0.1054)
        # No command for --cmd-timeout (2 s): the bridge stops the robot with a zero Twist.
        assert 1.0 < seconds_to_zero_twist() < 4.0
        # A bridge told to stop while the robot drives stops it first, before any timeout.
        drive(5)
        bridge.terminate()
        assert seconds_to_zero_twist() < 1.5
        assert bridge.wait(timeout=10) == 0
    log = (tmp_path / "bridge.log").read_text()
    assert "robot 5: 10 commands" in log and "dropped none" in log, log


def mission_started(log: Path) -> bool:
    return log.exists() and "mission started" in log.read_text()


def test_ros2_robots_run_a_mission_and_stop_when_their_agents_go_quiet(tmp_path: Path) -> None:
    """4 ROS 2 robots (scripts/ros2_robot_sim.py) behind the bridge, 4 agents and the
    coordinator of ``covswarm run --robots none``: the team converges; at t = 10 s, while
    the domain moves, the agents are killed and the bridge stops every robot."""
    swarm, out, agents, kill_at = f"e2e-{secrets.token_hex(4)}", tmp_path / "run", 4, 10.0
    poses = initial_poses(load_scenario("passage"), agents, 0)
    robots = [f"--robot={i}:{x},{y},{theta}" for i, (x, y, theta) in enumerate(poses.tolist())]
    record = tmp_path / "twists.jsonl"
    sim_argv = [sys.executable, str(ROOT / "scripts" / "ros2_robot_sim.py"), "--record",
                str(record)]  # fmt: skip
    with (
        router() as endpoint,
        process([*sim_argv, "--connect", endpoint, *robots], text=True) as sim,
    ):
        assert sim.stdout.readline().strip() == "ready"
        with (
            process(
                bridge_argv(endpoint, swarm, f"0-{agents - 1}", "--publish-state"),
                tmp_path / "bridge.log",
            ),
            zenoh.open(session_config([endpoint])) as session,
        ):
            state = {
                ros_type: session.declare_subscriber(
                    rmw_zenoh.topic_key(0, f"/covswarm/{name}", ros_type),
                    zenoh.handlers.RingChannel(1),
                )
                for name, ros_type in (("domain", cdr.POLYGON_STAMPED), ("error", cdr.FLOAT64))
            }
            launcher = subprocess.Popen(
                [*covswarm_argv(), "run", "--robots", "none", "--connect", endpoint, "--swarm",
                 swarm, "--scenario", "passage", "--agents", str(agents), "--duration", "12",
                 "--out", str(out)],
                stdout=(tmp_path / "launcher.log").open("wb"), stderr=subprocess.STDOUT,
            )  # fmt: skip
            try:
                coordinator_log = out / "logs" / "coordinator-0.log"
                assert wait_until(lambda: mission_started(coordinator_log), 90, 0.05)
                started = time.monotonic()
                # No simulated robot was started: the bridge's tokens started the mission.
                assert swarm_pids(swarm, "robot") == set()
                # --publish-state: S(t) and e_a on ROS 2 topics, as RViz would read them.
                polygon = decode(next_sample(state[cdr.POLYGON_STAMPED], 10), cdr.POLYGON_STAMPED)
                assert polygon.header.frame_id == "map" and len(polygon.polygon.points) == 4
                error = decode(next_sample(state[cdr.FLOAT64], 10), cdr.FLOAT64).data
                assert 0.0 <= error < 1.0
                time.sleep(max(0.0, kill_at - (time.monotonic() - started)))
                victims = swarm_pids(swarm, "agent")
                for pid in victims:
                    os.kill(pid, signal.SIGKILL)
                killed = time.time()
                assert len(victims) == agents
                assert launcher.wait(timeout=60) == 0, (tmp_path / "launcher.log").read_text()
            finally:
                if launcher.poll() is None:
                    launcher.kill()
                    launcher.wait()
            time.sleep(1.0)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["alive_at_end"]["robots"] == agents  # the bridge held every robot's token
    t, e = np.loadtxt(out / "error.csv", delimiter=",", skiprows=1, unpack=True)
    before = e[(t >= 6.0) & (t <= kill_at - 0.5)]
    # The random start (~0.3 m) has converged while the domain moves.
    assert before.size and before.max() < 0.05 and e[0] > 2 * before.max(), (e[0], before.max())

    lines = [json.loads(line) for line in record.read_text().splitlines()]
    counters = lines[-1]["counters"]
    assert counters["dropped_no_attachment"] == 0 and counters["dropped_malformed"] == 0
    for rid in range(agents):
        mine = [line for line in lines[:-1] if line["id"] == rid]
        driving = [line for line in mine if line["t"] < killed]
        stops = [line for line in mine if line["t"] >= killed and line["v"] == line["omega"] == 0]
        # A command sent just before the kill may still be on its way for a few tens of ms.
        late = [line for line in mine if line["t"] >= killed + 0.25]
        assert max(abs(line["v"]) for line in driving) > 0.01, rid  # it was driven
        assert abs(driving[-1]["v"]) > 1e-3, rid  # and was moving when its agent died
        # The bridge's zero Twist within the command timeout (0.5 s) plus scheduling slack,
        # and nothing but zero Twists after it.
        assert stops and stops[0]["t"] - killed < 1.0, (rid, mine[-3:])
        assert late and all(line["v"] == line["omega"] == 0 for line in late), rid
    log = (tmp_path / "bridge.log").read_text()
    for rid in range(agents):
        assert f"robot {rid} visible" in log
