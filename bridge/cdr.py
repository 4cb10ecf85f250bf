"""CDR payloads of the ROS 2 messages the bridge speaks, through ``rosbags`` (pure Python).

rmw_zenoh carries each message as CDR, little endian, behind the 4-byte encapsulation
header ``00 01 00 00`` (alignment counted from the byte after it): a Twist is the header
and six float64 (52 bytes), a Pose2D three float64 (28 bytes), a PoseStamped an int32 sec,
a uint32 nanosec, the frame id as a uint32 length (NUL included) plus its characters and
NUL, padding to 8, then seven float64. ``rosbags`` (``pip install 'covswarm[ros2]'``)
implements these layouts; the tests check its bytes against ones built by hand.

Planar conventions: a pose is (x, y, theta), theta the yaw in radians (a rotation about z,
quaternion (0, 0, sin(theta/2), cos(theta/2))); a Twist drives a planar robot with
linear.x = v (m/s) and angular.z = omega (rad/s); stamps are float seconds since the epoch
(builtin_interfaces/Time: int32 sec, uint32 nanosec).

Decoders raise :class:`covswarm.protocol.ProtocolError` with a reason (oversize,
undecodable, nonfinite, value), so the bridge drops and counts like every other receiver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from covswarm.protocol.messages import ProtocolError

MAX_ROS_PAYLOAD = 65536  # bytes: an Odometry with long frame ids is under 1 kB
MAX_FRAME_ID = 256  # characters of a frame id we publish
QUATERNION_TOLERANCE = 0.1  # |1 - |q|| beyond which an orientation is not a rotation

TWIST, TWIST_STAMPED = "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"
POSE_STAMPED, POSE_2D = "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/Pose2D"
ODOMETRY = "nav_msgs/msg/Odometry"
POLYGON_STAMPED, POSE_ARRAY = "geometry_msgs/msg/PolygonStamped", "geometry_msgs/msg/PoseArray"
FLOAT64 = "std_msgs/msg/Float64"
COMMAND_TYPES = {"Twist": TWIST, "TwistStamped": TWIST_STAMPED}
POSE_TYPES = {"PoseStamped": POSE_STAMPED, "Pose2D": POSE_2D, "Odometry": ODOMETRY}


@lru_cache(maxsize=1)
def typestore() -> Any:
    """rosbags' Jazzy type store (the layouts above are the same in Humble and Kilted)."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:  # the optional extra is missing
        raise RuntimeError("the ROS 2 bridge needs rosbags: pip install 'covswarm[ros2]'") from exc
    return get_typestore(Stores.ROS2_JAZZY)


def _msg(ros_type: str, **fields: Any) -> Any:
    return typestore().types[ros_type](**fields)


def _serialize(message: Any) -> bytes:
    return bytes(typestore().serialize_cdr(message, message.__msgtype__))


