"""Message types of the covswarm wire protocol: msgpack maps with a schema version.

Every message is a frozen dataclass validated on construction (``__init__``), so an
invalid message can neither be decoded nor encoded: ``decode`` and the constructor raise
:class:`ProtocolError` (a ValueError) with the reason, and callers drop and count.

Validation is strict: payload size, schema version ``"v"``, every field present, **unknown
fields rejected** (a new field means a new SCHEMA_VERSION; silently ignoring one would hide
a version mismatch between processes; the one exception is an optional field, listed in
``_OPTIONAL``, which is left out of the payload when None and reads back as None when absent:
Domain's ``density`` joined version 1 that way, so uniform missions send the same bytes as
before and a peer that does not know densities refuses a Domain carrying one; Domain's
``tile_size``, AgentState's ``stats`` (sent once a second), ``vx``/``vy`` and ``relay``, and
Status's ``route`` work the same way), exact types
(bool is not a number), finite numbers, ids in 0..MAX_ID, vertex counts in 3..MAX_VERTICES
and magnitudes within sane bounds. Ints are accepted where floats are expected (other
languages' encoders drop ``.0``). Geometry (convexity) is not checked here: that is
covswarm.tvd.coverage.validate_polygon's job.

Checking is on every brain's hot path (a command and a state built, a pose and a state
decoded per period), so each message type compiles its number fields' checks into one
expression that takes the plain, in-range values (Message, _compile_init) and ids, relays
and stats take a plain loop first; anything else goes to the field-by-field checkers, which
give the verdict and the reason. Both refuse the same messages
(tests/test_protocol_fast.py). A receiver that reads a few fields of many messages takes
them with a reader (Message.reader), which checks every field as decode does but builds
no message, nor a field left out whose checker gives its verdict unbuilt (a relay).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
import threading
from collections.abc import Callable, Iterable
from dataclasses import MISSING, dataclass
from typing import Any, ClassVar, TypeVar

import msgpack

from covswarm.protocol.keys import MAX_ID

SCHEMA_VERSION = 1

MAX_PAYLOAD = 8192  # bytes; the largest valid message (64-vertex Domain) is ~2.4 kB
MAX_VERTICES = 64
MAX_NEIGHBORS = 256
MAX_RELAY = 64  # relayed neighbour positions per AgentState (~2.6 kB at most)
MAX_STATS = 64  # stat entries per AgentState (~2.8 kB, with 64 relays well under MAX_PAYLOAD)
MAX_STAT_NAME = 32
MAX_COORD = 1.0e4  # m: positions and vertices
MAX_SPEED = 1.0e2  # m/s: velocities an agent reports
MAX_ANGLE = 1.0e4  # rad: headings need not be wrapped, but must be bounded
MAX_WHEEL_SPEED = 10.0  # m/s on the wire; the robot clamps to its own, lower limit
MAX_VERTEX_SPEED = 1.0e3  # m/s
MAX_KAPPA = 1.0e3
MAX_STAMP = 1.0e11  # s since the epoch
MAX_TIME = 1.0e9  # s of mission time
MAX_SEQ = 2**63 - 1
MAX_STAT = 1.0e15
STATES = ("waiting", "running", "done")
MAX_BUMPS = 16  # density bumps in a Domain (covswarm.tvd.density.MAX_BUMPS)
MAX_DENSITY = 1.0e6  # bound on every number of a density (floor, weights, moments, rates)
MAX_TILE_SIZE = 1.0e3  # m
DEFAULT_TILE_SIZE = 1.0  # m: beacon tiles of a swarm whose Domain does not say


# Short codes of ProtocolError.reason, so receivers can count drops per reason.
REASONS = ("oversize", "undecodable", "version", "schema", "nonfinite", "value")


class ProtocolError(ValueError):
    """A payload or message that violates the wire protocol; the message says why.

    ``reason`` is one of REASONS: "value" covers wrong types, shapes and out-of-range values.
    """

    def __init__(self, message: str, reason: str = "value") -> None:
        super().__init__(message)
        self.reason = reason


Checker = Callable[[Any, str], Any]


def _inline(check: Checker, test: str, real: bool = False) -> Checker:
    """``check`` with ``test``: a Python expression in ``{v}`` that is true exactly when the
    value ``{v}`` is one ``check`` accepts *and returns unchanged* (canonical already). Each
    message type compiles the tests of its fields into one expression (Message's fast
    path); a value failing it goes through ``check`` for the verdict and the reason.
    ``real``: ``check`` returns float(value) for any float (numpy's float64 is one), so the
    fast path may test that instead."""
    check.inline = test  # type: ignore[attr-defined]
    check.real = real  # type: ignore[attr-defined]
    return check


def _real(lo: float, hi: float) -> Checker:
    """A finite number in [lo, hi], returned as float."""

    def check(value: Any, name: str) -> float:
        # Plain floats and ints take one type test and one chained comparison (NaN and inf
        # fail it and are sorted out below); the ABC test (numpy scalars on the sending
        # side) only runs for others.
        kind = type(value)
        if kind is float or kind is int:
            out = float(value)
            if lo <= out <= hi:
                return out
        elif isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ProtocolError(f"{name}: expected a number, got {type(value).__name__}")
        out = float(value)
        if not math.isfinite(out):
            raise ProtocolError(f"{name}: not finite ({out})", "nonfinite")
        if not lo <= out <= hi:
            raise ProtocolError(f"{name}: {out} outside [{lo}, {hi}]")
        return out

    # A float (not an int, which check converts) within finite bounds: NaN fails the
    # comparisons, and so does an infinity.
    assert math.isfinite(lo) and math.isfinite(hi)
    test = f"type({{v}}) is float and {float(lo)!r} <= {{v}} <= {float(hi)!r}"
    return _inline(check, test, real=True)


def _positive(hi: float) -> Checker:
    """A finite number in (0, hi]."""
    bounded = _real(0.0, hi)

    def check(value: Any, name: str) -> float:
        out = bounded(value, name)
        if out <= 0.0:
            raise ProtocolError(f"{name}: must be > 0, got {out}")
        return out

    return _inline(check, f"type({{v}}) is float and 0.0 < {{v}} <= {float(hi)!r}", real=True)


def _int(lo: int, hi: int) -> Checker:
    """An int in [lo, hi] (numpy integers accepted on the sending side)."""

    def check(value: Any, name: str) -> int:
        if type(value) is int:  # the common case, without the ABC test (see _real)
            out = value
        elif isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ProtocolError(f"{name}: expected an int, got {type(value).__name__}")
        else:
            out = int(value)
        if not lo <= out <= hi:
            raise ProtocolError(f"{name}: {out} outside [{lo}, {hi}]")
        return out

    # type(...) is int excludes bool, a subclass of int.
    return _inline(check, f"type({{v}}) is int and {int(lo)!r} <= {{v}} <= {int(hi)!r}")


def _optional(inner: Checker) -> Checker:
    """None, or whatever ``inner`` accepts."""

    def check(value: Any, name: str) -> Any:
        return None if value is None else inner(value, name)

    check.inner = inner  # type: ignore[attr-defined]  # _compile_init's: a call less
    test = getattr(inner, "inline", None)
    if test is None:
        return check
    return _inline(check, f"{{v}} is None or ({test})", inner.real)  # type: ignore[attr-defined]


def _choice(options: tuple[str, ...]) -> Checker:
    def check(value: Any, name: str) -> str:
        if not isinstance(value, str) or value not in options:
            raise ProtocolError(f"{name}: expected one of {options}, got {value!r}")
        return value

    return check


def _sequence(value: Any, name: str) -> list[Any] | tuple[Any, ...]:
    """A list/tuple (or, when sending, anything with ``tolist`` such as a numpy array), as
    it is: checkers read it and build their own."""
    if type(value) is list or type(value) is tuple:  # msgpack's arrays, without hasattr
        return value
    if hasattr(value, "tolist") and not isinstance(value, (list, tuple)):
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        raise ProtocolError(f"{name}: expected an array, got {type(value).__name__}")
    return list(value)


def _points(min_n: int, max_n: int, bound: float) -> Checker:
    """A list of [x, y] pairs, returned as a tuple of float pairs."""
    coord = _real(-bound, bound)

    def check(value: Any, name: str) -> tuple[tuple[float, float], ...]:
        items = _sequence(value, name)
        if not min_n <= len(items) <= max_n:
            raise ProtocolError(f"{name}: {len(items)} points, expected {min_n}..{max_n}")
        out = []
        for i, item in enumerate(items):
            pair = _sequence(item, f"{name}[{i}]")
            if len(pair) != 2:
                raise ProtocolError(f"{name}[{i}]: expected [x, y], got {len(pair)} values")
            out.append((coord(pair[0], f"{name}[{i}].x"), coord(pair[1], f"{name}[{i}].y")))
        return tuple(out)

    return check


def _plain_ids(value: Any, max_n: int) -> tuple[int, ...] | None:
    """The ids as _ids's checker of at most ``max_n`` returns them if ``value`` holds them
    as plain ints in range, distinct, in a tuple (msgpack's), list or set (a sender's): the
    common case, without a checker call per id; else None, and the checker finds the
    reason. A plain loop: faster than all() over a generator or passes of map()."""
    kind = type(value)
    if (
        kind is not tuple and kind is not list and kind is not set and kind is not frozenset
    ) or len(value) > max_n:
        return None
    for item in value:
        if type(item) is not int or not 0 <= item <= MAX_ID:
            return None
    unique = set(value)
    return tuple(sorted(unique)) if len(unique) == len(value) else None


def _ids(max_n: int) -> Checker:
    """A list of distinct robot ids, returned as a sorted tuple."""
    one = _int(0, MAX_ID)

    def check(value: Any, name: str) -> tuple[int, ...]:
        if (fast := _plain_ids(value, max_n)) is not None:
            return fast
        # Senders may pass a set of ids (msgpack never decodes to one).
        items = _sequence(list(value) if isinstance(value, (set, frozenset)) else value, name)
        if len(items) > max_n:
            raise ProtocolError(f"{name}: {len(items)} ids, at most {max_n}")
        ids = [one(item, f"{name}[{i}]") for i, item in enumerate(items)]
        if len(set(ids)) != len(ids):
            raise ProtocolError(f"{name}: duplicate ids")
        return tuple(sorted(ids))

    return check


def _plain_relay(value: Any, max_n: int) -> bool:
    """Whether _relay's checker of at most ``max_n`` entries takes ``value`` as it is: what
    every receiver decodes at the control rate from each neighbour (msgpack arrays of an
    int and four floats, which Message.decode unpacks as tuples, as an agent builds its
    own), in bounds, of distinct ids; if not, the checker finds the reason. One type test
    and chained comparison per number (NaN fails it)."""
    kind = type(value)
    if (kind is not tuple and kind is not list) or len(value) > max_n:
        return False
    xlo, xhi, vlo, vhi = -MAX_COORD, MAX_COORD, -MAX_SPEED, MAX_SPEED  # locals, once
    for entry in value:
        kind = type(entry)
        if kind is not tuple and kind is not list:
            return False
        try:  # of a list or tuple: unpacks exactly when it holds five values
            rid, x, y, vx, vy = entry
        except ValueError:
            return False
        if not (
            type(rid) is int
            and type(x) is float
            and type(y) is float
            and type(vx) is float
            and type(vy) is float
            and 0 <= rid <= MAX_ID
            and xlo <= x <= xhi
            and xlo <= y <= xhi
            and vlo <= vx <= vhi
            and vlo <= vy <= vhi
        ):
            return False
    return len({entry[0] for entry in value}) == len(value)


def _relay(max_n: int) -> Checker:
    """A list of [id, x, y, vx, vy] of distinct robots, returned as a tuple of tuples; its
    ``verify`` gives the verdict without building them (Message.reader)."""
    one = _int(0, MAX_ID)
    coord = _real(-MAX_COORD, MAX_COORD)
    speed = _real(-MAX_SPEED, MAX_SPEED)

    def check(value: Any, name: str) -> tuple[tuple[int, float, float, float, float], ...]:
        if _plain_relay(value, max_n):
            return tuple(map(tuple, value))  # tuple() of a tuple is itself
        items = _sequence(value, name)
        if len(items) > max_n:
            raise ProtocolError(f"{name}: {len(items)} entries, at most {max_n}")
        out = []
        for i, item in enumerate(items):
            entry = _sequence(item, f"{name}[{i}]")
            if len(entry) != 5:
                raise ProtocolError(
                    f"{name}[{i}]: expected [id, x, y, vx, vy], got {len(entry)} values"
                )
            rid, x, y, vx, vy = entry
            where = f"{name}[{i}]"
            out.append(
                (
                    one(rid, f"{where}.id"),
                    coord(x, f"{where}.x"),
                    coord(y, f"{where}.y"),
                    speed(vx, f"{where}.vx"),
                    speed(vy, f"{where}.vy"),
                )
            )
        if len({entry[0] for entry in out}) != len(out):
            raise ProtocolError(f"{name}: duplicate ids")
        return tuple(out)

    def verify(value: Any, name: str) -> None:
        if not _plain_relay(value, max_n):
            check(value, name)

    check.verify = verify  # type: ignore[attr-defined]
    return check


def _plain_stats(value: dict[Any, Any]) -> bool:
    """Whether _stats would return the map ``value`` as it is: names of plain str of
    1..MAX_STAT_NAME characters, values plain floats and ints within +-MAX_STAT (stricter
    than ints need; NaN and infinities fail the comparison)."""
    for key, item in value.items():
        kind = type(item)
        if not (
            type(key) is str
            and 1 <= len(key) <= MAX_STAT_NAME
            and (kind is float or kind is int)
            and -MAX_STAT <= item <= MAX_STAT
        ):
            return False
    return True


def _stats(value: Any, name: str) -> dict[str, float | int]:
    """Small flat map of named numbers (counters and measurements)."""
    if not isinstance(value, dict):
        raise ProtocolError(f"{name}: expected a map, got {type(value).__name__}")
    if len(value) > MAX_STATS:
        raise ProtocolError(f"{name}: {len(value)} entries, at most {MAX_STATS}")
    if _plain_stats(value):
        return dict(value)
    number = _real(-MAX_STAT, MAX_STAT)
    integer = _int(-MAX_SEQ, MAX_SEQ)
    out: dict[str, float | int] = {}
    for key, item in value.items():
        if not isinstance(key, str) or not 1 <= len(key) <= MAX_STAT_NAME:
            raise ProtocolError(f"{name}: bad entry name {key!r}")
        is_int = isinstance(item, numbers.Integral) and not isinstance(item, bool)
        out[key] = integer(item, key) if is_int else number(item, key)
    return out


_ID = _int(0, MAX_ID)
_COORD = _real(-MAX_COORD, MAX_COORD)
_STAMP = _real(0.0, MAX_STAMP)
_SEQ = _int(0, MAX_SEQ)
_TIME = _real(-MAX_TIME, MAX_TIME)

M = TypeVar("M", bound="Message")


def _unpack(payload: Any, limit: int = MAX_PAYLOAD, arrays: type = tuple) -> Any:
    """Bytes (or a zenoh ZBytes) -> msgpack object, ProtocolError on anything malformed or
    longer than ``limit`` bytes. Arrays become ``arrays`` (tuple or list): tuples by
    default, which unpack a little faster and which checkers keep as they are."""
    if type(payload) is bytes:  # the common case, without the isinstance tests below
        data = payload
    elif isinstance(payload, (bytes, bytearray, memoryview)):
        data = bytes(payload)
    elif hasattr(payload, "to_bytes"):  # zenoh.ZBytes
        data = payload.to_bytes()
    else:
        raise ProtocolError(f"payload: expected bytes, got {type(payload).__name__}", "undecodable")
    if len(data) > limit:
        raise ProtocolError(f"payload: {len(data)} bytes, limit {limit}", "oversize")
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=True, use_list=arrays is list)
    # msgpack signals malformed input with many exception types (ExtraData, FormatError,
    # StackError, UnicodeDecodeError, ValueError, ...): all of them mean "bad payload".
    except Exception as exc:
        raise ProtocolError(
            f"payload: not valid msgpack ({type(exc).__name__}: {exc})", "undecodable"
        ) from exc


def _field_checks(cls: type[Message]) -> tuple[dict[str, Any], list[str], str, dict[str, str]]:
    """What the functions compiled for the message type ``cls`` (_compile_init's,
    _compile_reader's) share: their namespace (``new``, ``cls`` and each field's checker
    c_<name>), the statements that read an unpacked map's values into locals named as the
    fields, the one test of the fields whose checkers have an ``inline`` test, and each
    field's value once it passed: the local itself (an inline field) or its checker's call
    (an optional field's without _optional's wrapper: a call less)."""
    spec = cls._SPEC
    assert all(name.isidentifier() and name not in ("self", "raw", "type") for name in spec)
    inline = {name: check.inline for name, check in spec.items() if hasattr(check, "inline")}
    test = " and ".join(f"({t.format(v=name)})" for name, t in inline.items()) or "True"
    namespace: dict[str, Any] = {"new": object.__new__, "cls": cls}
    reads, values = [], {}
    for name, check in spec.items():
        read = f"raw.get({name!r})" if name in cls._OPTIONAL else f"raw[{name!r}]"
        reads.append(f"    {name} = {read}")
        namespace[f"c_{name}"] = check
        values[name] = name if name in inline else f"c_{name}({name}, {name!r})"
        inner = getattr(check, "inner", None)  # an optional field's checker (_optional)
        if inner is not None and name not in inline:
            namespace[f"c_{name}"] = inner
            values[name] = f"None if {name} is None else {values[name]}"
    return namespace, reads, test, values


def _locals_map(names: Iterable[str]) -> str:
    """The source of a map of the locals ``names`` by name (Message._fill_checked's)."""
    return "{" + ", ".join(f"{name!r}: {name}" for name in names) + "}"


def _compile_init(cls: type[Message]) -> tuple[Callable[..., None], Callable[[dict], Message]]:
    """(``__init__``, ``decoded``) of the slotted dataclass ``cls`` (a message type):
    ``__init__`` in place of the one dataclass writes (the same parameters), ``decoded(raw)``
    the message of an unpacked map whose keys were checked (decode's); each field checked
    and set once.

    Both run the same code on the values: the fields whose checkers have an ``inline``
    test (the numbers: _real, _int, _positive, optional ones) are tested in one compiled
    expression. If all pass, they are set unchanged (their checkers would return them so)
    and the other fields set to their checkers' verdicts, in order, as the checkers alone
    (Message._fill_checked) would; otherwise the checkers alone set every field and find
    the reason. So both accept the same messages with the same fields and raise the same
    errors (tests/test_protocol_fast.py), and a message of plain, in-range numbers (what
    msgpack decodes, what a sender passes) takes no call per number. A sender's numpy
    floats, and ints for floats, take the checkers' path, which makes them floats.

    Fields are set through their slots' descriptors (a frozen dataclass refuses setattr),
    about twice as fast as object.__setattr__.
    """
    spec, fields = cls._SPEC, {info.name: info for info in dataclasses.fields(cls)}
    assert list(fields) == list(spec), f"{cls.__name__}: _SPEC must list the fields in order"
    namespace, reads, test, values = _field_checks(cls)
    params = []
    for name, info in fields.items():
        assert info.default_factory is MISSING, f"{cls.__name__}.{name}: no factories"
        # An absent optional field is None to decoded and the checkers: so is its default.
        assert name not in cls._OPTIONAL or info.default is None, f"{cls.__name__}.{name}"
        if info.default is MISSING:
            params.append(name)
        else:
            namespace[f"d_{name}"] = info.default
            params.append(f"{name}=d_{name}")
        namespace[f"s_{name}"] = cls.__dict__[name].__set__  # the slot's descriptor
    body = [f"    if {test}:"]
    body += [f"        s_{name}(self, {value})" for name, value in values.items()]
    body += ["    else:", f"        self._fill_checked({_locals_map(spec)})"]
    if cls._check_fields is not Message._check_fields:  # the base's checks nothing
        body += ["    self._check_fields()"]
    init = [f"def __init__(self, {', '.join(params)}):", *body]
    decoded = ["def decoded(raw):", "    self = new(cls)", *reads, *body, "    return self"]
    exec("\n".join([*init, *decoded]), namespace)
    namespace["__init__"].__qualname__ = f"{cls.__qualname__}.__init__"
    return namespace["__init__"], namespace["decoded"]


def _compile_reader(cls: type[Message], names: tuple[str, ...]) -> Callable[[Any], tuple]:
    """Message.reader's ``read`` for ``cls``: decode's code (_compile_init's ``decoded``)
    keeping the locals ``names`` rather than setting fields, and for a field it does not
    keep, calling its checker's ``verify`` if it has one (the verdict, the value unbuilt)."""
    spec = cls._SPEC
    if not names or not set(names) <= spec.keys():
        raise ValueError(f"{cls.__name__}: no fields {names}")
    # A check across fields takes the message, which read does not build (and read would
    # accept what decode refuses): not an assert, which python -O drops.
    own_decode = cls.decode.__func__ is not Message.decode.__func__  # type: ignore[attr-defined]
    if cls._check_fields is not Message._check_fields or own_decode:
        raise TypeError(f"{cls.__name__}: no reader (checks across fields, or its own decode)")
    assert all(name not in ("payload", "unpack", "checked") for name in spec)
    namespace, reads, test, values = _field_checks(cls)
    namespace.update(unpack=_unpack, checked=cls._checked_map)
    body = ["def read(payload):", "    raw = checked(unpack(payload))", *reads, f"    if {test}:"]
    for name, value in values.items():
        if value == name:  # an inline field: the test checked it
            continue
        if name in names:
            body.append(f"        {name} = {value}")
            continue
        verify = getattr(namespace[f"c_{name}"], "verify", None)
        if verify is not None:  # this namespace is read's own
            namespace[f"c_{name}"] = verify
        body.append(f"        {value}")
    body += [
        f"        return ({', '.join(names)},)",
        "    self = new(cls)",  # the checkers' verdicts and reason, as decoded's
        f"    self._fill_checked({_locals_map(spec)})",
        f"    return ({', '.join(f'self.{name}' for name in names)},)",
    ]
    exec("\n".join(body), namespace)
    return namespace["read"]


def _not_slotted(self: Message, *args: Any, **kwargs: Any) -> None:
    raise TypeError(f"{type(self).__name__}: a Message must be @dataclass(frozen=True, slots=True)")


def _compile_wire(spec: dict[str, Checker], optional: frozenset[str]) -> Callable:
    """``wire(message)``: the map Message.encode packs, the schema version and the fields
    of ``spec`` in order, an ``optional`` one left out when None; built in one expression
    rather than a loop over the fields."""
    required = ", ".join(f"{name!r}: message.{name}" for name in spec if name not in optional)
    lines = ["def wire(message):", f"    out = {{'v': {SCHEMA_VERSION!r}, {required}}}"]
    for name in spec:
        if name in optional:
            lines += [
                f"    if message.{name} is not None:",
                f"        out[{name!r}] = message.{name}",
            ]
    namespace: dict[str, Any] = {}
    exec("\n".join([*lines, "    return out"]), namespace)
    return namespace["wire"]


_PACKERS = threading.local()


def _pack(value: Any) -> bytes:
    """msgpack bytes of ``value``, by this thread's Packer: msgpack.packb builds a Packer per
    call, most of its cost for a small message (a Packer is not shared between threads,
    which may encode at once)."""
    try:
        packer = _PACKERS.packer
    except AttributeError:
        packer = _PACKERS.packer = msgpack.Packer(use_bin_type=True)
    return packer.pack(value)


class Message:
    """Base of all wire messages: schema-checked construction, encode and decode.

    Subclasses are frozen dataclasses whose fields are the wire fields (besides "v") and
    declare one checker per field in ``_SPEC``.

    Every brain builds a command and a state and decodes a pose and a state per period, so
    checking is on the hot path: each type's ``__init__`` (_compile_init) tests its number
    fields in one compiled expression, which takes the messages whose numbers are already
    plain in-range floats and ints, and leaves any other to the field-by-field checkers.
    Decoding runs the same code on the unpacked map (``_decoded``).
    """

    __slots__ = ()
    _SPEC: ClassVar[dict[str, Checker]]
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset()
    _REQUIRED: ClassVar[frozenset[str]]  # the fields not in _OPTIONAL
    _wire: ClassVar[Callable[[Message], dict[str, Any]]]
    _decoded: ClassVar[Callable[[dict[str, Any]], Message]]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "__dataclass_fields__" not in cls.__dict__:
            # The class statement's class: @dataclass(slots=True) makes it anew, with its
            # fields, and comes back here. One that is not made anew keeps this __init__
            # (dataclass does not replace an __init__ the class defines), which refuses.
            cls.__init__ = _not_slotted  # type: ignore[method-assign]
            return
        init, decoded = _compile_init(cls)
        cls.__init__, cls._decoded = init, staticmethod(decoded)  # type: ignore[method-assign]
        cls._wire = staticmethod(_compile_wire(cls._SPEC, cls._OPTIONAL))
        cls._REQUIRED = frozenset(cls._SPEC) - cls._OPTIONAL

    def _fill_checked(self, raw: dict[str, Any]) -> None:
        """Set every field to its checker's verdict on ``raw``'s value (None if absent):
        the slow path, which raises the first field's error."""
        for name, check in self._SPEC.items():
            object.__setattr__(self, name, check(raw.get(name), name))

    def _check_fields(self) -> None:
        """Checks across fields, after each field passed its own (override to add some)."""

    def encode(self) -> bytes:
        """msgpack bytes of this message, with the schema version."""
        return _pack(self._wire(self))

    @classmethod
    def decode(cls: type[M], payload: Any) -> M:
        """Parse and validate a payload; raise ProtocolError with the reason."""
        # Not through __init__: binding a map's values to parameters costs more.
        return cls._decoded(cls._checked_map(_unpack(payload)))  # type: ignore[return-value]

    @classmethod
    def reader(cls, *names: str) -> Callable[[Any], tuple]:
        """``read(payload)``: the values of the fields ``names``, in that order, of the
        message ``decode(payload)`` returns, or decode's ProtocolError: every field is
        checked as decode checks it, but no message is built, nor the value of a field left
        out whose checker can give its verdict without it (an AgentState's relay). For a
        receiver that reads a few fields of many messages: the coordinator reads ids,
        neighbours and stats of 10 000 AgentStates a second at 1000 robots."""
        return _compile_reader(cls, names)

    @classmethod
    def _from_map(cls: type[M], raw: Any) -> M:
        """The message of an unpacked msgpack object (decode's second half)."""
        return cls._decoded(cls._checked_map(raw))  # type: ignore[return-value]

    @classmethod
    def _checked_map(cls, raw: Any) -> dict[str, Any]:
        """``raw``, an unpacked msgpack object, without its schema version if it is a map
        of this version holding the fields of ``cls`` (their values unchecked)."""
        if not isinstance(raw, dict):
            raise ProtocolError(
                f"{cls.__name__}: expected a map, got {type(raw).__name__}", "schema"
            )
        version = raw.pop("v", None)
        if version != SCHEMA_VERSION or isinstance(version, bool):
            raise ProtocolError(
                f"{cls.__name__}: schema version {version!r}, expected {SCHEMA_VERSION}",
                "version",
            )
        spec, keys = cls._SPEC, raw.keys()
        # The common cases in one or two comparisons: every field, or no other than the
        # fields and every required one (optional ones are often left out).
        if keys != spec.keys() and not (keys <= spec.keys() and keys >= cls._REQUIRED):
            missing = [name for name in spec if name not in raw and name not in cls._OPTIONAL]
            if missing:
                raise ProtocolError(f"{cls.__name__}: missing fields {missing}", "schema")
            unknown = sorted(repr(name) for name in raw if name not in spec)
            if unknown:
                raise ProtocolError(
                    f"{cls.__name__}: unknown fields {', '.join(unknown)}", "schema"
                )
        return raw


@dataclass(frozen=True, slots=True)
class Pose(Message):
    """Robot -> everyone interested: pose at ``stamp`` (s since the epoch)."""

    id: int
    x: float
    y: float
    theta: float
    stamp: float
    seq: int

    _SPEC: ClassVar[dict[str, Checker]] = {
        "id": _ID,
        "x": _COORD,
        "y": _COORD,
        "theta": _real(-MAX_ANGLE, MAX_ANGLE),
        "stamp": _STAMP,
        "seq": _SEQ,
    }


@dataclass(frozen=True, slots=True)
class WheelCommand(Message):
    """Agent -> robot: rim speeds in m/s; ``pose_stamp`` is the pose it was computed from."""

    id: int
    left: float
    right: float
    stamp: float
    seq: int
    pose_stamp: float

    _SPEC: ClassVar[dict[str, Checker]] = {
        "id": _ID,
        "left": _real(-MAX_WHEEL_SPEED, MAX_WHEEL_SPEED),
        "right": _real(-MAX_WHEEL_SPEED, MAX_WHEEL_SPEED),
        "stamp": _STAMP,
        "seq": _SEQ,
        "pose_stamp": _STAMP,
    }


def _density(value: Any, name: str) -> dict[str, Any]:
    """Density.to_dict's shape: {t, floor, bumps: [{mean, cov, weight, rates}]}.

    Structure and finiteness only; positivity and positive definite covariances are
    covswarm.tvd.density's job (as convexity is covswarm.tvd.coverage's).
    """
    number = _real(-MAX_DENSITY, MAX_DENSITY)
    pair = _points(1, 1, MAX_DENSITY)
    matrix = _points(2, 2, MAX_DENSITY)
    bump_spec: dict[str, Checker] = {
        "mean": lambda v, n: pair([v], n)[0],
        "cov": matrix,
        "weight": number,
        "mean_rate": lambda v, n: pair([v], n)[0],
        "cov_rate": matrix,
        "weight_rate": number,
    }
    if not isinstance(value, dict) or set(value) != {"t", "floor", "bumps"}:
        raise ProtocolError(f"{name}: expected a map with keys t, floor, bumps")
    bumps = _sequence(value["bumps"], f"{name}.bumps")
    if len(bumps) > MAX_BUMPS:
        raise ProtocolError(f"{name}.bumps: {len(bumps)} bumps, at most {MAX_BUMPS}")
    out = []
    for i, bump in enumerate(bumps):
        where = f"{name}.bumps[{i}]"
        if not isinstance(bump, dict) or set(bump) != set(bump_spec):
            raise ProtocolError(f"{where}: expected a map with keys {sorted(bump_spec)}")
        out.append({key: check(bump[key], f"{where}.{key}") for key, check in bump_spec.items()})
    return {
        "t": _TIME(value["t"], f"{name}.t"),
        "floor": number(value["floor"], f"{name}.floor"),
        "bumps": tuple(out),
    }


@dataclass(frozen=True, slots=True)
class Domain(Message):
    """Coordinator -> all: subdomain S(t) at mission time ``t`` and its vertex velocities.

    density: None (uniform) or phi at time ``t`` with its rates, covswarm.tvd.density's
    ``Density.to_dict()`` form; optional on the wire (module notes).

    tile_size: side (m) of the beacon tiles of this swarm (protocol.keys.beacon_key). Every
    agent must use the same one, or agents on different grids miss each other's beacons,
    so the coordinator chooses it for the whole swarm and broadcasts it here; optional on
    the wire, absent means DEFAULT_TILE_SIZE.

    start_velocities: while the mission waits, and for the last second of a deploy hold
    (``velocities`` all 0: S holds still; covswarm.coordinator.pace.DEPLOY_ALIGN), the
    vertex velocities S will have when it starts, so that robots that can only drive
    forwards turn to face S's first motion beforehand (covswarm.agent.brain); optional on
    the wire, absent when S will not move at the start (a steered mission) and once it moves.
    """

    seq: int
    stamp: float
    t: float
    state: str
    vertices: tuple[tuple[float, float], ...]
    velocities: tuple[tuple[float, float], ...]
    kappa: float
    density: dict[str, Any] | None = None
    tile_size: float | None = None
    start_velocities: tuple[tuple[float, float], ...] | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "seq": _SEQ,
        "stamp": _STAMP,
        "t": _TIME,
        "state": _choice(STATES),
        "vertices": _points(3, MAX_VERTICES, MAX_COORD),
        "velocities": _points(3, MAX_VERTICES, MAX_VERTEX_SPEED),
        "kappa": _positive(MAX_KAPPA),
        "density": _optional(_density),
        "tile_size": _optional(_positive(MAX_TILE_SIZE)),
        "start_velocities": _optional(_points(3, MAX_VERTICES, MAX_VERTEX_SPEED)),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"density", "tile_size", "start_velocities"})

    def _check_fields(self) -> None:
        for name in ("velocities", "start_velocities"):
            values = getattr(self, name)
            if values is not None and len(values) != len(self.vertices):
                raise ProtocolError(
                    f"Domain: {len(values)} {name} for {len(self.vertices)} vertices"
                )


