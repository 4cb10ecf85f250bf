"""``covswarm steer``'s options: bad input is a usage error (exit 2) before any network."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from covswarm.coordinator.steer_client import SteeringClient, steer_command

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
        (["--scale", "0"], "x>0"),
        (["--translate", "1,0", "--duration", "2", "--speed", "1"], "not both"),
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
