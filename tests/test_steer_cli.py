"""``covswarm steer``'s options: bad input is a usage error (exit 2) before any network."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from click.testing import CliRunner

from covswarm.coordinator.steer_client import SteeringClient, steer_command
from covswarm.protocol.steering import SteerReply, SteerRequest

BASE = ["--connect", "tcp/127.0.0.1:1", "--swarm", "s1"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "exactly one of"),
        (["--translate", "1,0", "--rotate", "10"], "exactly one of"),
        (["--translate", "1"], "expected X,Y"),
        (["--translate", "1,x"], "expected X,Y"),
        (["--rotate", "10", "--about", "1;2"], "expected X,Y"),
        (["--polygon", "0,0;1,0"], "2 points"),
        (["--translate", "nan,0"], "not finite"),
        (["--translate", "1,0", "--about", "0,0"], "--rotate or --scale only"),
        (["--scale", "0"], "0<x<="),
        (["--translate", "1,0", "--duration", "2", "--speed", "1"], "not both"),
        (["--goto", "1"], "expected X,Y"),
        (["--goto", "1,0", "--translate", "1,0"], "exactly one of"),
        (["--goto", "1,0", "--duration", "2"], "--speed, not --duration"),
        (["--goto", "1,0", "--polygon", "0,0;1,0"], "2 points"),
        (["--goto", "inf,0"], "not finite"),
    ],
)
def test_bad_options_are_usage_errors(args: list[str], message: str) -> None:
    result = CliRunner().invoke(steer_command, [*BASE, *args])
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_bad_swarm_names_and_timeouts_are_refused() -> None:
    result = CliRunner().invoke(steer_command, ["--connect", "tcp/127.0.0.1:1", "--swarm", "a/b",
                                                "--translate", "1,0"])  # fmt: skip
    assert result.exit_code == 2 and "invalid swarm name" in result.output
    with pytest.raises(ValueError):
        SteeringClient(object(), "s1", timeout=0.0)


class _Session:
    """Answers every query with ``reply`` and keeps the request (no network)."""

    def __init__(self, reply: SteerReply) -> None:
        self.reply, self.sent = reply, []

    def get(self, key: str, payload: bytes, timeout: float) -> list:
        self.sent.append((key, SteerRequest.decode(payload)))
        ok = SimpleNamespace(payload=SimpleNamespace(to_bytes=self.reply.encode))
        return [SimpleNamespace(ok=ok, err=None)]


def test_the_client_sends_a_goto_and_returns_its_route() -> None:
    route = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.6), (2.0, 0.5, 1.0))
    session = _Session(SteerReply(True, "", 12.5, route))
    reply = SteeringClient(session, "s1").goto(2.0, 0.5, polygon=[(0, 0), (1, 0), (0, 1)])
    assert reply.route == route
    ((key, request),) = session.sent
    assert key == "covswarm/s1/steer" and request.kind == "goto" and request.goal == (2.0, 0.5)
    assert request.polygon == ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))
    SteeringClient(session, "s1").goto(1.0, 1.0, speed=0.2)
    assert session.sent[-1][1] == SteerRequest("goto", goal=(1.0, 1.0), speed=0.2)


def test_a_routes_stops_print_with_their_angle_where_s_is_turned() -> None:
    from covswarm.coordinator.steer_client import describe_route

    route = ((-1.5, -2.8, 1.0), (-1.47, -2.8, 1.0, -math.pi / 2), (1.5, 2.8, 0.5))
    assert describe_route(route) == (
        "(-1.500, -2.800) x1.00 -> (-1.470, -2.800) x1.00 -90 deg -> (1.500, 2.800) x0.50"
    )