@dataclass(frozen=True, slots=True)
class AgentState(Message):
    """Agent -> neighbours and monitors: position, Voronoi neighbour ids, stats.

    stats: measurements and counters for monitors, optional on the wire: agents send them
    about once a second rather than in every state, which neighbours decode at the
    control rate and never read the stats of. vx, vy: the velocity the agent last
    commanded (m/s, optional, 0 when absent), so that neighbours can dead-reckon the
    position between states.

    relay: [id, x, y, vx, vy] of (up to MAX_RELAY of) its neighbours as the sender used
    them in its last step (position reckoned to that step, velocity as reported), optional.
    A receiver needs the positions of its two-hop set; relayed, they cost it one
    subscription per one-hop neighbour instead of one per two-hop robot.
    """

    id: int
    x: float
    y: float
    stamp: float
    neighbors: tuple[int, ...]
    stats: dict[str, float | int] | None = None
    vx: float | None = None
    vy: float | None = None
    relay: tuple[tuple[int, float, float, float, float], ...] | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "id": _ID,
        "x": _COORD,
        "y": _COORD,
        "stamp": _STAMP,
        "neighbors": _ids(MAX_NEIGHBORS),
        "stats": _optional(_stats),
        "vx": _optional(_real(-MAX_SPEED, MAX_SPEED)),
        "vy": _optional(_real(-MAX_SPEED, MAX_SPEED)),
        "relay": _optional(_relay(MAX_RELAY)),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"stats", "vx", "vy", "relay"})


