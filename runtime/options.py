"""Command-line options shared by several covswarm processes."""

from __future__ import annotations

import click

from covswarm.protocol.inbound import MAX_CLOCK_SKEW
from covswarm.protocol.keys import parse_ids

MAX_CLOCK_SKEW_OPTION = click.option(
    "--max-clock-skew",
    type=click.FloatRange(min=0.0),
    default=MAX_CLOCK_SKEW,
    show_default=True,
    help="Drop messages stamped more than this (s) ahead of this process's clock.",
)


TIME_SCALE_OPTION = click.option(
    "--time-scale",
    type=click.FloatRange(min=0.0, min_open=True),
    default=1.0,
    show_default=True,
    help="Mission seconds per wall second (< 1: slower than real time, for big simulations); "
    "the same for every process of a run.",
)


def id_selection(robot_id: int | None, ids: str | None) -> list[int]:
    """The ids a robot or agent process runs: ``--id N`` or ``--ids 0-9`` (exactly one)."""
    if (robot_id is None) == (ids is None):
        raise click.UsageError("give exactly one of --id and --ids")
    if robot_id is not None:
        return [robot_id]
    try:
        return parse_ids(ids)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--ids") from None
