"""Wire protocol: key builders, round trips, strict rejection, fuzzing."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from covswarm import protocol
from covswarm.protocol import (
    AgentState,
    Beacon,
    Domain,
    Pose,
    ProtocolError,
    Status,
    WheelCommand,
)

STAMP = 1.7e9
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]

SAMPLES = [
    Pose(id=3, x=1.5, y=-2.0, theta=0.3, stamp=STAMP, seq=7),
    WheelCommand(id=3, left=0.1, right=-0.2, stamp=STAMP, seq=8, pose_stamp=STAMP - 0.05),
    Domain(
        seq=1,
        stamp=STAMP,
        t=2.5,
        state="running",
        vertices=SQUARE,
        velocities=[[0.1, 0.0]] * 4,
        kappa=1.0,
    ),
    AgentState(
        id=4, x=0.5, y=0.5, stamp=STAMP, neighbors=[9, 1, 2], stats={"rate": 9.9, "drops": 3}
    ),
    Beacon(id=5, x=-0.1, y=7.0, stamp=STAMP),
    Status(stamp=STAMP, t=3.0, state="done", error=0.25, alive_agents=3, alive_robots=3),
    Status(stamp=STAMP, t=0.0, state="waiting", error=None, alive_agents=0, alive_robots=0),
]


def wire(message: protocol.Message) -> dict:
    return msgpack.unpackb(message.encode(), raw=False)


def packed(d: dict) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


# --- keys ------------------------------------------------------------------------------


def test_keys_have_the_contract_shape() -> None:
    assert protocol.pose_key("s1", 4) == "covswarm/s1/robot/4/pose"
    assert protocol.cmd_key("s1", 4) == "covswarm/s1/robot/4/cmd"
    assert protocol.domain_key("s1") == "covswarm/s1/domain"
    assert protocol.status_key("s1") == "covswarm/s1/status"
    assert protocol.agent_state_key("s1", 4) == "covswarm/s1/agent/4/state"
    assert protocol.beacon_key("s1", -1, 2, 4) == "covswarm/s1/beacon/-1/2/4"
    assert protocol.beacon_tile_selector("s1", -1, 2) == "covswarm/s1/beacon/-1/2/*"
    assert protocol.alive_key("s1", "robot", 4) == "covswarm/s1/alive/robot/4"
    assert protocol.alive_selector("s1", "agent") == "covswarm/s1/alive/agent/*"
    assert protocol.all_poses_selector("s1") == "covswarm/s1/robot/*/pose"


def test_key_parsing_round_trips() -> None:
    assert protocol.parse_id(protocol.pose_key("s", 12), "s", "pose") == 12
    assert protocol.parse_id(protocol.agent_state_key("s", 0), "s", "state") == 0
    assert protocol.parse_id(protocol.beacon_key("s", 0, -3, 9), "s", "beacon") == 9
    assert protocol.parse_alive_key(protocol.alive_key("s", "agent", 2), "s") == ("agent", 2)
    for bad in ["covswarm/s/robot/x/pose", "covswarm/t/robot/1/pose", "covswarm/s/robot/1/cmd"]:
        with pytest.raises(ValueError):
            protocol.parse_id(bad, "s", "pose")
    with pytest.raises(ValueError):
        protocol.parse_alive_key("covswarm/s/alive/pilot/1", "s")


@pytest.mark.parametrize("swarm", ["", "a/b", "a*", "x" * 65, "a b", "$x"])
def test_bad_swarm_names_rejected(swarm: str) -> None:
    with pytest.raises(ValueError):
        protocol.pose_key(swarm, 1)


@pytest.mark.parametrize("robot_id", [-1, protocol.MAX_ID + 1, True, 1.0, "1"])
def test_bad_ids_rejected_by_key_builders(robot_id: object) -> None:
    with pytest.raises(ValueError):
        protocol.pose_key("s", robot_id)  # type: ignore[arg-type]


def test_tile_of_floors() -> None:
    assert protocol.tile_of(0.5, -0.5, 1.0) == (0, -1)
    assert protocol.tile_of(2.0, 3.99, 2.0) == (1, 1)
    with pytest.raises(ValueError):
        protocol.tile_of(math.nan, 0.0, 1.0)
    with pytest.raises(ValueError):
        protocol.tile_of(0.0, 0.0, 0.0)


def test_new_swarm_names_are_valid_and_distinct() -> None:
    names = {protocol.new_swarm_name() for _ in range(50)}
    assert len(names) == 50
    for name in names:
        protocol.check_swarm(name)


def test_protocol_import_does_not_import_zenoh() -> None:
    code = (
        "import sys; from covswarm import protocol; "
        "assert 'zenoh' not in sys.modules; protocol.PREFIX"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_session_config_has_no_scouting() -> None:
    config = protocol.session_config(["tcp/127.0.0.1:7447"], None, "client")
    assert '"enabled":false' in config.get_json("scouting/multicast").replace(" ", "")
    assert "127.0.0.1:7447" in config.get_json("connect/endpoints")
    with pytest.raises(ValueError):
        protocol.session_config(None, None, "client")
    with pytest.raises(ValueError):
        protocol.session_config(None, None, "router")
    with pytest.raises(ValueError):
        protocol.session_config(["tcp/127.0.0.1:1"], None, "bogus")


# --- round trips ------------------------------------------------------------------------


@pytest.mark.parametrize("message", SAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(message: protocol.Message) -> None:
    payload = message.encode()
    assert len(payload) <= protocol.MAX_PAYLOAD
    assert type(message).decode(payload) == message
    assert wire(message)["v"] == protocol.SCHEMA_VERSION


def test_canonical_forms() -> None:
    state = SAMPLES[3]
    assert state.neighbors == (1, 2, 9)
    domain = SAMPLES[2]
    assert domain.vertices[1] == (2.0, 0.0)
    # ints are accepted for floats (other encoders drop ".0")
    pose = Pose.decode(packed({**wire(SAMPLES[0]), "x": 2}))
    assert pose.x == 2.0 and isinstance(pose.x, float)


def test_numpy_values_accepted_when_sending() -> None:
    np = pytest.importorskip("numpy")
    domain = Domain(
        seq=np.int64(2),
        stamp=STAMP,
        t=np.float64(1.0),
        state="running",
        vertices=np.array(SQUARE),
        velocities=np.zeros((4, 2)),
        kappa=np.float32(2.0),
    )
    assert Domain.decode(domain.encode()) == domain


def test_largest_domain_fits() -> None:
    vertices = [[1000.0 * math.cos(a / 10), 1000.0 * math.sin(a / 10)] for a in range(64)]
    domain = Domain(
        seq=protocol.messages.MAX_SEQ,
        stamp=STAMP,
        t=1.0,
        state="running",
        vertices=vertices,
        velocities=vertices,
        kappa=1.0,
    )
    assert len(domain.encode()) <= protocol.MAX_PAYLOAD


def test_domain_density_round_trip() -> None:
    """The optional density: absent when uniform (same bytes as before), else round-trips."""
    np = pytest.importorskip("numpy")
    from covswarm.tvd.density import MAX_BUMPS, Density

    uniform = SAMPLES[2]
    assert "density" not in wire(uniform) and uniform.density is None
    bumps = [
        {"mean": [0.1 * b, 1.0], "cov": [[0.2, 0.05], [0.05, 0.1]], "weight": 3.0,
         "mean_rate": [0.1, 0.0], "cov_rate": [[0.01, 0.0], [0.0, -0.01]], "weight_rate": 0.5}
        for b in range(MAX_BUMPS)
    ]  # fmt: skip
    density = Density.from_dict({"t": 2.5, "floor": 1.0, "bumps": bumps})
    vertices = [[1000.0 * math.cos(a / 10), 1000.0 * math.sin(a / 10)] for a in range(64)]
    fields = {**wire(uniform), "vertices": vertices, "velocities": vertices}
    del fields["v"]
    domain = Domain(**fields, density=density.to_dict())
    payload = domain.encode()
    assert len(payload) <= protocol.MAX_PAYLOAD  # the largest Domain still fits
    again = Domain.decode(payload)
    assert again == domain
    back = Density.from_dict(again.density)
    assert back.to_dict() == density.to_dict()
    assert np.array_equal(back.covariance_rates, density.covariance_rates)
    for bad, reason in (
        ({**density.to_dict(), "extra": 1}, "keys"),
        ({**density.to_dict(), "bumps": bumps * 2}, "at most"),
        ({**density.to_dict(), "floor": math.nan}, "not finite"),
        ({**density.to_dict(), "bumps": [{**bumps[0], "cov": [[1.0, 0.0]]}]}, "points"),
    ):
        with pytest.raises(ProtocolError, match=reason):
            Domain.decode(packed({**wire(uniform), "density": bad}))


def test_domain_tile_size_and_state_stats_are_optional() -> None:
    """The swarm's beacon tile size rides on the Domain, an agent's stats on some of its
    AgentStates: absent on the wire when None, round-trips otherwise, checked when present."""
    uniform = SAMPLES[2]
    assert "tile_size" not in wire(uniform) and uniform.tile_size is None
    fields = {**wire(uniform), "tile_size": 0.6}
    del fields["v"]
    tiled = Domain(**fields)
    assert wire(tiled)["tile_size"] == 0.6 and Domain.decode(tiled.encode()) == tiled
    for bad, reason in ((0.0, "> 0"), (-1.0, "outside"), (math.inf, "not finite"), ("1", "number")):
        with pytest.raises(ProtocolError, match=reason):
            Domain.decode(packed({**wire(uniform), "tile_size": bad}))
    slim = AgentState(id=4, x=0.5, y=0.5, stamp=STAMP, neighbors=[1, 2])
    assert "stats" not in wire(slim) and AgentState.decode(slim.encode()) == slim
    with pytest.raises(ProtocolError, match="expected a map"):
        AgentState.decode(packed({**wire(slim), "stats": [1]}))


def test_domain_start_velocities_are_optional_and_one_per_vertex() -> None:
    """How S will move at the start rides on a waiting Domain: absent on the wire when
    None, round-trips otherwise, checked point by point and against the vertices."""
    still = SAMPLES[2]
    assert "start_velocities" not in wire(still) and still.start_velocities is None
    fields = {**wire(still), "start_velocities": [[0.0, 0.2]] * len(still.vertices)}
    del fields["v"]
    moving = Domain(**fields)
    assert moving.start_velocities == ((0.0, 0.2),) * len(still.vertices)
    assert Domain.decode(moving.encode()) == moving
    n = len(still.vertices)
    for bad, reason in (
        ([[0.0, 0.2]] * (n - 1), f"{n - 1} start_velocities for {n} vertices"),
        ([[0.0, math.nan]] * n, "not finite"),
        ([[0.0, 1e6]] * n, "outside"),
        ([[0.0]] * n, r"expected \[x, y\]"),
        (0.2, "expected an array"),
    ):
        with pytest.raises(ProtocolError, match=reason):
            Domain.decode(packed({**wire(still), "start_velocities": bad}))


def test_agent_state_relay() -> None:
    """Relayed neighbour positions: optional, round-trip, every entry checked (the fast path
    for plain msgpack lists and the slow one with the reason agree)."""
    relay = [[2, 1.0, 2.0, 0.1, -0.1], [7, -3.0, 0.5, 0.0, 0.0]]
    state = AgentState(id=4, x=0.5, y=0.5, stamp=STAMP, neighbors=[2, 7], relay=relay)
    assert AgentState.decode(state.encode()) == state
    assert state.relay == ((2, 1.0, 2.0, 0.1, -0.1), (7, -3.0, 0.5, 0.0, 0.0))
    base = {**wire(state)}
    fields = {"id": 4, "x": 0.5, "y": 0.5, "stamp": STAMP, "neighbors": [2, 7]}
    as_ints = AgentState.decode(packed({**base, "relay": [[2, 1, 2, 0, 0]]}))
    assert as_ints.relay == ((2, 1.0, 2.0, 0.0, 0.0),) and type(as_ints.relay[0][1]) is float
    too_many = [[i, 0.0, 0.0, 0.0, 0.0] for i in range(protocol.MAX_RELAY + 1)]
    for bad, reason in (
        ([[2, 1.0, 2.0, 0.1]], "expected \\[id, x, y, vx, vy\\]"),
        ([[2, 1.0, math.nan, 0.0, 0.0]], "not finite"),
        ([[2, 1.0, 2.0, 0.0, 1e3]], "outside"),
        ([[2, 1e5, 2.0, 0.0, 0.0]], "outside"),
        ([[-1, 1.0, 2.0, 0.0, 0.0]], "outside"),
        ([[2, 1.0, 2.0, 0.0, 0.0], [2, 0.0, 0.0, 0.0, 0.0]], "duplicate"),
        ([[True, 1.0, 2.0, 0.0, 0.0]], "expected an int"),
        (too_many, "at most"),
        ({"2": 1.0}, "expected an array"),
    ):
        with pytest.raises(ProtocolError, match=reason):
            AgentState.decode(packed({**base, "relay": bad}))
        # An agent builds its own relay as tuples: checked the same way.
        if isinstance(bad, list):
            with pytest.raises(ProtocolError, match=reason):
                AgentState(**{**fields, "relay": [tuple(entry) for entry in bad]})
    assert AgentState(**{**fields, "relay": [tuple(entry) for entry in relay]}) == state


# --- rejection --------------------------------------------------------------------------

POSE = wire(SAMPLES[0])
DOMAIN = wire(SAMPLES[2])
STATE = wire(SAMPLES[3])


@pytest.mark.parametrize(
    ("cls", "d", "reason"),
    [
        (Pose, {**POSE, "v": 2}, "schema version"),
        (Pose, {k: v for k, v in POSE.items() if k != "v"}, "schema version"),
        (Pose, {**POSE, "v": True}, "schema version"),
        (Pose, {k: v for k, v in POSE.items() if k != "theta"}, "missing"),
        (Pose, {**POSE, "extra": 1}, "unknown"),
        (Pose, {**POSE, "x": "1.0"}, "expected a number"),
        (Pose, {**POSE, "x": True}, "expected a number"),
        (Pose, {**POSE, "x": math.nan}, "not finite"),
        (Pose, {**POSE, "y": math.inf}, "not finite"),
        (Pose, {**POSE, "x": 1e9}, "outside"),
        (Pose, {**POSE, "id": -1}, "outside"),
        (Pose, {**POSE, "id": 70000}, "outside"),
        (Pose, {**POSE, "id": 1.0}, "expected an int"),
        (Pose, {**POSE, "stamp": -1.0}, "outside"),
        (Pose, {**POSE, "seq": -5}, "outside"),
        (WheelCommand, {**wire(SAMPLES[1]), "left": 100.0}, "outside"),
        (WheelCommand, {**wire(SAMPLES[1]), "right": math.nan}, "not finite"),
        (Domain, {**DOMAIN, "state": "flying"}, "expected one of"),
        (Domain, {**DOMAIN, "vertices": SQUARE[:2], "velocities": SQUARE[:2]}, "points"),
        (Domain, {**DOMAIN, "vertices": [[0, 0]] * 65, "velocities": [[0, 0]] * 65}, "points"),
        (Domain, {**DOMAIN, "velocities": [[0.0, 0.0]] * 3}, "velocities for"),
        (Domain, {**DOMAIN, "vertices": [[0, 0, 0]] * 4}, "got 3 values"),
        (Domain, {**DOMAIN, "vertices": [[0, math.nan]] * 4}, "not finite"),
        (Domain, {**DOMAIN, "vertices": "abcd"}, "expected an array"),
        (Domain, {**DOMAIN, "kappa": 0.0}, "> 0"),
        (Domain, {**DOMAIN, "kappa": -1.0}, "outside"),
        (AgentState, {**STATE, "neighbors": [1, 1]}, "duplicate"),
        (AgentState, {**STATE, "neighbors": [1, -1]}, "outside"),
        (AgentState, {**STATE, "neighbors": list(range(300))}, "at most"),
        (AgentState, {**STATE, "stats": {"x": math.nan}}, "not finite"),
        (AgentState, {**STATE, "stats": {"": 1}}, "bad entry name"),
        (AgentState, {**STATE, "stats": [1, 2]}, "expected a map"),
        (Status, {**wire(SAMPLES[5]), "alive_agents": -1}, "outside"),
        (Status, {**wire(SAMPLES[5]), "error": -0.5}, "outside"),
    ],
)
def test_rejects_bad_fields(cls: type[protocol.Message], d: dict, reason: str) -> None:
    with pytest.raises(ProtocolError, match=reason):
        cls.decode(packed(d))


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "not valid msgpack"),
        (b"\xc1", "not valid msgpack"),
        (packed(POSE) + b"\x00", "not valid msgpack"),
        (packed(POSE)[:-3], "not valid msgpack"),
        (packed([1, 2, 3]), "expected a map"),
        (packed(None), "expected a map"),
        (packed({1: 2}), "not valid msgpack"),  # strict_map_key: keys must be str/bytes
        (b"\x00" * (protocol.MAX_PAYLOAD + 1), "limit"),
        ("not bytes", "expected bytes"),
    ],
)
def test_rejects_bad_payloads(payload: object, reason: str) -> None:
    with pytest.raises(ProtocolError, match=reason):
        Pose.decode(payload)


def test_wrong_message_type_rejected() -> None:
    with pytest.raises(ProtocolError):
        Pose.decode(SAMPLES[4].encode())  # a Beacon lacks theta and seq


def test_invalid_messages_cannot_be_built_or_sent() -> None:
    with pytest.raises(ProtocolError):
        WheelCommand(id=1, left=math.nan, right=0.0, stamp=STAMP, seq=0, pose_stamp=STAMP)
    assert issubclass(ProtocolError, ValueError)


# --- fuzz -------------------------------------------------------------------------------

MESSAGE_TYPES = [Pose, WheelCommand, Domain, AgentState, Beacon, Status]

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**64), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.binary(max_size=8),
)
values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.sampled_from(MESSAGE_TYPES))
def test_fuzz_random_bytes(payload: bytes, cls: type[protocol.Message]) -> None:
    try:
        cls.decode(payload)
    except ProtocolError:
        pass


@settings(max_examples=500, deadline=None)
@given(
    st.sampled_from(SAMPLES),
    st.dictionaries(
        st.sampled_from(
            [
                "v",
                "id",
                "x",
                "y",
                "theta",
                "stamp",
                "seq",
                "left",
                "right",
                "pose_stamp",
                "t",
                "state",
                "vertices",
                "velocities",
                "kappa",
                "neighbors",
                "stats",
                "relay",
                "error",
                "alive_agents",
                "alive_robots",
                "zz",
            ]
        ),
        values,
        max_size=4,
    ),
)
def test_fuzz_structured(base: protocol.Message, overrides: dict) -> None:
    """Valid messages with random fields replaced: decode succeeds or raises ProtocolError."""
    d = {**wire(base), **overrides}
    try:
        payload = packed(d)
    except (OverflowError, ValueError):
        return  # not representable in msgpack at all
    try:
        decoded = type(base).decode(payload)
    except ProtocolError:
        return
    # Whatever is accepted re-encodes to an equal message.
    assert type(base).decode(decoded.encode()) == decoded


# --- process plumbing -------------------------------------------------------------------

LOOP = """
from covswarm.runtime.clock import StopFlag, Ticker
stop = StopFlag()
ticker = Ticker(200.0)
print("ready", flush=True)
while not stop.is_set():
    ticker.wait(stop)
print("stopped", ticker.ticks > 0, flush=True)
"""


@pytest.mark.e2e
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_stop_flag_ends_a_ticking_loop(signum: int) -> None:
    child = subprocess.Popen([sys.executable, "-c", LOOP], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline() == "ready\n"
        time.sleep(0.05)
        child.send_signal(signum)
        out, _ = child.communicate(timeout=5)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0
    assert out == "stopped True\n"