@dataclass(frozen=True, slots=True)
class Beacon(Message):
    """Agent -> agents in nearby tiles: "I am here" for neighbour discovery (every 10 s,
    early when a teammate appears, and as its robot moves while it drives through S)."""

    id: int
    x: float
    y: float
    stamp: float

    _SPEC: ClassVar[dict[str, Checker]] = {
        "id": _ID,
        "x": _COORD,
        "y": _COORD,
        "stamp": _STAMP,
    }


MAX_STOPS = 128  # stops of a route in a Status (protocol.steering.MAX_ROUTE in a reply)
MAX_STOP_SCALE = 100.0  # a stop's scale of S (protocol.steering.MAX_FACTOR)


def route_stops(max_stops: int, max_scale: float) -> Checker:
    """Checker of 1..``max_stops`` route stops [x, y, scale] or [x, y, scale, angle]: S's
    centroid (m, within MAX_COORD), its size relative to S when the route starts (0,
    ``max_scale``] and, when given, its rotation from then (rad, CCW, within MAX_ANGLE;
    absent: 0). The Status's route and the steering reply's."""
    coord, scale, angle = _COORD, _positive(max_scale), _real(-MAX_ANGLE, MAX_ANGLE)

    def check(value: Any, name: str) -> tuple[tuple[float, ...], ...]:
        items = _sequence(value, name)
        if not 1 <= len(items) <= max_stops:
            raise ProtocolError(f"{name}: {len(items)} stops, expected 1..{max_stops}")
        out = []
        for i, item in enumerate(items):
            stop = _sequence(item, f"{name}[{i}]")
            if len(stop) not in (3, 4):
                raise ProtocolError(
                    f"{name}[{i}]: expected [x, y, scale] or [x, y, scale, angle], "
                    f"got {len(stop)} values"
                )
            checked = (
                coord(stop[0], f"{name}[{i}].x"),
                coord(stop[1], f"{name}[{i}].y"),
                scale(stop[2], f"{name}[{i}].scale"),
            )
            if len(stop) == 4:
                checked += (angle(stop[3], f"{name}[{i}].angle"),)
            out.append(checked)
        return tuple(out)

    return check


