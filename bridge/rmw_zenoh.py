"""rmw_zenoh's wire conventions, as plain functions: data keys, attachments, graph tokens.

ROS 2's Zenoh middleware (rmw_zenoh, Jazzy and later) puts every topic on a Zenoh key and
announces every node, publisher and subscription with a liveliness token; a covswarm
process that follows these conventions is, to ROS 2, one more node. Read from
ros2/rmw_zenoh ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``, ``attachment_helpers.cpp``
and ``qos.cpp`` (docs/design.md describes the same):

- data key ``<domain>/<topic without its leading slash>/<pkg>::msg::dds_::<Name>_/<hash>``,
  with the type's RIHS01 hash (a key with the wrong hash matches nothing, silently);
- every sample carries a 33-byte attachment (zenoh-ext serialisation of int64 sequence
  number, int64 source timestamp in ns, and a 16-byte GID as a length-prefixed sequence),
  without which a ROS 2 subscriber drops the sample;
- liveliness tokens ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/
  <namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]``, every ``/`` inside a name
  replaced by ``%`` (an empty enclave or the root namespace is ``%``); no part may be empty
  and a publisher's or subscription's token has exactly 13 parts.

Pure (stdlib only): no Zenoh session, no CDR.
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
ENTITY_KINDS = (NODE, PUBLISHER, SUBSCRIPTION, "SS", "SC")
GID_SIZE = 16  # RMW_GID_STORAGE_SIZE
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE  # 33 bytes
MAX_DOMAIN_ID = 232  # ROS 2 domain ids are 0..232 (DDS port arithmetic; rmw_zenoh keeps it)

# RIHS01 type hashes (REP 2011), identical for Humble, Jazzy and Kilted; tests recompute
# every one with rosbags' hash_rihs01 so a typo cannot ship.
TYPE_HASHES: dict[str, str] = {
    "geometry_msgs/msg/Twist": "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/TwistStamped": (
        "5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64"
    ),
    "geometry_msgs/msg/PoseStamped": (
        "10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
    ),
    "geometry_msgs/msg/Pose2D": "d68efa5b46e70f7b16ca23085474fdac5a44b638783ec42f661da64da4724ccc",
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "geometry_msgs/msg/PolygonStamped": (
        "b7cf07932f1523d4b4088075945c1a0141f7cd21da87cc940fc61652e9138b46"
    ),
    "geometry_msgs/msg/PoseArray": (
        "af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0"
    ),
    "std_msgs/msg/Float64": "705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
}

# rmw_zenoh's default QoS (qos.cpp): a component equal to it is left empty in a token.
DEFAULT_DEPTH = 42
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def check_topic(topic: str) -> str:
    """The topic as an absolute ROS 2 name ("/robot1/cmd_vel"); ValueError if not a name.

    ROS 2 names are tokens of letters, digits and underscores (not starting with a digit)
    joined by slashes, no empty token; anything else would also be a broken Zenoh key.
    """
    tokens = topic[1:].split("/") if isinstance(topic, str) and topic.startswith("/") else None
    if tokens is None and isinstance(topic, str):
        tokens = topic.split("/")
    if not tokens or any(not _NAME_RE.match(t) for t in tokens):
        raise ValueError(f"invalid ROS 2 topic name {topic!r}: use e.g. /robot1/cmd_vel")
    return "/" + "/".join(tokens)


def check_domain_id(domain_id: int) -> int:
    if isinstance(domain_id, bool) or not isinstance(domain_id, int):
        raise ValueError(f"ROS 2 domain id must be an int, got {domain_id!r}")
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS 2 domain id {domain_id} outside 0..{MAX_DOMAIN_ID}")
    return domain_id


def dds_type_name(ros_type: str) -> str:
    """ "geometry_msgs/msg/Twist" -> "geometry_msgs::msg::dds_::Twist_" (the key's type part)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str) -> str:
    """The RIHS01 hash string of one of the TYPE_HASHES types (KeyError otherwise)."""
    return f"RIHS01_{TYPE_HASHES[ros_type]}"


def topic_key(domain_id: int, topic: str, ros_type: str) -> str:
    """The Zenoh key on which rmw_zenoh publishes ``topic`` of ``ros_type``."""
    name = check_topic(topic)[1:]
    return f"{check_domain_id(domain_id)}/{name}/{dds_type_name(ros_type)}/{type_hash(ros_type)}"


def topic_selector(domain_id: int, topic: str, ros_type: str) -> str:
    """What to subscribe to for ``topic``: any type hash (Humble's rmw_zenoh sends none).

    The type name still has to match, and the payload is decoded strictly, so the wildcard
    only admits other distributions' hashes of the same message layout.
    """
    name = check_topic(topic)[1:]
    return f"{check_domain_id(domain_id)}/{name}/{dds_type_name(ros_type)}/*"


def mangle(name: str) -> str:
    """A name as a single key chunk: every "/" becomes "%", and "" or "/" is "%"."""
    return "%" if name in ("", "/") else name.replace("/", "%")


def demangle(chunk: str) -> str:
    return chunk.replace("%", "/")


def qos_string(*, reliable: bool = True, depth: int = 10, transient_local: bool = False) -> str:
    """rmw_zenoh's QoS token part; components equal to its defaults are left empty.

    ``rel:dur:hist,depth:deadline_s,ns:lifespan_s,ns:liveliness,lease_s,lease_ns`` with the
    defaults RELIABLE (1), VOLATILE (2), KEEP_LAST (1) depth 42, infinite durations,
    AUTOMATIC liveliness: reliable, volatile, depth 10 is ``::,10:,:,:,,``.
    """
    if not 1 <= depth <= 10_000:
        raise ValueError(f"QoS depth must be in 1..10000, got {depth}")
    reliability = "" if reliable else "2"  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
    durability = "1" if transient_local else ""  # RMW_QOS_POLICY_DURABILITY_TRANSIENT_LOCAL
    history = f",{'' if depth == DEFAULT_DEPTH else depth}"
    return f"{reliability}:{durability}:{history}:,:,:,,"


def node_token_key(
    domain_id: int, zid: str, node_id: int, node_name: str, namespace: str = "/"
) -> str:
    """Liveliness token of a node (9 parts): what ``ros2 node list`` shows."""
    if not _NAME_RE.match(node_name):
        raise ValueError(f"invalid ROS 2 node name {node_name!r}")
    parts = [ADMIN_SPACE, str(check_domain_id(domain_id)), zid, str(node_id), str(node_id)]
    return "/".join([*parts, NODE, "%", mangle(namespace), node_name])


def endpoint_token_key(
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    kind: str,
    node_name: str,
    topic: str,
    ros_type: str,
    qos: str,
    namespace: str = "/",
) -> str:
    """Liveliness token of a publisher (MP) or subscription (MS), 13 parts:
    what ``ros2 topic list`` and ``ros2 topic info`` show."""
    if kind not in (PUBLISHER, SUBSCRIPTION):
        raise ValueError(f"kind must be {PUBLISHER} or {SUBSCRIPTION}, got {kind!r}")
    node = node_token_key(domain_id, zid, node_id, node_name, namespace).split("/")
    node[4], node[5] = str(entity_id), kind
    topic_part = mangle(check_topic(topic))
    return "/".join([*node, topic_part, dds_type_name(ros_type), type_hash(ros_type), qos])


@dataclass(frozen=True)
class GraphEntity:
    """A liveliness token parsed with rmw_zenoh's rules (Entity::make(keyexpr))."""

    domain_id: int
    zid: str
    node_id: str
    entity_id: str
    kind: str
    enclave: str
    namespace: str
    node_name: str
    topic: str | None = None
    type_name: str | None = None
    type_hash: str | None = None
    qos: str | None = None


def parse_token_key(key: str) -> GraphEntity:
    """Parse a token as rmw_zenoh does; ValueError where rmw_zenoh would reject it.

    At least 9 parts, none empty, the admin space, a known entity kind, a numeric domain;
    a non-node entity needs all 13 parts and a QoS string of 6 ``:``-separated components.
    """
    parts = key.split("/")
    if len(parts) < 9 or any(not p for p in parts):
        raise ValueError(f"liveliness token with {len(parts)} parts or an empty part: {key!r}")
    if parts[0] != ADMIN_SPACE:
        raise ValueError(f"not in the {ADMIN_SPACE} admin space: {key!r}")
    if parts[5] not in ENTITY_KINDS:
        raise ValueError(f"unknown entity kind {parts[5]!r}")
    if not parts[1].isdigit():
        raise ValueError(f"domain id {parts[1]!r} is not a number")
    common = {
        "domain_id": int(parts[1]),
        "zid": parts[2],
        "node_id": parts[3],
        "entity_id": parts[4],
        "kind": parts[5],
        "enclave": demangle(parts[6]),
        "namespace": demangle(parts[7]),
        "node_name": demangle(parts[8]),
    }
    if parts[5] == NODE:
        return GraphEntity(**common)
    if len(parts) != 13:
        raise ValueError(f"a {parts[5]} token needs 13 parts, got {len(parts)}")
    qos = parts[12].split(":")
    if len(qos) < 6 or len(qos[2].split(",")) < 2 or len(qos[5].split(",")) < 3:
        raise ValueError(f"invalid QoS string {parts[12]!r}")
    return GraphEntity(
        **common,
        topic=demangle(parts[9]),
        type_name=demangle(parts[10]),
        type_hash=demangle(parts[11]),
        qos=parts[12],
    )


def entity_gid(token_key: str) -> bytes:
    """A 16-byte GID for the entity announced by ``token_key``.

    rmw_zenoh takes XXH3-128 of the token key; receivers never check it against anything
    (it only tells publishers apart), so a stable 128-bit digest of the same key serves.
    """
    return hashlib.blake2b(token_key.encode(), digest_size=GID_SIZE).digest()


def encode_attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment of one sample.

    zenoh-ext serialisation of (int64 sequence number, int64 source timestamp in ns since
    the epoch, uint8[16] GID): two little-endian int64 and the array as a sequence with a
    LEB128 length prefix (16 = one byte 0x10).
    """
    if len(gid) != GID_SIZE:
        raise ValueError(f"GID must be {GID_SIZE} bytes, got {len(gid)}")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, GID_SIZE) + bytes(gid)


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def decode_attachment(data: bytes) -> Attachment:
    """Inverse of :func:`encode_attachment`; ValueError unless exactly that layout."""
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise ValueError(f"not an rmw_zenoh attachment ({len(data)} bytes)")
    seq, stamp = struct.unpack_from("<qq", data)
    return Attachment(seq, stamp, bytes(data[17:]))


class SampleCounter:
    """Attachments of one publisher: sequence numbers from 1, the publisher's GID."""

    def __init__(self, gid: bytes) -> None:
        self.gid = gid
        self.sequence_number = 0

    def next(self, source_timestamp_ns: int) -> bytes:
        self.sequence_number += 1
        return encode_attachment(self.sequence_number, source_timestamp_ns, self.gid)
