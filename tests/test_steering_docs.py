"""The steering examples of docs/steering.md, in the ``live`` scenario they are written for:
each command line and each Python call is accepted in the order given (the coordinator's
core, its world checks and planner included), so a reader who types them sees them work."""

from __future__ import annotations

import math
import re
import shlex
from pathlib import Path

import pytest

from covswarm.coordinator.core import CoordinatorCore, CoordinatorSettings
from covswarm.coordinator.steer_client import steer_command, steer_request
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol.steering import SteerReply, SteerRequest

DOC = (Path(__file__).resolve().parents[1] / "docs" / "steering.md").read_text(encoding="utf-8")


def live_core() -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=load_scenario("live"), swarm="docs", agents=10, duration=1800.0, kappa=2.0,
        rate=20.0, sample_rate=10.0, feedforward=True, time_scale=1.0, tile_size=0.5,
    )  # fmt: skip
    return CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)


def accepted_in_turn(requests: list[SteerRequest]) -> list[SteerReply]:
    """Each request sent once the one before has finished; the replies."""
    core, t, replies = live_core(), 1.0, []
    for request in requests:
        reply = SteerReply.decode(
            core.steering.handle(request.encode(), t, 1.7e9 + t, True).encode()
        )
        replies.append(reply)
        t += reply.duration + 0.5
    return replies


def cli_requests() -> list[SteerRequest]:
    """The `covswarm steer` lines of the doc's first example, parsed as the command parses
    them."""
    lines = re.findall(r"^covswarm steer (.*?)(?:\s+#.*)?$", DOC, flags=re.MULTILINE)
    assert len(lines) >= 5, lines
    requests = []
    for line in lines[:5]:
        args = shlex.split(line.replace("ENDPOINT", "tcp/127.0.0.1:7447"))
        params = steer_command.make_context("steer", args).params
        motion = {
            k: v for k, v in params.items() if k not in ("connect", "swarm", "timeout", "secure")
        }
        requests.append(steer_request(**motion))
    return requests


def test_the_docs_command_lines_are_accepted_in_live_in_their_order() -> None:
    requests = cli_requests()
    assert [r.kind for r in requests] == ["translate", "rotate", "scale", "polygon", "goto"]
    for request, reply in zip(requests, accepted_in_turn(requests), strict=True):
        assert reply.accepted, (request.describe(), reply.reason)
    assert requests[-1].goal == (-1.5, 0.0)


def test_the_docs_python_calls_are_accepted_in_live_in_their_order() -> None:
    block = DOC[DOC.index("```python") : DOC.index("```", DOC.index("```python") + 3)]
    assert "steer.translate(1.5, 0.0, duration=5.0)" in block
    assert "steer.rotate(30.0)" in block and "steer.scale(0.8)" in block
    assert "steer.polygon([(0.8, -0.8), (2.4, -0.8), (1.6, 0.8)])" in block
    requests = [
        SteerRequest("translate", dx=1.5, dy=0.0, duration=5.0),
        SteerRequest("rotate", angle=math.radians(30.0)),
        SteerRequest("scale", factor=0.8),
        SteerRequest("polygon", polygon=((0.8, -0.8), (2.4, -0.8), (1.6, 0.8))),
    ]
    for request, reply in zip(requests, accepted_in_turn(requests), strict=True):
        assert reply.accepted, (request.describe(), reply.reason)


def test_a_turn_in_the_passage_is_refused_as_the_doc_says() -> None:
    (reply,) = accepted_in_turn([SteerRequest("rotate", angle=math.radians(30.0))])
    assert not reply.accepted and reply.reason.startswith("obstacle")


@pytest.mark.parametrize("code", ["obstacle", "no-path"])
def test_the_docs_list_every_refusal_reason(code: str) -> None:
    from covswarm.coordinator.steering import REFUSALS

    assert code in REFUSALS
    refusals = DOC[DOC.index("**Refusals**") :]
    for reason in REFUSALS:
        assert f"`{reason}`" in refusals, reason


def test_rotate_is_read_and_echoed_in_degrees() -> None:
    from click.testing import CliRunner

    args = ["--connect", "tcp/127.0.0.1:1", "--swarm", "x", "--rotate", "1e6"]
    refused = CliRunner().invoke(steer_command, args)
    assert refused.exit_code == 2 and "--rotate" in refused.output
    assert "17453" not in refused.output  # not the radians of the protocol's bound
    assert SteerRequest("rotate", angle=math.radians(360.0)).describe() == "rotate 360 deg"
    long = CliRunner().invoke(
        steer_command, [*args[:4], "--translate", "1,0", "--duration", "3601"]
    )
    assert long.exit_code == 2 and "0<x<=3600" in long.output
