"""The defaults and limits the documentation states are the ones the code has.

Each row pairs a phrase of a documentation page (docs/*.md, whitespace collapsed, so line
breaks do not matter) with the value behind it, read from the code or from the command's own
option default (what a user gets). Changing one without the other fails here. The README is
not read: it may be reworded freely.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import click
import pytest

from covswarm.agent import brain, neighborhood
from covswarm.agent.brain import AgentConfig
from covswarm.coordinator import core as coordinator_core
from covswarm.coordinator import monitor, pace
from covswarm.deploy import host_speed, plan
from covswarm.deploy.cli import main
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import messages
from covswarm.protocol.session import session_config
from covswarm.tvd import control, coverage, drive, safety

DOCS = {
    page.name: re.sub(r"\s+", " ", page.read_text(encoding="utf-8"))
    for page in sorted((Path(__file__).resolve().parents[1] / "docs").glob("*.md"))
}


def option_default(command: str, option: str) -> object:
    """The default of ``covswarm COMMAND --OPTION`` as click gives it to a user."""
    with click.Context(main) as ctx:
        (param,) = [p for p in main.get_command(ctx, command).params if p.name == option]
    return param.default


def reconnect(key: str) -> int:
    retry = session_config(["tcp/127.0.0.1:7447"]).get_json("connect/retry")
    return json.loads(retry)[key]


DOCUMENTED: list[tuple[str, Callable[[], object], object]] = [
    ("`MAX_AMPLIFICATION` (10)", lambda: control.MAX_AMPLIFICATION, 10.0),
    ("`DAMPING` = 0.05", lambda: control.DAMPING, 0.05),
    ("a 3 cm projection distance in `covswarm sim`", lambda: drive.DEFAULT_PROJECTION_DISTANCE,
     0.03),
    ("a 5 cm projection distance in the agents", lambda: brain.AGENT_PROJECTION_DISTANCE, 0.05),
    ("`--stale-timeout` (relays carry", lambda: AgentConfig().stale_timeout, 1.0),
    ("obstacle where it was last known for 30 s", lambda: brain.OBSTACLE_MEMORY, 30.0),
    ("a beacon older than `BEACON_TRUST` (0.5 s)", lambda: brain.BEACON_TRUST, 0.5),
    ("`auto` runs at `HOLDING_SHARE` (0.6)", lambda: plan.HOLDING_SHARE, 0.6),
    ("`RECEDE_SHARE` (0.5) of a neighbour's", lambda: safety.RECEDE_SHARE, 0.5),
    ("with `RECEDE_SLACK` 0.015 m", lambda: safety.RECEDE_SLACK, 0.015),
    ("is under `SLIDE_MIN` (0.1) of its aim's speed", lambda: drive.SLIDE_MIN, 0.1),
    ("safe distances `SLIDE_CLEARANCE` (5 mm) larger", lambda: drive.SLIDE_CLEARANCE, 0.005),
    ("stopped dead for `SLIDE_AFTER` (1 s) on end", lambda: drive.SLIDE_AFTER, 1.0),
    ("at a forward speed of `STOPPED_SPEED` (1 mm/s) or less", lambda: drive.STOPPED_SPEED, 0.001),
    ("stopped dead at `STOPPED_SPEED` (1 mm/s)", lambda: drive.STOPPED_SPEED, 0.001),
    ("by a brain whose turns come later than `ARC_HOLD` (0.3 s)", lambda: brain.ARC_HOLD, 0.3),
    ("one row per robot it knows within 0.5 m", lambda: safety.SAFETY_RADIUS, 0.5),
    ("liveliness token for 1.5 s", lambda: coordinator_core.START_SETTLE, 1.5),
    ("or for three rounds of the slowest agent's", lambda: monitor.START_ROUNDS, 3),
    ("the last has been silent for 0.5 s", lambda: brain.DOMAIN_RESTART_SILENCE, 0.5),
    ("wheel radius 21 mm", lambda: drive.KHEPERA_IV.wheel_radius, 0.021),
    ("wheel separation 105.4 mm", lambda: drive.KHEPERA_IV.wheel_separation, 0.1054),
    ("top rim speed `--max-wheel-speed` 0.8 m/s",
     lambda: option_default("robot", "max_wheel_speed"), 0.8),
    ("`--cmd-timeout` (0.5 s)", lambda: option_default("robot", "cmd_timeout"), 0.5),
    ("at most 0.5 s ahead per hop", lambda: neighborhood.DEAD_RECKONING_LIMIT, 0.5),
    ("linger 0.5 s", lambda: option_default("agent", "linger"), 0.5),
    ("linger 0.5 s", lambda: AgentConfig().linger, 0.5),
    ("publishes a Beacon every 10 s", lambda: AgentConfig().beacon_period, 10.0),
    ("sends its next beacon within a second", lambda: brain.BEACON_MIN_PERIOD, 1.0),
    ("more than 80 % of its gap", lambda: brain.MAX_STEP_FRACTION, 0.8),
    ("(at most `MAX_DUTY` = 4;", lambda: AgentConfig().max_duty, 4.0),
    ("periods count up to 4 s", lambda: brain.MAX_PERIOD, 4.0),
    ("1.6 is kept, 1.3-2.2 over", lambda: host_speed.LIVE_PER_BENCH, 1.6),
    ("one pack of 100 brains over the bench's team", lambda: host_speed.CALIBRATION_BRAINS, 100),
    ("(1.0 s for 1000 robots on 2 cores;",
     lambda: round(plan.command_timeout(1000, 2, 10.0), 2), 1.0),
    ("1.0 s for 1000 robots on two cores",
     lambda: round(plan.command_timeout(1000, 2, 10.0), 2), 1.0),
    ("over the command history's whole span (2 s)", lambda: brain.POSE_HORIZON, 2.0),
    ("once its pose is 1 s old", lambda: AgentConfig().stale_timeout, 1.0),
    ("extrapolate the last domain for 1 s", lambda: AgentConfig().max_extrapolation, 1.0),
    ("more than 1024 vertices", lambda: coverage.MAX_POLYGON_VERTICES, 1024),
    ("per neighbour, at most 64", lambda: messages.MAX_RELAY, 64),
    ("every 250 ms, backing off to 1 s", lambda: reconnect("period_init_ms"), 250),
    ("every 250 ms, backing off to 1 s", lambda: reconnect("period_max_ms"), 1000),
    ("control rate (10 Hz)", lambda: option_default("run", "rate"), 10.0),
    ("over `DEPLOY_RAMP` (2 s,", lambda: pace.DEPLOY_RAMP, 2.0),
    ("after `--deploy-timeout` s (60 by default)",
     lambda: option_default("run", "deploy_timeout"), 60.0),
    ("after `--deploy-timeout` s (60 by default)",
     lambda: option_default("sim", "deploy_timeout"), 60.0),
    ("This is the default run (`passage`, 10 robots, 45 s)",
     lambda: option_default("run", "scenario") == "passage", True),
    ("This is the default run (`passage`, 10 robots, 45 s)",
     lambda: (load_scenario("passage").agents, load_scenario("passage").duration), (10, 45.0)),
]  # fmt: skip


@pytest.mark.parametrize(
    ("phrase", "value", "expected"), DOCUMENTED, ids=[d[0] for d in DOCUMENTED]
)
def test_the_docs_state_the_code_default(phrase: str, value: Callable, expected: object) -> None:
    assert any(phrase in text for text in DOCS.values()), (
        f"no page says {phrase!r}: update this row"
    )
    assert value() == pytest.approx(expected), phrase


@pytest.mark.parametrize("command", [[], ["agent"]], ids=["covswarm", "agent"])
def test_help_names_the_default_law(command: list[str]) -> None:
    """`covswarm --help` and `covswarm agent --help` name TVD-DA as the default law, which it
    is (the paper's TVD-D1 only with --law d1)."""
    from click.testing import CliRunner

    said = " ".join(CliRunner().invoke(main, [*command, "--help"]).output.split())
    assert "TVD-DA by default" in said or "default law TVD-DA" in said, said
    assert option_default("agent", "law") == "da" and option_default("run", "law") == "da"