@dataclass(frozen=True, slots=True)
class Status(Message):
    """Coordinator -> all: mission state, aggregate error (None until known), live counts,
    and the route S follows: the stops of the accepted goto being carried out (whoever
    sent it; SteerReply.route's stops, 3 or 4 numbers each), absent otherwise (optional,
    so a Status without a route is the same bytes as before). ``pace`` and ``script_t``
    (optional): how fast the coordinator runs the mission's script for a team that cannot
    hold its control rate, and how far the script got (covswarm.coordinator.pace)."""

    stamp: float
    t: float
    state: str
    error: float | None
    alive_agents: int
    alive_robots: int
    route: tuple[tuple[float, ...], ...] | None = None
    pace: float | None = None
    script_t: float | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "stamp": _STAMP,
        "t": _TIME,
        "state": _choice(STATES),
        "error": _optional(_real(0.0, MAX_COORD * MAX_ID)),
        "alive_agents": _int(0, MAX_ID + 1),
        "alive_robots": _int(0, MAX_ID + 1),
        "route": _optional(route_stops(MAX_STOPS, MAX_STOP_SCALE)),
        "pace": _optional(_real(0.0, 1.0)),
        "script_t": _optional(_TIME),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"route", "pace", "script_t"})


# World: the arena, sent by the coordinator at start and every WORLD_PERIOD s after.
MAX_WORLD_PAYLOAD = 1 << 17  # bytes: 128 KiB; a 20 m x 20 m map at 5 cm is ~1.4 kB
MAX_OBSTACLES = 4096
MAX_OBSTACLE_VERTICES = 64
MAX_NAME = 64  # characters of an obstacle's name
MAX_NAME_NUMBER = 10**9  # numbers of numbered names ("map piece 7")
MM = 1000.0  # wire coordinates of a World are whole millimetres
_NUMBERED = re.compile(r"^(.*[^ ]) ([1-9][0-9]{0,8})$")  # "<prefix> <number>", no leading 0


