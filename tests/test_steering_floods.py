"""Steering floods cost a count (issue 21, item 3): per-requester token buckets, the
"rate-limited" refusal, and records bounded to their first and last requests."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest

from covswarm.coordinator import steering as steering_module
from covswarm.coordinator.steering import (
    UNKNOWN_REQUESTER,
    Limits,
    RequestLimiter,
    Steering,
    SteeringRecord,
    SteeringRecords,
    requester_key,
)
from covswarm.protocol.steering import SteerRequest

SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
WALL = 1.7e9


def steering() -> Steering:
    still = lambda t: (SQUARE.copy(), np.zeros_like(SQUARE))  # noqa: E731
    return Steering(still, Limits(max_speed=0.5, workspace=(-3.0, 3.0, -2.0, 2.0), min_area=0.3))


def test_the_bucket_against_a_brute_force_count() -> None:
    # Random arrival times: the bucket allows exactly what a direct simulation allows.
    rng = np.random.default_rng(3)
    rate, burst = 2.0, 5
    limiter = RequestLimiter(rate, burst)
    times = np.sort(rng.uniform(0.0, 20.0, 400))
    tokens, last = float(burst), 0.0
    for now in times:
        tokens = min(burst, tokens + (now - last) * rate)
        last = now
        expected = tokens >= 1.0
        tokens -= expected
        assert limiter.allow("a", float(now)) == expected
    # Over 20 s at most burst + rate * 20 requests pass.
    fresh = RequestLimiter(rate, burst)
    assert sum(fresh.allow("b", float(t)) for t in times) <= burst + 40


def test_requesters_have_their_own_buckets_and_their_number_is_bounded() -> None:
    limiter = RequestLimiter(rate=1.0, burst=2, max_keys=3)
    assert [limiter.allow("flood", 0.0) for _ in range(4)] == [True, True, False, False]
    assert limiter.allow("operator", 0.0)  # not starved by the flood
    for k in range(1000):  # forged sources: all beyond the third share one bucket
        limiter.allow(f"forged {k}", 0.0)
    assert len(limiter._buckets) <= 4
    assert not limiter.allow("flood", 0.5)  # half a token: still empty
    assert limiter.allow("flood", 1.0)
    assert not limiter.allow("flood", -100.0)  # a clock stepping back refills nothing
    with pytest.raises(ValueError, match="RequestLimiter"):
        RequestLimiter(rate=0.0)


def test_requester_key_reads_the_zenoh_source_when_there_is_one() -> None:
    assert requester_key(None) == UNKNOWN_REQUESTER
    assert requester_key(types.SimpleNamespace(source_id=None)) == UNKNOWN_REQUESTER
    source = types.SimpleNamespace(source_id=types.SimpleNamespace(zid="ab12", eid=7))
    assert requester_key(source) == "ab12/7"


def test_a_flood_of_valid_requests_is_refused_counted_and_bounded() -> None:
    steer = steering()
    request = SteerRequest(kind="translate", dx=0.1, duration=5.0).encode()
    n = 10_893  # the probe's count, in 5 s
    replies = [steer.handle(request, 1.0, WALL + 5.0 * k / n, True, "flood") for k in range(n)]
    accepted = sum(r.accepted for r in replies)
    burst, rate = steering_module.STEER_BURST, steering_module.STEER_RATE
    assert burst <= accepted <= burst + rate * 5.0 + 1
    assert steer.refused["rate-limited"] == n - accepted
    assert all(r.reason.startswith("rate-limited") for r in replies if not r.accepted)
    # Another requester still gets through.
    assert steer.handle(request, 1.0, WALL + 5.0, True, "operator").accepted
    # summary.json's list: first and last RECORDS_HEAD / RECORDS_TAIL, the rest counted.
    head, tail = steering_module.RECORDS_HEAD, steering_module.RECORDS_TAIL
    records = list(steer.records)
    assert len(records) == head + tail == len(steer.records)
    assert steer.records.omitted == n + 1 - head - tail
    assert records[-1].accepted and steer.records[-1] is records[-1]
    assert len(json.dumps([r.to_dict() for r in records])) < 100_000
    # A journal's replay is not rate-limited (requester None).
    lines = [json.dumps({"t": 1.0, "wall": WALL, "request": {"kind": "scale", "factor": 1.01}})]
    assert steering().replay(lines * 50) == 50


def test_records_keep_head_and_tail_in_order() -> None:
    records = SteeringRecords(head=3, tail=2)
    for k in range(10):
        records.append(SteeringRecord(float(k), WALL, None, False, "x", 0.0))
    assert [r.t for r in records] == [0.0, 1.0, 2.0, 8.0, 9.0]
    assert records.omitted == 5 and records[-1].t == 9.0 and records[0].t == 0.0
    few = SteeringRecords(head=3, tail=2)
    few.append(SteeringRecord(0.0, WALL, None, False, "x", 0.0))
    assert few[-1].t == 0.0 and len(few) == 1 and few.omitted == 0
