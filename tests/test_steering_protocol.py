"""Steering messages on the wire: round trips, strict refusal of anything malformed."""

from __future__ import annotations

import math

import msgpack
import pytest

from covswarm import protocol
from covswarm.protocol import ProtocolError
from covswarm.protocol.steering import SteerReply, SteerRequest

REQUESTS = [
    SteerRequest("translate", dx=1.0, dy=-0.5),
    SteerRequest("translate", dx=1, dy=0, duration=4),
    SteerRequest("rotate", angle=0.5, about=(1.0, 2.0), speed=0.2),
    SteerRequest("scale", factor=0.5),
    SteerRequest("polygon", polygon=[[0, 0], [1, 0], [1, 1], [0, 1]], duration=10.0),
]


def packed(d: dict) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


def wire(message: protocol.Message) -> dict:
    return msgpack.unpackb(message.encode(), raw=False)


def test_steer_key_has_the_contract_shape() -> None:
    assert protocol.steer_key("s1") == "covswarm/s1/steer"
    with pytest.raises(ValueError):
        protocol.steer_key("a/b")


@pytest.mark.parametrize("request_", REQUESTS, ids=lambda r: r.kind)
def test_requests_round_trip(request_: SteerRequest) -> None:
    assert SteerRequest.decode(request_.encode()) == request_
    assert wire(request_)["v"] == protocol.SCHEMA_VERSION


def test_absent_optionals_are_left_out_of_the_payload() -> None:
    assert set(wire(SteerRequest("translate", dx=1.0))) == {
        "v", "kind", "dx", "dy", "angle", "factor",
    }  # fmt: skip


def test_replies_round_trip() -> None:
    for reply in (SteerReply(True, "", 3.5), SteerReply(False, "non-convex: reflex", 0.0)):
        assert SteerReply.decode(reply.encode()) == reply


@pytest.mark.parametrize(
    ("fields", "reason"),
    [
        ({"kind": "jump"}, "value"),
        ({"kind": "translate", "dx": math.nan}, "nonfinite"),
        ({"kind": "translate", "dx": math.inf}, "nonfinite"),
        ({"kind": "translate", "dx": True}, "value"),
        ({"kind": "scale", "factor": 0.0}, "value"),
        ({"kind": "scale", "factor": -2.0}, "value"),
        ({"kind": "translate", "duration": 0.0}, "value"),
        ({"kind": "translate", "duration": 1.0, "speed": 1.0}, "value"),
        ({"kind": "translate", "angle": 0.3}, "value"),  # a field the kind does not use
        ({"kind": "translate", "about": [0.0, 0.0]}, "value"),
        ({"kind": "rotate", "polygon": [[0, 0], [1, 0], [0, 1]]}, "value"),
        ({"kind": "polygon"}, "schema"),  # no vertices
        ({"kind": "polygon", "polygon": [[0, 0], [1, 0]]}, "value"),
        ({"kind": "polygon", "polygon": [[0, 0], [1, 0], [0, math.nan]]}, "nonfinite"),
        ({"kind": "polygon", "polygon": [[0, 0]] * (protocol.MAX_VERTICES + 1)}, "value"),
    ],
)
def test_malformed_requests_are_refused_with_the_reason(fields: dict, reason: str) -> None:
    base = {"v": protocol.SCHEMA_VERSION, "dx": 0.0, "dy": 0.0, "angle": 0.0, "factor": 1.0}
    with pytest.raises(ProtocolError) as caught:
        SteerRequest.decode(packed({**base, **fields}))
    assert caught.value.reason == reason
    # The constructor refuses the same things, so a client cannot send them either.
    with pytest.raises(ProtocolError):
        SteerRequest(**{k: v for k, v in {**base, **fields}.items() if k != "v"})


def test_unknown_fields_versions_and_garbage_are_refused() -> None:
    good = wire(REQUESTS[0])
    cases = [
        ({**good, "token": "x"}, "schema"),
        ({**good, "v": 2}, "version"),
        ({k: v for k, v in good.items() if k != "dx"}, "schema"),
    ]
    for payload, reason in cases:
        with pytest.raises(ProtocolError) as caught:
            SteerRequest.decode(packed(payload))
        assert caught.value.reason == reason
    for raw, reason in [(b"\xc1", "undecodable"), (b"\x00" * 9000, "oversize")]:
        with pytest.raises(ProtocolError) as caught:
            SteerRequest.decode(raw)
        assert caught.value.reason == reason
    with pytest.raises(ProtocolError):
        SteerReply.decode(packed({"v": 1, "accepted": 1, "reason": "", "duration": 0.0}))
    with pytest.raises(ProtocolError):
        SteerReply(False, "x" * 1000, 0.0)


def test_requests_describe_themselves_for_logs() -> None:
    assert REQUESTS[1].describe() == "translate (1, 0) m in 4 s"
    assert REQUESTS[4].to_dict()["polygon"] == [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


def test_a_route_stop_may_carry_the_angle_s_is_turned_by() -> None:
    """SteerReply.route: (x, y, scale) or (x, y, scale, angle) per stop, strictly decoded."""
    route = ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0, -1.5707963267948966), (2.0, 0.5, 1.0))
    reply = SteerReply(True, "", 12.5, route)
    assert SteerReply.decode(reply.encode()).route == route
    for bad in ((1.0, 0.0), (1.0, 0.0, 1.0, 0.0, 2.0), (1.0, 0.0, 1.0, float("nan"))):
        with pytest.raises(ProtocolError, match=r"route\[0\]"):
            SteerReply(True, "", 12.5, (bad,))