def _mm(value: Any, name: str) -> int:
    """A coordinate in m (within MAX_COORD) -> whole millimetres (the World's resolution)."""
    return round(_COORD(value, name) * MM)


def _convex_mm(points: list[tuple[int, int]], name: str) -> None:
    """ProtocolError unless ``points`` (whole mm) are a strictly convex CCW polygon.

    Exact in integers: every corner turns left (cross product > 0, so no repeated or
    collinear vertex and no clockwise corner), and the turns add up to one turn, not several
    (a star whose corners all turn left winds twice: 4 pi).
    """
    k = len(points)
    total = 0.0
    for i in range(k):
        (ax, ay), (bx, by), (cx, cy) = points[i - 2], points[i - 1], points[i]
        ux, uy, wx, wy = bx - ax, by - ay, cx - bx, cy - by
        cross = ux * wy - uy * wx
        if cross <= 0:
            what = "a clockwise or straight corner" if cross else "a straight or repeated corner"
            raise ProtocolError(
                f"{name}: not a convex counter-clockwise polygon ({what} at vertex {(i - 1) % k})"
            )
        total += math.atan2(cross, ux * wx + uy * wy)
    if total > 3.0 * math.pi:
        raise ProtocolError(f"{name}: self-intersecting outline (it winds more than once)")