def _time(stamp: float) -> Any:
    if not (math.isfinite(stamp) and 0.0 <= stamp < 2**31):
        raise ValueError(f"stamp {stamp!r} outside builtin_interfaces/Time")
    sec = math.floor(stamp)
    nanosec = min(round((stamp - sec) * 1e9), 999_999_999)
    return _msg("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def _header(stamp: float, frame: str) -> Any:
    if len(frame) > MAX_FRAME_ID or "\0" in frame:
        raise ValueError(f"frame id must be at most {MAX_FRAME_ID} characters without NUL")
    return _msg("std_msgs/msg/Header", stamp=_time(stamp), frame_id=frame)


def _vector(x: float, y: float, z: float) -> Any:
    return _msg("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def _pose(x: float, y: float, theta: float) -> Any:
    position = _msg("geometry_msgs/msg/Point", x=float(x), y=float(y), z=0.0)
    orientation = _msg(
        "geometry_msgs/msg/Quaternion",
        x=0.0,
        y=0.0,
        z=math.sin(theta / 2.0),
        w=math.cos(theta / 2.0),
    )
    return _msg("geometry_msgs/msg/Pose", position=position, orientation=orientation)


def _twist(v: float, omega: float) -> Any:
    if not (math.isfinite(v) and math.isfinite(omega)):
        raise ValueError(f"twist must be finite, got v={v!r}, omega={omega!r}")
    return _msg(TWIST, linear=_vector(v, 0.0, 0.0), angular=_vector(0.0, 0.0, omega))


def encode_twist(v: float, omega: float) -> bytes:
    """geometry_msgs/Twist: linear.x = v (m/s), angular.z = omega (rad/s), the rest 0."""
    return _serialize(_twist(v, omega))


def encode_twist_stamped(v: float, omega: float, stamp: float, frame: str) -> bytes:
    """geometry_msgs/TwistStamped of the same twist, stamped (s since the epoch)."""
    return _serialize(_msg(TWIST_STAMPED, header=_header(stamp, frame), twist=_twist(v, omega)))


def encode_pose_stamped(x: float, y: float, theta: float, stamp: float, frame: str) -> bytes:
    """geometry_msgs/PoseStamped of a planar pose (z = 0, yaw-only orientation)."""
    return _serialize(_msg(POSE_STAMPED, header=_header(stamp, frame), pose=_pose(x, y, theta)))


def encode_pose2d(x: float, y: float, theta: float) -> bytes:
    """geometry_msgs/Pose2D (no stamp)."""
    return _serialize(_msg(POSE_2D, x=float(x), y=float(y), theta=float(theta)))


def encode_odometry(
    x: float, y: float, theta: float, stamp: float, frame: str, child_frame: str = "base_link"
) -> bytes:
    """nav_msgs/Odometry with the pose set, zero twist and zero covariances."""
    covariance = np.zeros(36)
    pose = _msg(
        "geometry_msgs/msg/PoseWithCovariance", pose=_pose(x, y, theta), covariance=covariance
    )
    twist = _msg(
        "geometry_msgs/msg/TwistWithCovariance", twist=_twist(0.0, 0.0), covariance=covariance
    )
    return _serialize(
        _msg(
            ODOMETRY,
            header=_header(stamp, frame),
            child_frame_id=child_frame,
            pose=pose,
            twist=twist,
        )
    )


def encode_polygon_stamped(vertices: np.ndarray, stamp: float, frame: str) -> bytes:
    """geometry_msgs/PolygonStamped of S(t): ``vertices`` (k, 2) m, as float32 points, z = 0."""
    points = [
        _msg("geometry_msgs/msg/Point32", x=float(px), y=float(py), z=0.0)
        for px, py in np.asarray(vertices, dtype=float).reshape(-1, 2)
    ]
    polygon = _msg("geometry_msgs/msg/Polygon", points=points)
    return _serialize(_msg(POLYGON_STAMPED, header=_header(stamp, frame), polygon=polygon))


def encode_pose_array(poses: np.ndarray, stamp: float, frame: str) -> bytes:
    """geometry_msgs/PoseArray of the robots' planar poses ``poses`` (n, 3): x, y, theta."""
    items = [_pose(*row) for row in np.asarray(poses, dtype=float).reshape(-1, 3)]
    return _serialize(_msg(POSE_ARRAY, header=_header(stamp, frame), poses=items))


def encode_float64(value: float) -> bytes:
    """std_msgs/Float64."""
    return _serialize(_msg(FLOAT64, data=float(value)))


def decode(payload: bytes, ros_type: str) -> Any:
    """The rosbags message in ``payload``; ProtocolError (oversize, undecodable) otherwise.

    Trailing bytes beyond CDR's alignment padding are refused: a payload that is longer
    than its message is not the message it claims to be.
    """
    if len(payload) > MAX_ROS_PAYLOAD:
        raise ProtocolError(f"{len(payload)} bytes, at most {MAX_ROS_PAYLOAD}", "oversize")
    if len(payload) < 4 or payload[:2] != b"\x00\x01":  # CDR_LE; options bytes vary
        raise ProtocolError("not little-endian CDR (encapsulation header)", "undecodable")
    try:
        message = typestore().deserialize_cdr(bytes(payload), ros_type)
    except Exception as exc:  # rosbags raises struct/index/value/unicode errors alike
        raise ProtocolError(f"{ros_type}: {type(exc).__name__}: {exc}", "undecodable") from None
    if len(payload) - len(_serialize(message)) not in range(4):  # only CDR's end padding
        raise ProtocolError(f"{ros_type}: trailing bytes", "undecodable")
    return message


@dataclass(frozen=True)
class PlanarPose:
    """A robot's pose from a ROS 2 message: x, y (m), theta (rad), stamp (s or None)."""

    x: float
    y: float
    theta: float
    stamp: float | None


def _stamp(header: Any) -> float | None:
    """The header's stamp in seconds, None when unset (zero: many drivers leave it)."""
    if header.stamp.sec == 0 and header.stamp.nanosec == 0:
        return None
    if header.stamp.nanosec >= 1_000_000_000:
        raise ProtocolError(f"nanosec {header.stamp.nanosec} >= 1e9", "value")
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _yaw(pose: Any) -> float:
    """Yaw of the pose's orientation: atan2(2(wz + xy), 1 - 2(y^2 + z^2)); ProtocolError if the
    quaternion is not a rotation (a zero quaternion, from an uninitialised message)."""
    q = pose.orientation
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if not math.isfinite(norm):
        raise ProtocolError("orientation not finite", "nonfinite")
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise ProtocolError(f"orientation |q| = {norm:.3g}, not a rotation", "value")
    x, y, z, w = q.x / norm, q.y / norm, q.z / norm, q.w / norm
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def decode_pose(payload: bytes, ros_type: str) -> PlanarPose:
    """A planar pose from a PoseStamped, Pose2D or Odometry payload; ProtocolError if bad."""
    message = decode(payload, ros_type)
    if ros_type == POSE_2D:
        pose = PlanarPose(message.x, message.y, message.theta, None)
    elif ros_type in (POSE_STAMPED, ODOMETRY):
        inner = message.pose if ros_type == POSE_STAMPED else message.pose.pose
        position = inner.position
        if not (math.isfinite(position.x) and math.isfinite(position.y)):
            raise ProtocolError("position not finite", "nonfinite")
        pose = PlanarPose(position.x, position.y, _yaw(inner), _stamp(message.header))
    else:
        raise ValueError(f"not a pose type: {ros_type!r}")
    if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.theta)):
        raise ProtocolError("pose not finite", "nonfinite")
    return pose


def decode_twist(payload: bytes, ros_type: str) -> tuple[float, float, float | None]:
    """(v, omega, stamp or None) from a Twist or TwistStamped payload; ProtocolError if bad."""
    message = decode(payload, ros_type)
    if ros_type == TWIST_STAMPED:
        twist, stamp = message.twist, _stamp(message.header)
    elif ros_type == TWIST:
        twist, stamp = message, None
    else:
        raise ValueError(f"not a twist type: {ros_type!r}")
    v, omega = twist.linear.x, twist.angular.z
    if not (math.isfinite(v) and math.isfinite(omega)):
        raise ProtocolError("twist not finite", "nonfinite")
    return v, omega, stamp
