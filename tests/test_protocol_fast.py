"""The fast path of message checking refuses exactly what the field-by-field checkers refuse.

Every message type's __init__ tests its number fields in one compiled expression
(protocol.messages._compile_init) and leaves any message failing it to the checkers. Here
random messages, each field the valid value or an adversarial one (NaN, infinities, values
just past a bound, huge ints, booleans, numpy scalars, ints for floats, strings, None,
arrays and maps where numbers belong, and the same inside ids, relays, stats and
vertices), go through the reference (the checkers alone, Message._fill_checked with the
fast paths inside the checkers of ids, relays and stats turned off), through
construction, through _from_map and through real msgpack bytes (decode, and readers of some
of the fields, Message.reader): all must accept with the same fields (same types too) or
refuse with the same reason and message.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from unittest.mock import patch

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from covswarm import protocol
from covswarm.protocol import messages
from covswarm.protocol.steering import SteerReply, SteerRequest

WALL = 1.7e9
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]

# Valid field values of each type (all fields, optional ones set).
VALID: dict[type[protocol.Message], dict] = {
    protocol.Pose: {"id": 3, "x": 1.0, "y": -2.0, "theta": 0.5, "stamp": WALL, "seq": 7},
    protocol.WheelCommand: {
        "id": 3, "left": 0.1, "right": -0.2, "stamp": WALL, "seq": 7, "pose_stamp": WALL - 0.1
    },
    protocol.Beacon: {"id": 3, "x": 1.0, "y": -2.0, "stamp": WALL},
    protocol.AgentState: {
        "id": 3, "x": 1.0, "y": -2.0, "stamp": WALL, "neighbors": [4, 1],
        "stats": {"rate_hz": 9.5, "rx_total": 12}, "vx": 0.1, "vy": -0.1,
        "relay": [[4, 1.5, 2.5, 0.0, 0.2], [1, -1.0, 0.5, 0.1, 0.0]],
    },
    protocol.Domain: {
        "seq": 2, "stamp": WALL, "t": 1.5, "state": "running", "vertices": SQUARE,
        "velocities": [[0.1, 0.0]] * 4, "kappa": 1.0, "density": None, "tile_size": 2.0,
        "start_velocities": [[0.0, 0.2]] * 4,
    },
    protocol.Status: {
        "stamp": WALL, "t": 1.5, "state": "running", "error": 0.25, "alive_agents": 4,
        "alive_robots": 4, "route": [[0.0, 0.0, 1.0], [1.0, 1.0, 1.0, 0.5]], "pace": 0.5,
        "script_t": 1.0,
    },
    SteerRequest: {
        "kind": "translate", "dx": 1.0, "dy": 0.0, "angle": 0.0, "factor": 1.0,
        "polygon": None, "about": None, "duration": 2.0, "speed": None, "goal": None,
    },
    SteerReply: {"accepted": True, "reason": "", "duration": 1.0, "route": [[0.0, 0.0, 1.0]]},
}  # fmt: skip

NUMBERS = [
    math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0, -0.0, 1, -1, 0, 2**63, 2**64 + 1,
    -(2**63), messages.MAX_ID, messages.MAX_ID + 1, messages.MAX_COORD, -messages.MAX_COORD,
    math.nextafter(messages.MAX_COORD, math.inf), messages.MAX_SPEED,
    math.nextafter(messages.MAX_SPEED, math.inf), messages.MAX_STAT, 2 * messages.MAX_STAT,
    messages.MAX_SEQ, 5e-324, 1.0, 0.5,
]  # fmt: skip
NUMPY = [np.float64(0.5), np.float64(math.nan), np.int64(3), np.float32(0.25), np.bool_(True)]
OTHERS = [True, False, None, "1.0", "", "x" * 40, b"\x01", [], [1.0, 2.0], {}, {"a": 1}]
ATOMS = NUMBERS + NUMPY + OTHERS
BAD_KEYS = ["", "y" * (messages.MAX_STAT_NAME + 1), 5, 1.5, None, b"k", True]
atoms = st.sampled_from(ATOMS)
numbers = st.sampled_from(NUMBERS)


def _mutated_list(valid: list, inner: st.SearchStrategy) -> st.SearchStrategy:
    """``valid`` with one entry replaced, dropped or duplicated, or an entry added."""
    n = len(valid)
    return st.one_of(
        st.builds(lambda i, v: [*valid[:i], v, *valid[i + 1 :]], st.integers(0, n - 1), inner),
        st.builds(lambda i: valid[:i] + valid[i + 1 :], st.integers(0, n - 1)),
        st.builds(lambda i: [*valid, valid[i]], st.integers(0, n - 1)),
        st.builds(lambda v: [*valid, v], inner),
        st.just(tuple(valid)),
    )


def _mutated_entry(entry: list) -> st.SearchStrategy:
    return st.one_of(
        st.builds(
            lambda i, v: [*entry[:i], v, *entry[i + 1 :]], st.integers(0, len(entry) - 1), atoms
        ),
        st.just(entry[:-1]),
        st.just([*entry, 0.0]),
        st.just(tuple(entry)),
        st.just(np.array(entry)),
    )


def _field(valid: object) -> st.SearchStrategy:
    """The valid value, an atom, or (for arrays and maps) the valid one spoilt inside."""
    options = [st.just(valid), atoms]
    if isinstance(valid, list) and valid:
        first = valid[0]
        inner = _mutated_entry(first) if isinstance(first, list) else atoms
        options.append(_mutated_list(valid, inner))
        if len({len(entry) if isinstance(entry, list) else 0 for entry in valid}) == 1:
            options.append(st.just(np.array(valid)))  # a sender's numpy array
    if isinstance(valid, dict) and valid:
        options.append(st.builds(lambda v: {**valid, "rate_hz": v}, atoms))
        options.append(st.builds(lambda k: {**valid, k: 1.0}, st.sampled_from(["", "y" * 33])))
        options.append(st.just({**valid, 5: 1.0}))
    return st.one_of(*options)


def _outcome(make) -> tuple:
    """("ok", the fields' repr, which tells 1 from 1.0 and numpy scalars from floats) or
    ("refused", reason, message)."""
    try:
        message = make()
    except protocol.ProtocolError as exc:
        return ("refused", exc.reason, str(exc))
    return ("ok", repr(tuple(getattr(message, name) for name in message._SPEC)))


def _slow_fill(cls: type[protocol.Message], values: dict) -> protocol.Message:
    """A message with each field set to its checker's verdict on ``values``, by the checkers
    alone: with the fast paths inside the checkers of ids, relays and stats turned off."""
    message = object.__new__(cls)
    with (
        patch.object(messages, "_plain_ids", lambda value, max_n: None),
        patch.object(messages, "_plain_relay", lambda value, max_n: False),
        patch.object(messages, "_plain_stats", lambda value: False),
    ):
        message._fill_checked(values)
    return message


def _reference(cls: type[protocol.Message], values: dict) -> protocol.Message:
    """The message of ``values`` by the field-by-field checkers alone (the slow path)."""
    message = _slow_fill(cls, values)
    message._check_fields()
    return message


def _fast(cls: type[protocol.Message], values: dict) -> bool:
    """Whether constructing ``cls`` of ``values`` takes the fast path: the checkers alone
    (Message._fill_checked) are not called; False too when it raises."""
    with patch.object(messages.Message, "_fill_checked", side_effect=AssertionError) as slow:
        try:
            cls(**values)
        except (protocol.ProtocolError, AssertionError):
            return False
    return not slow.called


# The types a reader can read (Message.reader): no checks across fields.
READABLE = [cls for cls in VALID if cls._check_fields is protocol.Message._check_fields]


def _read_outcome(read, payload: bytes) -> tuple:
    """("ok", the repr of the values the reader ``read`` returns) or ("refused", ...)."""
    try:
        values = read(payload)
    except protocol.ProtocolError as exc:
        return ("refused", exc.reason, str(exc))
    return ("ok", repr(values))


def _decode_outcome(cls: type[protocol.Message], names: list[str], payload: bytes) -> tuple:
    """_read_outcome's, of the message decode returns."""
    try:
        message = cls.decode(payload)
    except protocol.ProtocolError as exc:
        return ("refused", exc.reason, str(exc))
    return ("ok", repr(tuple(getattr(message, name) for name in names)))


FAST = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)