def _obstacles(value: Any, name: str) -> tuple[tuple[tuple[float, float], ...], ...]:
    """Convex polygons in m, canonicalised to whole mm; each strictly convex CCW."""
    items = _sequence(value, name)
    if len(items) > MAX_OBSTACLES:
        raise ProtocolError(f"{name}: {len(items)} obstacles, at most {MAX_OBSTACLES}")
    check = _points(3, MAX_OBSTACLE_VERTICES, MAX_COORD)
    out = []
    for i, item in enumerate(items):
        where = f"{name}[{i}]"
        mm = [(round(x * MM), round(y * MM)) for x, y in check(item, where)]
        _convex_mm(mm, where)
        out.append(tuple((x / MM, y / MM) for x, y in mm))
    return tuple(out)


def _workspace(value: Any, name: str) -> tuple[float, float, float, float]:
    """[xmin, xmax, ymin, ymax] in m, canonicalised to whole mm, non-empty."""
    items = _sequence(value, name)
    if len(items) != 4:
        raise ProtocolError(f"{name}: expected [xmin, xmax, ymin, ymax], got {len(items)} values")
    xmin, xmax, ymin, ymax = (_mm(v, f"{name}[{i}]") for i, v in enumerate(items))
    if not (xmin < xmax and ymin < ymax):
        raise ProtocolError(f"{name}: need xmin < xmax and ymin < ymax (mm: {items!r})")
    return (xmin / MM, xmax / MM, ymin / MM, ymax / MM)


