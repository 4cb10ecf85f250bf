"""Fuzzing the input paths of the processes that steer and drive robots.

Random bytes and random structured messages (valid-looking maps with NaN, inf, huge,
negative and wrong-typed values, extra and missing keys, thousands of vertices, non-convex
polygons, stamps from the future and the past) go to every decoder, to the agent's update
path (AgentBrain.receive, then a control step) and to the simulated robot. Nothing may
raise, the agent may never produce a NaN or out-of-limit wheel command nor an AgentState or
beacon it cannot send, and the robot's pose stays finite and moves no faster than its
wheels allow. Tests share no state, so they can run twice at once.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from covswarm import protocol
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.protocol.inbound import check_stamp
from covswarm.sim_robot.process import RobotSim
from covswarm.tvd.drive import DiffDrive

WALL = 1.7e9  # the receiver's wall clock in these tests
ME = 0
ROBOT = DiffDrive(max_wheel_speed=0.8)
FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)

# --- strategies: valid-looking values, and the ways they go wrong ----------------------

finite = st.floats(-10.0, 10.0, allow_nan=False)
coords = st.one_of(finite, st.floats(-protocol.messages.MAX_COORD, protocol.messages.MAX_COORD))
stamps = st.one_of(
    st.floats(WALL - 0.4, WALL + 0.2),  # fresh
    st.floats(WALL - 1e4, WALL + 1e4),  # far past and future
    st.sampled_from([0.0, protocol.messages.MAX_STAMP]),
)
ids = st.integers(0, 12)
bad_numbers = st.sampled_from(
    [math.nan, math.inf, -math.inf, 1e300, -1e300, 2**64 - 1, -(2**63), 1e12, -1.0, 0.0]
)
wrong_types = st.sampled_from([None, True, "x", b"\x00", [], {}, [1.0, 2.0], {"a": 1}])
SPOILS = ("number", "type", "drop")


def spoil(draw: st.DrawFn, d: dict, field: str, how: str) -> None:
    """Corrupt ``d[field]`` in place as ``how`` (one of SPOILS) says: a bad number, a value of
    the wrong type, or the field dropped."""
    if how == "number":
        d[field] = draw(bad_numbers)
    elif how == "type":
        d[field] = draw(wrong_types)
    else:
        del d[field]


@st.composite
def convex_polygons(draw: st.DrawFn) -> list[list[float]]:
    """Convex polygons of 3..64 vertices, from millimetres to kilometres across."""
    k = draw(st.integers(3, protocol.MAX_VERTICES))
    # Positive gaps between consecutive angles, so no two vertices coincide.
    gaps = np.array(draw(st.lists(st.floats(1.0, 10.0), min_size=k + 1, max_size=k + 1)))
    angles = 2 * np.pi * np.cumsum(gaps)[:-1] / gaps.sum() + draw(st.floats(0.0, 2 * np.pi))
    scale = draw(st.sampled_from([1e-3, 1.0, 2.0, 1e3]))
    centre = np.array([draw(finite), draw(finite)])
    points = centre + scale * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return points.tolist()


nonconvex = st.sampled_from(
    [
        [[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]],  # bow-tie (self-intersecting)
        [[0.0, 0.0], [2.0, 0.0], [1.0, 0.2], [2.0, 2.0], [0.0, 2.0]],  # reflex vertex
        [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]],  # zero area
        [[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]],  # repeated vertex
        [[math.cos(a), math.sin(a)] for a in np.linspace(0, 4 * np.pi, 9)[:-1]],  # wound twice
    ]
)
polygons = st.one_of(convex_polygons(), nonconvex)


@st.composite
def densities(draw: st.DrawFn) -> dict:
    """Density maps of the Domain's shape, often invalid (negative weights, covariances that
    are not positive definite, huge values), for covswarm.tvd.density to refuse."""
    number = st.one_of(st.floats(-1.0, 10.0), st.sampled_from([0.0, 1e6, -1e6]))

    def bump() -> dict:
        a, b, c = draw(st.floats(-0.1, 1.0)), draw(st.floats(-0.5, 0.5)), draw(st.floats(-0.1, 1))
        return {
            "mean": [draw(finite), draw(finite)],
            "cov": [[a, b], [b, c]],
            "weight": draw(number),
            "mean_rate": [draw(st.floats(-1.0, 1.0)), 0.0],
            "cov_rate": [[draw(st.floats(-0.1, 0.1)), 0.0], [0.0, 0.0]],
            "weight_rate": draw(st.floats(-1.0, 1.0)),
        }

    n = draw(st.integers(0, 3))
    return {"t": draw(finite), "floor": draw(number), "bumps": [bump() for _ in range(n)]}


@st.composite
def velocities_for(draw: st.DrawFn, vertices: list) -> list[list[float]]:
    """Vertex velocities from still to 1 km/s (which turns most domains inside out)."""
    scale = draw(st.sampled_from([0.0, 0.1, 1.0, 1e3]))
    speed = st.floats(-1.0, 1.0).map(lambda v: scale * v)
    k = len(vertices)
    return draw(st.lists(st.tuples(speed, speed).map(list), min_size=k, max_size=k))


@st.composite
def wire_maps(draw: st.DrawFn, kind: str) -> dict:
    """A valid-looking wire map of ``kind`` with plausible, extreme or corrupted values."""
    if kind == "pose":
        d = {"id": draw(ids), "x": draw(coords), "y": draw(coords), "theta": draw(finite)}
        d |= {"seq": draw(st.integers(0, 2**40))}
    elif kind == "state":
        neighbors = st.lists(st.integers(0, 20), max_size=8, unique=True)
        stats = st.dictionaries(st.text(min_size=1, max_size=8), finite, max_size=4)
        d = {"id": draw(ids), "x": draw(coords), "y": draw(coords)}
        d |= {"neighbors": draw(neighbors), "stats": draw(stats)}
    elif kind == "beacon":
        d = {"id": draw(ids), "x": draw(coords), "y": draw(coords)}
    else:
        vertices = draw(polygons)
        d = {"seq": draw(st.integers(0, 100)), "t": draw(finite), "vertices": vertices}
        d |= {"state": draw(st.sampled_from(protocol.STATES)), "kappa": draw(st.floats(1e-3, 1e3))}
        d |= {"velocities": draw(velocities_for(vertices))}
        if draw(st.booleans()):
            d["density"] = draw(densities())
    d = {"v": protocol.SCHEMA_VERSION, **d, "stamp": draw(stamps)}
    for _ in range(draw(st.integers(0, 2))):  # corruptions
        field = draw(st.sampled_from(sorted(d)))
        how = draw(st.sampled_from(["number", "type", "drop", "extra", "vertices"]))
        if how in SPOILS:
            spoil(draw, d, field, how)
        elif how == "extra":
            d["zz"] = draw(st.one_of(bad_numbers, wrong_types))
        else:
            n = draw(st.sampled_from([0, 1, 65, 5000]))
            d["vertices"] = [[float(i), float(i * i)] for i in range(n)]
    return d


def pack(d: dict) -> bytes:
    try:
        return msgpack.packb(d, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return b"\xc1"  # not representable in msgpack: send the reserved byte instead


KINDS = ("pose", "state", "beacon", "domain")


@st.composite
def inputs(draw: st.DrawFn) -> tuple[str, bytes, int | None]:
    """(kind, payload, id in the key) as a Pack hands them to AgentBrain.receive."""
    kind = draw(st.sampled_from(KINDS))
    source = draw(st.sampled_from(["map", "map", "map", "bytes", "big"]))
    if source == "bytes":
        payload = draw(st.binary(max_size=64))
    elif source == "big":
        payload = bytes(protocol.MAX_PAYLOAD + 1)
    else:
        payload = pack(draw(wire_maps(kind)))
    key_id = None if kind == "domain" else draw(st.one_of(ids, st.just(None)))
    return kind, payload, key_id


# --- decoders ---------------------------------------------------------------------------

DECODERS = {
    "pose": protocol.Pose,
    "state": protocol.AgentState,
    "beacon": protocol.Beacon,
    "domain": protocol.Domain,
}


@FUZZ
@given(st.data())
def test_decoders_accept_or_give_a_reason(data: st.DataObject) -> None:
    kind, payload, _ = data.draw(inputs())
    try:
        message = DECODERS[kind].decode(payload)
    except protocol.ProtocolError as exc:
        assert exc.reason in protocol.REASONS and str(exc)
        return
    assert DECODERS[kind].decode(message.encode()) == message


# --- agent --------------------------------------------------------------------------------


def assert_sendable(brain: AgentBrain, now: float) -> None:
    """One control step and everything the agent would publish after it."""
    decision = brain.step(now, WALL)
    command = brain.command(decision, WALL)  # constructing it validates the wire ranges
    for speed in (decision.left, decision.right, command.left, command.right):
        assert math.isfinite(speed) and abs(speed) <= ROBOT.max_wheel_speed + 1e-12
    state = brain.agent_state(WALL)
    if state is not None:
        assert protocol.AgentState.decode(state.encode()) == state
    beacon = brain.beacon(now, WALL)
    if beacon is not None:
        protocol.Beacon.decode(beacon[1].encode())


def refusal(kind: str, payload: bytes, key_id: int | None, config: AgentConfig) -> str | None:
    """Why the wire contract refuses this input (the protocol's own decoder and stamp policy,
    not the agent's decoding cache), or None."""
    try:
        message = DECODERS[kind].decode(payload)
        max_age = config.beacon_timeout if kind == "beacon" else config.stale_timeout
        check_stamp(message.stamp, WALL, max_age, config.max_clock_skew)
    except protocol.ProtocolError as exc:
        return exc.reason
    if key_id is not None and message.id != key_id:
        return "wrong_id"
    return None


@FUZZ
@given(st.lists(inputs(), min_size=1, max_size=12), st.booleans())
def test_agent_survives_any_input(messages: list, seeded: bool) -> None:
    brain = AgentBrain(ME, AgentConfig(robot=ROBOT))
    if seeded:  # a working agent, so that the control law runs on whatever gets through
        own = protocol.Pose(id=ME, x=0.5, y=0.5, theta=0.0, stamp=WALL, seq=0)
        square = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
        domain = protocol.Domain(
            seq=0, stamp=WALL - 0.1, t=0.0, state="running", vertices=square,
            velocities=[[0.1, 0.0]] * 4, kappa=1.0,
        )  # fmt: skip
        assert brain.receive("pose", own.encode(), 0.0, WALL, ME)
        assert brain.receive("domain", domain.encode(), 0.0, WALL)
    received = brain.counters.received
    for step, (kind, payload, key_id) in enumerate(messages):
        before = dict(brain.drops.counts)
        accepted = brain.receive(kind, payload, 0.01 * step, WALL, key_id)
        added = {r: n - before.get(r, 0) for r, n in brain.drops.counts.items()}
        added = {r: n for r, n in added.items() if n}
        reason = refusal(kind, payload, key_id, brain.config)
        if reason is not None:  # the wire contract refuses it: dropped, counted once, so named
            assert not accepted and added == {reason: 1}, (reason, added)
        elif accepted:
            assert added == {}
        else:  # valid on the wire, refused for its meaning (an old domain, our own state)
            assert sum(added.values()) <= 1 and set(added) <= {"old_domain", "bad_domain"}
        assert_sendable(brain, 0.01 * step)
    assert brain.counters.received == received + len(messages)


@FUZZ
@given(
    st.lists(
        st.tuples(st.integers(ME + 1, 12), st.floats(-5.0, 5.0), st.floats(-5.0, 5.0)),
        max_size=10,
    ),
    convex_polygons(),
    st.data(),
)
def test_agent_decoded_extremes(others: list, vertices: list, data: st.DataObject) -> None:
    """Valid but extreme messages through the typed path: coincident and far robots, huge
    and tiny domains, fast vertices, large gains."""
    brain = AgentBrain(ME, AgentConfig(robot=ROBOT))
    me = data.draw(st.tuples(coords, coords, st.floats(-1e4, 1e4)))
    brain.on_pose(protocol.Pose(id=ME, x=me[0], y=me[1], theta=me[2], stamp=WALL, seq=0), 0.0)
    for rid, x, y in others:
        brain.on_pose(protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=WALL, seq=0), 0.0)
    brain.on_pose(protocol.Pose(id=99, x=me[0], y=me[1], theta=0.0, stamp=WALL, seq=0), 0.0)
    domain = protocol.Domain(
        seq=0,
        stamp=data.draw(st.floats(WALL - 2.0, WALL)),
        t=0.0,
        state="running",
        vertices=vertices,
        velocities=data.draw(velocities_for(vertices)),
        kappa=data.draw(st.floats(1e-3, 1e3)),
        density=data.draw(st.one_of(st.none(), densities())),
    )
    brain.on_domain(domain, 0.0)
    for k in range(3):
        assert_sendable(brain, 0.05 * k)