@pytest.mark.parametrize("cls", list(VALID), ids=lambda cls: cls.__name__)
@given(data=st.data())
@FAST
def test_fast_path_refuses_what_the_checkers_refuse(cls, data: st.DataObject) -> None:
    valid = VALID[cls]
    values = {
        name: data.draw(_field(value) if data.draw(st.booleans()) else st.just(value), name)
        for name, value in valid.items()
    }
    expected = _outcome(lambda: _reference(cls, values))
    assert _outcome(lambda: cls(**values)) == expected
    assert _outcome(lambda: cls._from_map({"v": protocol.SCHEMA_VERSION, **values})) == expected
    try:
        payload = msgpack.packb({"v": protocol.SCHEMA_VERSION, **values}, use_bin_type=True)
    except (TypeError, ValueError, OverflowError):
        return  # numpy values and ints beyond 64 bits: not on the wire
    try:
        unpacked = msgpack.unpackb(payload, raw=False, strict_map_key=True, use_list=False)
    except ValueError:  # a map with a key that is not a string
        assert _outcome(lambda: cls.decode(payload))[:2] == ("refused", "undecodable")
        return
    unpacked.pop("v")
    decoded = _outcome(lambda: cls.decode(payload))
    assert decoded == _outcome(lambda: _reference(cls, unpacked))
    if cls in READABLE:
        names = data.draw(st.lists(st.sampled_from(list(cls._SPEC)), min_size=1, unique=True))
        read = cls.reader(*names)
        assert _read_outcome(read, payload) == _decode_outcome(cls, names, payload)