def _names(value: Any, name: str) -> tuple[str, ...]:
    items = _sequence(value, name)
    if len(items) > MAX_OBSTACLES:
        raise ProtocolError(f"{name}: {len(items)} names, at most {MAX_OBSTACLES}")
    for i, item in enumerate(items):
        if not isinstance(item, str) or not 1 <= len(item) <= MAX_NAME:
            raise ProtocolError(f"{name}[{i}]: expected a name of 1..{MAX_NAME} characters")
    return tuple(items)


def default_names(count: int) -> tuple[str, ...]:
    """The names of a World's obstacles when its payload has none: "obstacle 1", ..."""
    return tuple(f"obstacle {i + 1}" for i in range(count))


def _wire_int(value: Any, name: str, lo: int, hi: int) -> int:
    """A plain msgpack int in [lo, hi] (no floats, no booleans)."""
    if type(value) is not int:
        raise ProtocolError(f"{name}: expected an int, got {type(value).__name__}")
    if not lo <= value <= hi:
        raise ProtocolError(f"{name}: {value} outside [{lo}, {hi}]")
    return value


_MAX_MM = round(MAX_COORD * MM)


def _wire_obstacle(value: Any, name: str) -> tuple[tuple[int, int], ...]:
    """One obstacle as sent: ints in mm, a box [x, y, w, h] (4) or a polygon x0, y0, dx1,
    dy1, ... (6..2 MAX_OBSTACLE_VERTICES: each vertex relative to the one before)."""
    if type(value) is not list:
        raise ProtocolError(f"{name}: expected an array, got {type(value).__name__}")
    n = len(value)
    if n == 4:
        x, y, w, h = (_wire_int(v, f"{name}[{i}]", -_MAX_MM, _MAX_MM) for i, v in enumerate(value))
        if w <= 0 or h <= 0 or x + w > _MAX_MM or y + h > _MAX_MM:
            raise ProtocolError(f"{name}: box [x, y, w, h] needs w, h > 0 within bounds")
        return ((x, y), (x + w, y), (x + w, y + h), (x, y + h))
    if n % 2 or not 6 <= n <= 2 * MAX_OBSTACLE_VERTICES:
        raise ProtocolError(
            f"{name}: {n} numbers: expected a box (4) or a polygon of "
            f"3..{MAX_OBSTACLE_VERTICES} vertices (6..{2 * MAX_OBSTACLE_VERTICES})"
        )
    x = y = 0
    out = []
    for i in range(0, n, 2):
        # The first pair is absolute, then deltas: each running sum must stay in bounds.
        x += _wire_int(value[i], f"{name}[{i}]", -2 * _MAX_MM, 2 * _MAX_MM)
        y += _wire_int(value[i + 1], f"{name}[{i + 1}]", -2 * _MAX_MM, 2 * _MAX_MM)
        if not (-_MAX_MM <= x <= _MAX_MM and -_MAX_MM <= y <= _MAX_MM):
            raise ProtocolError(f"{name}: vertex {i // 2} outside +-{MAX_COORD} m")
        out.append((x, y))
    return tuple(out)


def _wire_names(value: Any, count: int) -> tuple[str, ...]:
    """Names as sent: each entry a name or a run [prefix, first, n] of the n names
    "prefix first" .. "prefix first+n-1"; they must name exactly ``count`` obstacles."""
    if type(value) is not list:
        raise ProtocolError(f"names: expected an array, got {type(value).__name__}")
    if len(value) > count:
        raise ProtocolError(f"names: {len(value)} entries for {count} obstacles")
    out: list[str] = []
    for i, entry in enumerate(value):
        if isinstance(entry, str):
            out.append(entry)
            continue
        if type(entry) is not list or len(entry) != 3 or not isinstance(entry[0], str):
            raise ProtocolError(f"names[{i}]: expected a name or [prefix, first, count]")
        prefix = entry[0]
        first = _wire_int(entry[1], f"names[{i}].first", 1, MAX_NAME_NUMBER)
        n = _wire_int(entry[2], f"names[{i}].count", 1, count - len(out))
        if first + n - 1 > MAX_NAME_NUMBER or not 1 <= len(prefix) < MAX_NAME - 10:
            raise ProtocolError(f"names[{i}]: prefix or numbers out of bounds")
        out.extend(f"{prefix} {first + j}" for j in range(n))
    if len(out) != count:
        raise ProtocolError(f"names: {len(out)} names for {count} obstacles")
    return tuple(out)


def _name_runs(names: tuple[str, ...]) -> list[Any]:
    """names -> the wire's entries: consecutive numbered names as runs (_wire_names)."""
    out: list[Any] = []
    for name in names:
        match = _NUMBERED.match(name)
        last = out[-1] if out else None
        if match and isinstance(last, list) and last[0] == match[1]:
            if int(match[2]) == last[1] + last[2]:
                last[2] += 1
                continue
        if match and len(match[1]) < MAX_NAME - 10:
            out.append([match[1], int(match[2]), 1])
        else:
            out.append(name)
    # A run of one is longer than the name itself.
    return [f"{e[0]} {e[1]}" if isinstance(e, list) and e[2] == 1 else e for e in out]