# --- robot --------------------------------------------------------------------------------


@st.composite
def commands(draw: st.DrawFn) -> bytes:
    """Raw WheelCommand payloads: valid (up to the 10 m/s wire limit), corrupted or noise."""
    speed = st.one_of(st.floats(-1.0, 1.0), st.floats(-10.0, 10.0))
    d = {
        "v": protocol.SCHEMA_VERSION,
        "id": draw(st.sampled_from([1, 1, 1, 2])),
        "left": draw(speed),
        "right": draw(speed),
        "stamp": draw(stamps),
        "seq": draw(st.integers(0, 100)),
        "pose_stamp": WALL,
    }
    how = draw(st.sampled_from(["valid", "valid", "number", "type", "drop", "extra", "bytes"]))
    field = draw(st.sampled_from(sorted(d)))
    if how in SPOILS:
        spoil(draw, d, field, how)
    elif how == "extra":
        d["zz"] = 1
    elif how == "bytes":
        return draw(st.binary(max_size=64))
    return pack(d)


@FUZZ
@given(st.lists(st.tuples(commands(), st.floats(0.0, 2.0)), min_size=1, max_size=30))
def test_robot_pose_stays_finite_and_bounded(script: list) -> None:
    sim = RobotSim(1, (0.0, 0.0, 0.0), robot=ROBOT, cmd_timeout=0.5)
    now = 0.0
    for payload, dt in script:
        sim.on_command(payload, now, WALL)
        before = sim.pose.copy()
        now += dt
        pose = sim.step(now)
        assert np.all(np.isfinite(pose))
        moved = float(np.hypot(*(pose[:2] - before[:2])))
        assert moved <= ROBOT.max_wheel_speed * min(dt, sim.cmd_timeout) + 1e-9
        sim.pose_message(WALL, 0)  # always publishable