@pytest.mark.parametrize("cls", list(VALID), ids=lambda cls: cls.__name__)
def test_fast_path_takes_only_numbers_the_checkers_return_unchanged(cls) -> None:
    """Each adversarial value in each number field: the fast test takes the message only if
    the checkers accept it and return the value unchanged (same type), and the outcome is
    the reference's; for valid messages it does take them (so that the test above tests
    the fast path, not only the slow one)."""
    valid = VALID[cls]
    assert _fast(cls, valid)
    names = [name for name, check in cls._SPEC.items() if hasattr(check, "inline")]
    assert names
    for name in names:
        for value in ATOMS:
            values = {**valid, name: value}
            reference = _outcome(lambda values=values: _reference(cls, values))
            if _fast(cls, values):
                checked = getattr(_slow_fill(cls, values), name)
                assert type(checked) is type(value) and checked == value
            assert _outcome(lambda values=values: cls._from_map({"v": 1, **values})) == reference
            assert _outcome(lambda values=values: cls(**values)) == reference


def _spoilt_inside(valid: dict) -> list[dict]:
    """``valid`` with one number inside an array or map field replaced by each atom, at
    every position (every entry of a map, every number of the first entry of an array),
    or a map with an entry of a bad name added."""
    out = []
    for name, value in valid.items():
        if isinstance(value, dict):
            out += [{**valid, name: {**value, key: atom}} for key in value for atom in ATOMS]
            out += [{**valid, name: {**value, key: 1.0}} for key in BAD_KEYS]
        elif isinstance(value, list) and value and isinstance(value[0], list):
            for k in range(len(value[0])):
                for atom in ATOMS:
                    entry = [*value[0][:k], atom, *value[0][k + 1 :]]
                    out.append({**valid, name: [entry, *value[1:]]})
        elif isinstance(value, list) and value:
            out += [{**valid, name: [atom, *value[1:]]} for atom in ATOMS]
    return out


