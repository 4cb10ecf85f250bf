"""The page's steering requests: strict JSON -> protocol SteerRequest, or the reason why not.

The page POSTs one JSON object with the fields of :class:`covswarm.protocol.SteerRequest`
(``kind`` plus the fields that kind uses). Anything else is refused here, before the
coordinator is asked, with a reason the page shows: a body that is not JSON or is too big,
NaN/Infinity (which Python's json would otherwise accept), unknown fields, wrong types or
values (SteerRequest's own checks). Geometry (convexity, workspace, team size) is the
coordinator's to judge: it answers with the reason, which the page shows too. A refused
request never reaches the coordinator, so it cannot move S. Every body that cannot be read
is a BadSteerInput (the console answers 400), never an exception of the JSON parser: a
nesting too deep for it (RecursionError), an integer past Python's digit limit
(ValueError), bytes that are not UTF-8.
"""

from __future__ import annotations

import json
from typing import Any

from covswarm.protocol.messages import MAX_PAYLOAD
from covswarm.protocol.steering import SteerRequest

MAX_BODY = 4 * MAX_PAYLOAD  # bytes of JSON: a 64-vertex polygon takes ~2.5 kB
FIELDS = frozenset(SteerRequest._SPEC)


class BadSteerInput(ValueError):
    """A page request the console refuses without asking the coordinator; str() says why."""


def _no_constant(name: str) -> Any:
    raise BadSteerInput(f"{name} is not a number the console accepts")


def parse_steer_body(body: bytes) -> SteerRequest:
    """The SteerRequest a JSON body asks for; BadSteerInput naming the problem otherwise."""
    if len(body) > MAX_BODY:
        raise BadSteerInput(f"request of {len(body)} bytes, limit {MAX_BODY}")
    try:
        data = json.loads(body.decode("utf-8"), parse_constant=_no_constant)
    except BadSteerInput:
        raise
    except (ValueError, RecursionError) as exc:  # JSON, UTF-8, digit limit, nesting depth
        raise BadSteerInput(f"not JSON: {str(exc)[:200]}") from None
    return steer_request(data)


def steer_request(data: Any) -> SteerRequest:
    """A SteerRequest from a decoded JSON object; BadSteerInput naming the problem."""
    if not isinstance(data, dict):
        raise BadSteerInput(f"expected a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - FIELDS)
    if unknown:
        raise BadSteerInput(f"unknown fields {unknown}")
    if "kind" not in data:
        raise BadSteerInput("missing field 'kind'")
    try:
        return SteerRequest(**data)
    except ValueError as exc:  # ProtocolError: types, ranges, fields a kind does not use
        raise BadSteerInput(str(exc)) from None
