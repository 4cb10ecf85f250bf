"""The ``covswarm`` command: one entry point, one subcommand per process or job.

Subcommands are imported lazily so that ``covswarm robot`` never pays for scipy or
matplotlib, and ``covswarm agent`` never pays for matplotlib: on a 2-core machine that
starts 200 processes, import time is start-up time.
"""

from __future__ import annotations

import importlib

import click

from covswarm.deploy import lifeline

# name -> "module:attribute" of a click.Command
SUBCOMMANDS: dict[str, str] = {
    "sim": "covswarm.deploy.simulate:sim_command",
    "run": "covswarm.deploy.launcher:run_command",
    "agent": "covswarm.agent.main:agent_command",
    "robot": "covswarm.sim_robot.process:robot_command",
    "coordinator": "covswarm.coordinator.main:coordinator_command",
    "bench": "covswarm.deploy.bench:bench_command",
    "credentials": "covswarm.protocol.security:credentials_command",
    "steer": "covswarm.coordinator.steer_client:steer_command",
    "console": "covswarm.console.server:console_command",
    "bridge": "covswarm.bridge.process:bridge_group",
    "replay": "covswarm.records.replay:replay_command",
    "router": "covswarm.deploy.router:router_command",
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported only when invoked."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(SUBCOMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = SUBCOMMANDS.get(cmd_name)
        if target is None:
            return None
        module_name, attribute = target.split(":")
        return getattr(importlib.import_module(module_name), attribute)

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except ConnectionError as exc:
            # Imported here: raised only once that module (and zenoh) was imported anyway.
            from covswarm.protocol.session import SessionError

            if isinstance(exc, SessionError):
                raise click.ClickException(f"cannot open a Zenoh session: {exc}") from None
            raise


@click.group(cls=LazyGroup)
@click.version_option(package_name="covswarm")
def main() -> None:
    """Steer a robot swarm by moving the region it covers: coverage control over a time-varying
    domain (default law TVD-DA; the paper's TVD-D1 and TVD-C with --law)."""
    lifeline.hold()