@pytest.mark.parametrize("cls", list(VALID), ids=lambda cls: cls.__name__)
def test_fast_path_refuses_every_bad_number_inside(cls) -> None:
    """Each atom at every place inside ids, relays, stats, vertices and routes: the same
    outcome by construction, by _from_map and by the checkers alone; and, of the bytes, by
    a reader of any one field (one that leaves out an AgentState's relay checks it without
    building it) as by decode."""
    readers = {name: cls.reader(name) for name in cls._SPEC} if cls in READABLE else {}
    for values in _spoilt_inside(VALID[cls]):
        reference = _outcome(lambda values=values: _reference(cls, values))
        assert _outcome(lambda values=values: cls._from_map({"v": 1, **values})) == reference
        assert _outcome(lambda values=values: cls(**values)) == reference
        try:
            payload = msgpack.packb({"v": 1, **values}, use_bin_type=True)
        except (TypeError, ValueError, OverflowError):
            continue  # numpy values and ints beyond 64 bits: not on the wire
        for name, read in readers.items():
            assert _read_outcome(read, payload) == _decode_outcome(cls, [name], payload)


def test_no_reader_of_a_type_that_checks_across_fields_or_decodes_its_own_way() -> None:
    """A reader checks field by field: of a Domain (velocities as many as vertices) or a
    World (its own compact decode) it would accept what decode refuses."""
    for cls in (protocol.Domain, protocol.World):
        with pytest.raises(TypeError):
            cls.reader("seq")
    with pytest.raises(ValueError):
        protocol.Pose.reader("z")


def test_decoded_stats_and_relay_are_copies() -> None:
    """The fast paths return new containers: a sender mutating its map or list afterwards
    does not change the message."""
    stats = {"rate_hz": 9.5}
    relay = [[4, 1.5, 2.5, 0.0, 0.2]]
    state = protocol.AgentState(
        id=3, x=1.0, y=2.0, stamp=WALL, neighbors=[4], stats=stats, relay=relay
    )
    stats["rate_hz"] = math.nan
    relay[0][1] = math.nan
    assert state.stats == {"rate_hz": 9.5}
    assert state.relay == ((4, 1.5, 2.5, 0.0, 0.2),)


@pytest.mark.parametrize("value", [np.float64(1.25), np.float64(math.nan), np.float64(2e4)])
def test_numpy_floats_of_a_sender_take_the_checkers_path(value: np.float64) -> None:
    """A sender's float64 (a float subclass) is no plain float: the checkers judge it, and a
    message then holds the float it becomes (the brain passes plain floats)."""
    values = {**VALID[protocol.Pose], "x": value}
    assert not _fast(protocol.Pose, values)
    assert _outcome(lambda: protocol.Pose(**values)) == _outcome(
        lambda: _reference(protocol.Pose, values)
    )
    if math.isfinite(value) and abs(value) <= messages.MAX_COORD:
        assert type(protocol.Pose(**values).x) is float


@pytest.mark.parametrize("cls", list(VALID), ids=lambda cls: cls.__name__)
def test_encode_packs_the_fields_in_order(cls) -> None:
    """encode's compiled map is the schema version and the fields in order, an optional
    one left out when None, packed as msgpack.packb packs it; and decodes back."""
    for values in ({**VALID[cls]}, {name: value for name, value in VALID[cls].items()
                                    if name not in cls._OPTIONAL}):  # fmt: skip
        message = cls(**values)
        wire = {"v": protocol.SCHEMA_VERSION}
        for name in message._SPEC:
            value = getattr(message, name)
            if value is not None or name not in cls._OPTIONAL:
                wire[name] = value
        assert message.encode() == msgpack.packb(wire, use_bin_type=True)
        assert cls.decode(message.encode()) == message


