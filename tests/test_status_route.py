"""The route S follows, told to everyone: Status's optional ``route`` (strict, bounded,
3 or 4 numbers a stop) and the coordinator core that fills it while an accepted goto is
carried out, whoever sent it, and clears it when another request is accepted or S
arrives."""

from __future__ import annotations

import math
import random

import msgpack
import pytest
from warehouse_core import make_core, run_until_started, steer

from covswarm.coordinator.core import PublishStatus
from covswarm.protocol import MAX_PAYLOAD, ProtocolError, Status
from covswarm.protocol.messages import MAX_STOP_SCALE, MAX_STOPS
from covswarm.protocol.steering import MAX_ROUTE, SteerRequest

BASE = {"stamp": 1.7e9, "t": 3.0, "state": "running", "error": 0.1, "alive_agents": 3,
        "alive_robots": 3}  # fmt: skip


def wire(**fields) -> bytes:
    return msgpack.packb({"v": 1, **BASE, **fields}, use_bin_type=True)


def test_a_status_without_a_route_is_the_same_bytes_as_before() -> None:
    status = Status(**BASE)
    assert status.route is None
    assert status.encode() == wire()  # no "route" key at all
    assert Status.decode(wire()).route is None


def test_routes_of_3_or_4_numbers_a_stop_round_trip() -> None:
    rng = random.Random(7)
    for _ in range(50):
        stops = tuple(
            tuple(
                [rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(0.01, 3.0)]
                + ([rng.uniform(-math.pi, math.pi)] if width == 4 else [])
            )
            for width in rng.choices((3, 4), k=rng.randint(1, MAX_STOPS))
        )
        status = Status(**BASE, route=stops)
        assert Status.decode(status.encode()).route == stops
    # The longest route with angles still fits a message (a Status is sent twice a second).
    longest = Status(**BASE, route=((1e4 - 1.0, -1e4 + 1.0, 99.9, 3.1),) * MAX_STOPS)
    assert len(longest.encode()) < MAX_PAYLOAD
    assert MAX_STOPS == MAX_ROUTE  # a reply's whole route fits a Status


@pytest.mark.parametrize(
    "route",
    [
        [],  # no stop
        [[0.0, 0.0, 1.0]] * (MAX_STOPS + 1),  # too many
        [[0.0, 0.0]],  # too few numbers
        [[0.0, 0.0, 1.0, 0.0, 0.0]],  # too many numbers
        [[0.0, 0.0, 0.0]],  # scale 0
        [[0.0, 0.0, -1.0]],
        [[0.0, 0.0, MAX_STOP_SCALE * 1.01]],
        [[float("nan"), 0.0, 1.0]],
        [[0.0, float("inf"), 1.0]],
        [[2e4, 0.0, 1.0]],  # beyond MAX_COORD
        [[0.0, 0.0, 1.0, 1e5]],  # angle beyond MAX_ANGLE
        [[True, 0.0, 1.0]],  # a bool is no number
        [["0", 0.0, 1.0]],
        [{"x": 0.0}],
        "stops",
        {"0": [0.0, 0.0, 1.0]},
    ],
)
def test_malformed_routes_are_refused(route) -> None:
    with pytest.raises(ProtocolError):
        Status.decode(wire(route=route))


def status_route(core, now: float):
    """The route of the Status the core sends at the first tick from ``now`` (or from just
    after the last tick, if later) that sends one; and that tick's time."""
    start = max(now, getattr(core, "_test_clock", now))
    for k in range(20):
        at = round(start + 0.05 * k, 10)
        core._test_clock = at + 0.05
        statuses = [a.status for a in core.tick(at, 1.7e9 + at) if isinstance(a, PublishStatus)]
        if statuses:
            return Status.decode(statuses[-1].encode()).route, at
    raise AssertionError("no Status in a second")


def test_the_status_carries_an_accepted_gotos_route_until_S_arrives() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    route, now = status_route(core, now)
    assert route is None  # the scenario's own motion: no route
    refused = steer(core, SteerRequest("translate", dx=0.0, dy=1.2), now, who="console-a")
    assert not refused.accepted
    assert status_route(core, now)[0] is None  # a refusal changes nothing
    reply = steer(core, SteerRequest("goto", goal=(2.0, 0.3)), now, who="cli-b")
    assert reply.accepted and len(reply.route) >= 2
    arrive = now + reply.duration  # S arrives the reply's duration after the request
    route, now = status_route(core, now)
    assert route == reply.route  # every console hears it, not only the asker
    # Still there just before S arrives, gone after.
    assert status_route(core, arrive - 1.0)[0] == reply.route
    assert status_route(core, arrive + 0.05)[0] is None


def test_another_accepted_request_ends_the_route() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    reply = steer(core, SteerRequest("goto", goal=(2.0, 0.3)), now, who="a")
    assert reply.accepted
    assert status_route(core, now)[0] is not None
    now += 2.0
    stop = steer(core, SteerRequest("scale", factor=0.95), now, who="b")
    assert stop.accepted, stop.reason
    assert status_route(core, now)[0] is None
    # A second goto replaces the first one's route with its own.
    now += 10.0
    again = steer(core, SteerRequest("goto", goal=(-2.5, -0.3)), now, who="a")
    assert again.accepted, again.reason
    assert status_route(core, now)[0] == again.route


def test_a_resumed_coordinator_tells_the_replayed_route() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    reply = steer(core, SteerRequest("goto", goal=(2.0, 0.3)), now, who="a")
    journal = [core.steering.journal_line()]
    resumed = make_core()
    run_until_started(resumed)
    resumed.steering.replay(journal)
    assert resumed.steering.active_route(now + 1.0) == reply.route


class SteeringLog:
    """Stands in for the run recorder's steering channel (records.recorder.RunRecorder)."""

    def __init__(self) -> None:
        self.events: list[tuple[float, dict]] = []

    def steering(self, t: float, event: dict) -> None:
        self.events.append((t, event))


def test_the_recorded_steering_event_of_a_goto_has_its_route() -> None:
    core = make_core()
    now = run_until_started(core) + 0.5
    core.recorder = log = SteeringLog()
    reply = steer(core, SteerRequest("goto", goal=(2.0, 0.3)), now, who="a")
    refused = steer(core, SteerRequest("translate", dx=0.0, dy=5.0), now + 0.1, who="b")
    assert reply.accepted and not refused.accepted
    (_, goto), (_, translate) = log.events
    assert goto["route"] == [list(stop) for stop in reply.route]
    assert goto["accepted"] and goto["duration"] == reply.duration
    assert "route" not in translate