@dataclass(frozen=True, slots=True)
class World(Message):
    """Coordinator -> all: the arena (workspace and convex obstacles), repeated every second
    so a late joiner has it within one; ``seq`` grows when the world changes.

    workspace: (xmin, xmax, ymin, ymax) m, or None; obstacles: convex CCW polygons, each a
    tuple of (x, y) m; names: one per obstacle (None when constructing: "obstacle 1", ...).
    Coordinates are whole millimetres (the constructor rounds to them):
    covswarm.world.wire.to_message rounds a model World outward so the sent obstacles
    contain the true ones. Every polygon is checked strictly convex counter-clockwise.

    On the wire (small: a 20 m x 20 m map at 5 cm is ~1.4 kB, docs/world.md): ``workspace``
    [xmin, xmax, ymin, ymax] and ``obstacles`` in integer mm, each obstacle a box
    [x, y, w, h] or a polygon [x0, y0, dx1, dy1, ...] (vertices after the first relative
    to the one before: small ints pack in 1-3 bytes); ``names`` optional (absent: the
    defaults above), its entries a name or a run [prefix, first, count] of numbered names.
    """

    seq: int
    stamp: float
    obstacles: tuple[tuple[tuple[float, float], ...], ...]
    workspace: tuple[float, float, float, float] | None = None
    names: tuple[str, ...] | None = None

    _SPEC: ClassVar[dict[str, Checker]] = {
        "seq": _SEQ,
        "stamp": _STAMP,
        "obstacles": _obstacles,
        "workspace": _optional(_workspace),
        "names": _optional(_names),
    }
    _OPTIONAL: ClassVar[frozenset[str]] = frozenset({"workspace", "names"})

    def _check_fields(self) -> None:
        if self.names is None:
            object.__setattr__(self, "names", default_names(len(self.obstacles)))
        elif len(self.names) != len(self.obstacles):
            raise ProtocolError(
                f"World: {len(self.names)} names for {len(self.obstacles)} obstacles"
            )

    def same_world(self, other: World) -> bool:
        """Whether ``other`` is the same world (the coordinator's repeats differ in the stamp
        only)."""
        return (self.seq, self.workspace, self.names, self.obstacles) == (
            other.seq, other.workspace, other.names, other.obstacles
        )  # fmt: skip

    def encode(self) -> bytes:
        """msgpack bytes in the compact form above; ProtocolError if over MAX_WORLD_PAYLOAD."""
        wire: dict[str, Any] = {"v": SCHEMA_VERSION, "seq": self.seq, "stamp": self.stamp}
        if self.workspace is not None:
            wire["workspace"] = [round(v * MM) for v in self.workspace]
        obstacles = []
        for polygon in self.obstacles:
            mm = [(round(x * MM), round(y * MM)) for x, y in polygon]
            (x0, y0), (x1, y1) = mm[0], mm[2]
            if mm == [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]:
                obstacles.append([x0, y0, x1 - x0, y1 - y0])
                continue
            flat = [x0, y0]
            for (ax, ay), (bx, by) in zip(mm, mm[1:], strict=False):
                flat += [bx - ax, by - ay]
            obstacles.append(flat)
        wire["obstacles"] = obstacles
        if self.names != default_names(len(self.obstacles)):
            wire["names"] = _name_runs(self.names)
        data = _pack(wire)
        if len(data) > MAX_WORLD_PAYLOAD:
            raise ProtocolError(f"World: {len(data)} bytes, limit {MAX_WORLD_PAYLOAD}", "oversize")
        return data

    @classmethod
    def decode(cls, payload: Any) -> World:
        """Parse and validate a payload (the compact form); ProtocolError with the reason."""
        raw = _unpack(payload, MAX_WORLD_PAYLOAD, list)
        if not isinstance(raw, dict):
            raise ProtocolError(f"World: expected a map, got {type(raw).__name__}", "schema")
        version = raw.pop("v", None)
        if version != SCHEMA_VERSION or isinstance(version, bool):
            raise ProtocolError(
                f"World: schema version {version!r}, expected {SCHEMA_VERSION}", "version"
            )
        unknown = sorted(repr(name) for name in raw if name not in cls._SPEC)
        if unknown:
            raise ProtocolError(f"World: unknown fields {', '.join(unknown)}", "schema")
        missing = [name for name in ("seq", "stamp", "obstacles") if name not in raw]
        if missing:
            raise ProtocolError(f"World: missing fields {missing}", "schema")
        items = raw["obstacles"]
        if type(items) is not list or len(items) > MAX_OBSTACLES:
            raise ProtocolError(f"obstacles: expected an array of at most {MAX_OBSTACLES}")
        polygons = []
        for i, item in enumerate(items):
            mm = _wire_obstacle(item, f"obstacles[{i}]")
            _convex_mm(list(mm), f"obstacles[{i}]")
            polygons.append(tuple((x / MM, y / MM) for x, y in mm))
        workspace = raw.get("workspace")
        if workspace is not None:
            if type(workspace) is not list or len(workspace) != 4:
                raise ProtocolError("workspace: expected [xmin, xmax, ymin, ymax] in mm")
            workspace = [
                _wire_int(v, f"workspace[{i}]", -_MAX_MM, _MAX_MM) / MM
                for i, v in enumerate(workspace)
            ]
        names = raw.get("names")
        return cls(
            seq=raw["seq"],
            stamp=raw["stamp"],
            obstacles=tuple(polygons),
            workspace=workspace,
            names=None if names is None else _wire_names(names, len(polygons)),
        )


# MapImage: the occupancy map as a picture, the coordinator's answer to a query on
# protocol.keys.world_map_key (asked once per World by a console).
MAX_MAP_SIDE = 1024  # pixels a side: a larger map is sent downsampled (world.map_image)
MAX_MAP_PNG = 1 << 18  # bytes of PNG: a 1-bit 1024 x 1024 image is at most ~130 kB
MAX_MAP_PAYLOAD = MAX_MAP_PNG + 256
MAX_MAP_RESOLUTION = 100.0  # m per pixel
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) in pixels from a PNG's header (its first chunk, IHDR); ProtocolError
    if ``data`` does not start like a PNG. The pixels are not decoded: the browser does."""
    if len(data) < 33 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise ProtocolError("png: not a PNG (no signature and IHDR header)")
    if int.from_bytes(data[8:12], "big") != 13:
        raise ProtocolError("png: malformed IHDR header")
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _png(value: Any, name: str) -> bytes:
    if not isinstance(value, (bytes, bytearray)):
        raise ProtocolError(f"{name}: expected bytes, got {type(value).__name__}")
    if len(value) > MAX_MAP_PNG:
        raise ProtocolError(f"{name}: {len(value)} bytes, at most {MAX_MAP_PNG}", "oversize")
    png_size(bytes(value))
    return bytes(value)


def _origin(value: Any, name: str) -> tuple[float, float]:
    items = _sequence(value, name)
    if len(items) != 2:
        raise ProtocolError(f"{name}: expected [x, y], got {len(items)} values")
    return (_COORD(items[0], f"{name}[0]"), _COORD(items[1], f"{name}[1]"))


@dataclass(frozen=True, slots=True)
class MapImage(Message):
    """Coordinator -> a console that asked: the scenario's occupancy map as a PNG to draw
    under the obstacles (the obstacles themselves are the World's).

    seq: the World's seq it belongs to; origin: (x, y) m, the world position of the
    lower-left corner of the lower-left pixel; resolution: m per pixel (> 0); width,
    height: pixels, each in 1..MAX_MAP_SIDE, as the PNG's header says; png: the image
    (row 0 is the TOP of the map, the largest y, as map_server's), at most MAX_MAP_PNG
    bytes. The map must lie within +-MAX_COORD.
    """

    seq: int
    origin: tuple[float, float]
    resolution: float
    width: int
    height: int
    png: bytes

    _SPEC: ClassVar[dict[str, Checker]] = {
        "seq": _SEQ,
        "origin": _origin,
        "resolution": _positive(MAX_MAP_RESOLUTION),
        "width": _int(1, MAX_MAP_SIDE),
        "height": _int(1, MAX_MAP_SIDE),
        "png": _png,
    }

    def _check_fields(self) -> None:
        size = png_size(self.png)
        if size != (self.width, self.height):
            raise ProtocolError(
                f"MapImage: the PNG is {size[0]} x {size[1]} pixels, "
                f"the message says {self.width} x {self.height}"
            )
        x0, y0 = self.origin
        x1, y1 = x0 + self.width * self.resolution, y0 + self.height * self.resolution
        if max(abs(x1), abs(y1)) > MAX_COORD:
            raise ProtocolError(
                f"MapImage: the map reaches ({x1:g}, {y1:g}), beyond +-{MAX_COORD:g} m"
            )

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) m of the whole image."""
        x0, y0 = self.origin
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    @classmethod
    def decode(cls, payload: Any) -> MapImage:
        """Parse and validate a payload of at most MAX_MAP_PAYLOAD bytes."""
        return cls._from_map(_unpack(payload, MAX_MAP_PAYLOAD))