def test_encode_from_threads_at_once() -> None:
    """Each thread packs with its own Packer: threads encoding at once get their own bytes,
    and a Packer that failed packs the next message from a clean buffer."""
    with pytest.raises(TypeError):
        messages._pack({"x": object()})
    poses = [protocol.Pose(id=i % 1000, x=i * 1e-3, y=-1.0, theta=0.0, stamp=WALL, seq=i)
             for i in range(3000)]  # fmt: skip

    def encode_all(offset: int) -> list[bool]:
        return [
            protocol.Pose.decode(poses[(i + offset) % len(poses)].encode())
            == poses[(i + offset) % len(poses)]
            for i in range(len(poses))
        ]

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(encode_all, [0, 700, 1400, 2100]))
    assert all(all(ok) for ok in results)


@pytest.mark.parametrize("cls", list(VALID), ids=lambda cls: cls.__name__)
def test_decode_refuses_missing_and_unknown_fields(cls) -> None:
    """Any set of fields with an unknown one added or not: refused ("schema") exactly when a
    required field is missing or an unknown one is present, missing ones named first; the
    optional ones may each be left out."""
    valid = VALID[cls]
    names = list(valid)
    for drop in [(), *[(name,) for name in names], tuple(cls._OPTIONAL)]:
        for extra in ({}, {"extra": 1.0}):
            fields = {k: v for k, v in valid.items() if k not in drop} | extra
            payload = msgpack.packb({"v": protocol.SCHEMA_VERSION, **fields})
            missing = [name for name in names if name in drop and name not in cls._OPTIONAL]
            if missing:
                expected = ("refused", "schema", f"{cls.__name__}: missing fields {missing}")
            elif extra:
                expected = ("refused", "schema", f"{cls.__name__}: unknown fields 'extra'")
            else:
                expected = _outcome(lambda fields=fields: cls(**fields))
                assert expected[0] == "ok"
            assert _outcome(lambda payload=payload: cls.decode(payload)) == expected


def test_a_running_pack_builds_and_decodes_on_the_fast_path() -> None:
    """What a running pack of brains builds (commands, AgentStates with neighbours, relays
    and stats, beacons) and decodes is of plain, in-range numbers: none of it goes through
    the checkers alone (Message._fill_checked), as a brain's numpy float would."""
    from covswarm.agent.brain import AgentBrain
    from covswarm.agent.pack import LocalBus, Pack
    from covswarm.deploy.bench import BRAIN_TICK_WALL, brain_tick_domain, make_layout

    n, swarm = 30, "fast"
    layout = make_layout(n, "cvt", 0)
    bus = LocalBus()
    pack = Pack(bus, swarm, [AgentBrain(i) for i in range(n)])
    slow = AssertionError("the checkers' path")
    with patch.object(messages.Message, "_fill_checked", side_effect=slow):
        for k in range(15):
            t = k * 0.1
            bus.put(protocol.domain_key(swarm), brain_tick_domain(layout, t, k + 1))
            for rid, (x, y) in enumerate(layout.positions.tolist()):
                stamp = BRAIN_TICK_WALL + t
                pose = protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=stamp, seq=k)
                bus.put(protocol.pose_key(swarm, rid), pose.encode())
            pack.tick(lambda t=t: t, lambda t=t: BRAIN_TICK_WALL + t, math.inf)
    sent = {
        kind: [p for key, p in bus.sent if key.endswith(f"/{kind}")] for kind in ("cmd", "state")
    }
    states = [protocol.AgentState.decode(payload) for payload in sent["state"]]
    assert len(sent["cmd"]) == 15 * n and states
    assert any(s.relay for s in states) and any(s.stats for s in states)
    assert any(s.neighbors for s in states) and any(s.vx for s in states)
    assert any(protocol.WheelCommand.decode(c).left for c in sent["cmd"])
    assert any("/beacon/" in key for key, _ in bus.sent)


def test_a_message_type_must_be_a_slotted_dataclass() -> None:
    """A message type whose fields are not slots (set where the compiled __init__ sets
    them) refuses to construct, rather than construct unchecked."""
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Loose(protocol.Message):
        id: int

    with pytest.raises(TypeError, match="slots=True"):
        Loose(3)
    assert protocol.Pose(**VALID[protocol.Pose]).id == 3
