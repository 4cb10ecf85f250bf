"""Command-line options shared by several covswarm processes."""

from __future__ import annotations

import dataclasses
from typing import Any

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


def config_argv(config: Any) -> list[str]:
    """The command-line options that rebuild ``config``, a process's config dataclass whose
    field names are its command's option names (``time_scale`` is ``--time-scale``).

    Written: every field without a default; every bool, as ``--name`` or ``--no-name``
    (its option is a ``--name/--no-name`` pair), so a command line says how the child runs
    whatever its defaults; every other field that differs from its default and is not
    None. A tuple is its option repeated (one option of several values where the field's
    metadata has ``nargs``); floats are written with repr, exact both ways.
    """
    if not dataclasses.is_dataclass(config):
        raise TypeError(f"not a config dataclass: {config!r}")
    argv: list[str] = []
    for spec in dataclasses.fields(config):
        value = getattr(config, spec.name)
        flag = "--" + spec.name.replace("_", "-")
        if isinstance(value, bool):
            argv.append(flag if value else "--no-" + flag[2:])
            continue
        required = (
            spec.default is dataclasses.MISSING and spec.default_factory is dataclasses.MISSING
        )
        if value is None or (not required and value == spec.default):
            continue
        if spec.metadata.get("nargs"):  # one option of several values (--workspace a b c d)
            argv += [flag, *(repr(float(item)) for item in value)]
            continue
        for item in value if isinstance(value, tuple) else (value,):
            argv += [flag, repr(item) if isinstance(item, float) else str(item)]
    return argv
