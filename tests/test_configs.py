"""One typed config per process kind: its fields are its command's options, name for name,
and a planned child's command line parses back into the config it was written from."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click
import pytest

from covswarm.agent.config import AgentProcessConfig
from covswarm.agent.main import agent_command
from covswarm.coordinator.config import CoordinatorConfig
from covswarm.coordinator.main import coordinator_command
from covswarm.deploy.launcher import run_command
from covswarm.deploy.plan import (
    RunConfig,
    agent_config,
    coordinator_config,
    plan_children,
    robot_config,
)
from covswarm.mission.scenario_files import load_scenario
from covswarm.runtime.options import config_argv
from covswarm.sim_robot.config import RobotConfig
from covswarm.sim_robot.process import robot_command

# FOXGLOVE_OPTION, shared by run and coordinator, names its value foxglove_port.
RENAMED = {"foxglove_port": "foxglove"}
KINDS = [
    (CoordinatorConfig, coordinator_command),
    (AgentProcessConfig, agent_command),
    (RobotConfig, robot_command),
    (RunConfig, run_command),
]


def parsed(command: click.Command, argv: list[str]) -> dict:
    """The options click gives ``command`` for ``argv``, under their config field names."""
    with command.make_context(command.name, list(argv)) as ctx:
        return {RENAMED.get(k, k): v for k, v in ctx.params.items()}


@pytest.mark.parametrize(("config", "command"), KINDS)
def test_every_field_is_an_option_of_the_same_name(config: type, command: click.Command) -> None:
    options = {RENAMED.get(p.name, p.name) for p in command.params if p.name != "help"}
    assert {f.name for f in dataclasses.fields(config)} == options
    for param in command.params:  # and the flag is the field's name with dashes
        field = RENAMED.get(param.name, param.name)
        assert "--" + field.replace("_", "-") in param.opts


@pytest.mark.parametrize(
    ("command", "argv", "config"),
    [
        (coordinator_command, ["--connect", "tcp/127.0.0.1:7447", "--swarm", "s", "--out", "o"],
         CoordinatorConfig(connect=("tcp/127.0.0.1:7447",), swarm="s", out=Path("o"))),
        (agent_command, ["--connect", "tcp/127.0.0.1:7447", "--id", "1"],
         AgentProcessConfig(connect=("tcp/127.0.0.1:7447",), rate=10.0, id=1)),
        (robot_command, ["--connect", "tcp/127.0.0.1:7447", "--id", "1"],
         RobotConfig(connect=("tcp/127.0.0.1:7447",), id=1)),
        (run_command, [], RunConfig()),
    ],
)  # fmt: skip
def test_options_left_out_give_the_fields_defaults(
    command: click.Command, argv: list[str], config: object
) -> None:
    assert type(config)(**parsed(command, argv)) == config


def test_config_argv_writes_what_differs_bools_and_required_fields() -> None:
    config = CoordinatorConfig(swarm="s", out=Path("o"), connect=("a", "b"), rate=12.5)
    assert config_argv(config) == [
        "--swarm", "s", "--out", "o", "--connect", "a", "--connect", "b", "--rate", "12.5",
        "--feedforward", "--no-resume", "--record", "--record-states", "--pace",
    ]  # fmt: skip
    with pytest.raises(TypeError):
        config_argv({"swarm": "s"})


def test_a_planned_childs_command_line_parses_back_into_its_config() -> None:
    scenario = load_scenario("passage")
    run = RunConfig(
        agents=5, seed=4, swarm="s", out=Path("out"), rate=7.5, feedforward=False,
        law="d1", time_scale=0.5, pose_loss=0.2, pose_delay=0.05, safety=False,
        prediction=False, foxglove=0, record=False, max_domain_speed=0.3,
        command_latency=0.1,
    )  # fmt: skip
    endpoint = "tcp/127.0.0.1:7447"
    poses = [[0.1 * i, -0.2, 0.3] for i in range(5)]
    configs = [
        (coordinator_config(run, scenario, endpoint), coordinator_command),
        (robot_config(run, endpoint, [2], poses, packed=False), robot_command),
        (robot_config(run, endpoint, [1, 2, 3], poses, packed=True), robot_command),
        (agent_config(run, scenario, endpoint, [2], 0.25, packed=False), agent_command),
        (agent_config(run, scenario, endpoint, [3, 4], 0.5, packed=True), agent_command),
    ]
    for config, command in configs:
        assert type(config)(**parsed(command, config_argv(config))) == config
    # The run's options reach the children under the same names.
    coordinator, agent = configs[0][0], configs[3][0]
    assert (coordinator.record, coordinator.foxglove, coordinator.seed) == (False, 0, 4)
    assert (agent.pose_loss, agent.pose_delay, agent.pose_seed) == (0.2, 0.05, 4)
    assert not (agent.safety or agent.prediction or agent.feedforward)
    assert agent.brain().pose_loss == 0.2 and agent.brain().robot.body_diameter == 0.14
    assert agent.command_latency == agent.brain().command_latency == 0.1
    specs = plan_children(run, scenario, endpoint=endpoint, base=("covswarm",))
    assert "--pose-loss" in specs[2].argv and "--no-record" in specs[0].argv


def test_the_run_command_line_parses_into_a_run_config() -> None:
    argv = ["--agents", "4", "--no-feedforward", "--pose-loss", "0.1", "--ids", "0-1",
            "--no-coordinator", "--swarm", "x", "--foxglove", "9000",
            "--command-latency", "0.05"]  # fmt: skip
    run = RunConfig(**parsed(run_command, argv))
    assert (run.agents, run.feedforward, run.pose_loss, run.ids) == (4, False, 0.1, "0-1")
    assert run.command_latency == 0.05
    assert (run.coordinator, run.swarm, run.foxglove) == (False, "x", 9000)


def test_no_help_text_shows_an_unbounded_range_as_none() -> None:
    # click's FloatRange describes a range without bounds as "x<=None" (covswarm sim --heading)
    from click.testing import CliRunner

    from covswarm.deploy.cli import SUBCOMMANDS, main

    for name in SUBCOMMANDS:
        if name == "bridge":
            continue  # a group: its commands' help below
        shown = CliRunner().invoke(main, [name, "--help"], terminal_width=200)
        assert shown.exit_code == 0, (name, shown.output)
        assert "None" not in shown.output, (name, shown.output)
    shown = CliRunner().invoke(main, ["bridge", "ros2", "--help"], terminal_width=200)
    assert shown.exit_code == 0 and "None" not in shown.output
