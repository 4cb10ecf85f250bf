"""A reference ROS 2 robot simulator that speaks rmw_zenoh's wire format, for tests and demos.

Usage: python scripts/ros2_robot_sim.py --connect tcp/127.0.0.1:7447 \
           --robot 0:-2.0,-0.5,0.0 --robot 1:-1.5,0.4,1.57 [--record twists.jsonl]

Each ``--robot ID:x,y,theta`` is a differential-drive robot (a unicycle, integrated along
exact arcs at ``--rate``) that, exactly like a ROS 2 driver on rmw_zenoh would:

- subscribes to ``/robot<ID>/cmd_vel`` (geometry_msgs/Twist: linear.x = v, angular.z =
  omega) and drops any sample without a valid 33-byte attachment, as rmw_zenoh does;
- publishes ``/robot<ID>/pose`` (geometry_msgs/PoseStamped, frame "map", stamped with the
  wall clock) at ``--pose-rate``, each sample with its attachment;
- announces its node, publisher and subscription with rmw_zenoh liveliness tokens.

It is deliberately written from the format's description (ros2/rmw_zenoh docs/design.md,
liveliness_utils.cpp, attachment_helpers.cpp; CDR from the OMG spec), with ``struct`` and
``zenoh`` only and nothing of covswarm, so that a test driving it through ``covswarm
bridge ros2`` checks covswarm against an independent reading of the format. It keeps
driving on its last Twist forever (``--own-timeout 0``, the default) so that a test sees
that the bridge, not the robot, stops it; a real driver usually has a timeout of its own.
``--record`` writes every accepted Twist as a JSON line (wall time, id, v, omega) and, at
exit, one line of counters.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import signal
import struct
import time

import zenoh

TWIST_TYPE = "geometry_msgs::msg::dds_::Twist_"
TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
POSE_TYPE = "geometry_msgs::msg::dds_::PoseStamped_"
POSE_HASH = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
QOS = "::,10:,:,:,,"  # reliable, volatile, keep last 10 (rmw_zenoh leaves defaults empty)
CDR_LE = b"\x00\x01\x00\x00"


def pose_stamped_cdr(x: float, y: float, theta: float, stamp: float, frame: str = "map") -> bytes:
    """PoseStamped: Time (int32 sec, uint32 nanosec), string frame_id, Pose (7 float64)."""
    sec = int(stamp)
    body = struct.pack("<iI", sec, int((stamp - sec) * 1e9))
    body += struct.pack("<I", len(frame) + 1) + frame.encode() + b"\x00"
    body += b"\x00" * (-len(body) % 8)  # float64 alignment, counted after the header
    body += struct.pack("<7d", x, y, 0.0, 0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2))
    return CDR_LE + body


def twist_from_cdr(payload: bytes) -> tuple[float, float]:
    """(linear.x, angular.z) of a Twist: header + 6 float64; ValueError if not 52 bytes."""
    if len(payload) != 52 or payload[:2] != CDR_LE[:2]:
        raise ValueError(f"not a little-endian Twist ({len(payload)} bytes)")
    lx, _, _, _, _, az = struct.unpack_from("<6d", payload, 4)
    return lx, az


def attachment(seq: int, gid: bytes) -> bytes:
    """int64 sequence number, int64 source timestamp (ns), GID as a length-prefixed array."""
    return struct.pack("<qqB", seq, time.time_ns(), 16) + gid


def attachment_ok(data: bytes | None) -> bool:
    return data is not None and len(data) == 33 and data[16] == 16


class Robot:
    def __init__(self, session: zenoh.Session, rid: int, pose: list[float], domain: int) -> None:
        self.id, self.pose = rid, pose
        self.v = self.omega = 0.0
        self.last_cmd = time.monotonic()
        zid = str(session.zid())
        node = f"robot{rid}_driver"
        prefix = f"@ros2_lv/{domain}/{zid}/0"
        self.tokens = [session.liveliness().declare_token(f"{prefix}/0/NN/%/%/{node}")]
        cmd, pose_topic = f"robot{rid}/cmd_vel", f"robot{rid}/pose"
        for entity, kind, topic, kind_type, type_hash in (
            (1, "MS", cmd, TWIST_TYPE, TWIST_HASH),
            (2, "MP", pose_topic, POSE_TYPE, POSE_HASH),
        ):
            token = f"{prefix}/{entity}/{kind}/%/%/{node}/%{topic.replace('/', '%')}/"
            self.tokens.append(
                session.liveliness().declare_token(f"{token}{kind_type}/{type_hash}/{QOS}")
            )
        self.gid = hashlib.md5(f"{zid}/{rid}".encode()).digest()  # any 16 bytes
        self.seq = 0
        self.commands = session.declare_subscriber(
            f"{domain}/{cmd}/{TWIST_TYPE}/{TWIST_HASH}", zenoh.handlers.RingChannel(64)
        )
        self.publisher = session.declare_publisher(f"{domain}/{pose_topic}/{POSE_TYPE}/{POSE_HASH}")

    def drive(self, dt: float) -> None:
        x, y, theta = self.pose
        turn = self.omega * dt
        # exact arc: chord v dt sinc(turn/2) along the mid heading
        chord = self.v * dt * (1.0 if turn == 0 else math.sin(turn / 2) / (turn / 2))
        mid = theta + turn / 2
        self.pose = [x + chord * math.cos(mid), y + chord * math.sin(mid), theta + turn]

    def publish(self) -> None:
        self.seq += 1
        self.publisher.put(
            pose_stamped_cdr(*self.pose, time.time()), attachment=attachment(self.seq, self.gid)
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--connect", required=True)
    parser.add_argument("--robot", action="append", required=True, help="ID:x,y,theta")
    parser.add_argument("--domain-id", type=int, default=0)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--pose-rate", type=float, default=20.0)
    parser.add_argument("--own-timeout", type=float, default=0.0, help="0: none")
    parser.add_argument("--record")
    args = parser.parse_args()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("scouting/multicast/enabled", "false")
    counters = {"twists": 0, "dropped_no_attachment": 0, "dropped_malformed": 0}
    record = open(args.record, "a", encoding="utf-8") if args.record else None  # noqa: SIM115
    with zenoh.open(config) as session:
        robots = []
        for spec in args.robot:
            rid, pose = spec.split(":")
            robots.append(
                Robot(session, int(rid), [float(v) for v in pose.split(",")], args.domain_id)
            )
        print("ready", flush=True)
        period, next_pose, last = 1.0 / args.rate, 0.0, time.monotonic()
        while not stop:
            time.sleep(period)
            now = time.monotonic()
            for robot in robots:
                while (sample := robot.commands.try_recv()) is not None:
                    extra = sample.attachment
                    if not attachment_ok(None if extra is None else extra.to_bytes()):
                        counters["dropped_no_attachment"] += 1
                        continue
                    try:
                        robot.v, robot.omega = twist_from_cdr(sample.payload.to_bytes())
                    except ValueError:
                        counters["dropped_malformed"] += 1
                        continue
                    robot.last_cmd = now
                    counters["twists"] += 1
                    if record:
                        line = {
                            "t": time.time(),
                            "id": robot.id,
                            "v": robot.v,
                            "omega": robot.omega,
                        }
                        record.write(json.dumps(line) + "\n")
                        record.flush()
                if args.own_timeout > 0 and now - robot.last_cmd > args.own_timeout:
                    robot.v = robot.omega = 0.0
                robot.drive(now - last)
            last = now
            if now >= next_pose:
                next_pose = now + 1.0 / args.pose_rate
                for robot in robots:
                    robot.publish()
        for robot in robots:
            for token in robot.tokens:
                token.undeclare()
    if record:
        record.write(json.dumps({"counters": counters}) + "\n")
        record.close()


if __name__ == "__main__":
    main()
