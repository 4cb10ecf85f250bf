"""Command-line options shared by several covswarm processes."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from covswarm.protocol.inbound import MAX_CLOCK_SKEW
from covswarm.protocol.keys import MAX_ID, parse_ids
from covswarm.protocol.messages import MAX_KAPPA

# No option of covswarm means anything beyond this magnitude (m, s, Hz, gains): 1e308 s of
# mission overflowed the clocks and step counts of the processes it reached.
OPTION_MAX = 1.0e6
# Nor anything positive below this: 1e-300 as a rate or a time scale asked for sleeps the
# platform cannot represent.
OPTION_TINY = 1.0e-6
# Hz: control, pose and broadcast rates beyond this only spin a core.
MAX_RATE = 1000.0


class FiniteFloat(click.FloatRange):
    """A float option's type: a finite number in the range (click's FloatRange lets "nan",
    which fails every comparison, and "inf" through to the code behind the option), of at
    most OPTION_MAX in magnitude unless the range says otherwise, and, for a positive one
    (a range open at 0), at least OPTION_TINY."""

    def __init__(
        self,
        min: float | None = None,  # noqa: A002 (click's names)
        max: float | None = None,  # noqa: A002
        min_open: bool = False,
        max_open: bool = False,
        clamp: bool = False,
    ) -> None:
        low = -OPTION_MAX if min is None else min
        high = OPTION_MAX if max is None else max
        super().__init__(low, high, min_open=min_open, max_open=max_open, clamp=clamp)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if not math.isfinite(click.FLOAT.convert(value, param, ctx)):  # before the range
            self.fail(f"{value!r} is not a finite number", param, ctx)
        number = super().convert(value, param, ctx)
        if self.min == 0 and self.min_open and number < OPTION_TINY:
            self.fail(f"{value!r} is below {OPTION_TINY:g}", param, ctx)
        return number

    def _describe_range(self) -> str:
        if self.min == -OPTION_MAX and self.max == OPTION_MAX:
            return f"|x|<={OPTION_MAX:g}"
        return super()._describe_range()


MAX_CLOCK_SKEW_OPTION = click.option(
    "--max-clock-skew",
    type=FiniteFloat(min=0.0),
    default=MAX_CLOCK_SKEW,
    show_default=True,
    help="Drop messages stamped more than this (s) ahead of this process's clock.",
)


# Mission seconds per wall second: 1000 robots run at 0.05; at 1e-300 a process asked for
# sleeps beyond the platform's, at 1e308 its mission stamps were no longer finite.
TIME_SCALES = (1.0e-3, 100.0)

TIME_SCALE_OPTION = click.option(
    "--time-scale",
    type=FiniteFloat(min=TIME_SCALES[0], max=TIME_SCALES[1]),
    default=1.0,
    show_default=True,
    help="Mission seconds per wall second (< 1: slower than real time, for big simulations); "
    "the same for every process of a run.",
)


class TimeScaleOrAuto(FiniteFloat):
    """``covswarm run --time-scale``'s type: a positive finite number, or "auto" (None: the
    launcher picks the scale the host holds, covswarm.deploy.plan.holding_time_scale)."""

    name = "number|auto"

    def __init__(self) -> None:
        super().__init__(min=TIME_SCALES[0], max=TIME_SCALES[1])

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
            return None
        return super().convert(value, param, ctx)


RUN_TIME_SCALE_OPTION = click.option(
    "--time-scale",
    type=TimeScaleOrAuto(),
    default="1",
    show_default=True,
    help="Mission seconds per wall second (< 1: slower than real time, for big simulations), "
    "or auto: the scale at which this host holds --rate for the team (timed at launch).",
)


Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


def float_option(
    *decls: str,
    help: str | None = None,
    default: float | None = None,
    low: float | None = None,
    low_open: bool = False,
    high: float | None = None,
    high_open: bool = False,
    **extra: Any,
) -> Decorator:
    """A float option in [low, high] (an end left open where asked; None: unbounded), its
    default shown in --help where it has one. ``extra`` goes to ``click.option`` as is."""
    return click.option(
        *decls,
        type=FiniteFloat(low, high, min_open=low_open, max_open=high_open),
        default=default,
        show_default=default is not None,
        help=help,
        **extra,
    )


def count_option(*decls: str, default: int, help: str, low: int = 1) -> Decorator:
    """An integer option of at least ``low`` (a count: teams, seeds, samples), its default
    shown in --help."""
    return click.option(
        *decls, type=click.IntRange(min=low), default=default, show_default=True, help=help
    )


def given_options(ctx: click.Context, *names: str) -> list[str]:
    """The options among ``names`` (parameter names) given on the command line, as flags
    (``--name``), in the order of ``names``."""
    from click.core import ParameterSource

    return [
        "--" + name.replace("_", "-")
        for name in names
        if ctx.get_parameter_source(name) is ParameterSource.COMMANDLINE
    ]


def refuse_unused(ctx: click.Context, names: tuple[str, ...], used: bool, needs: str) -> None:
    """UsageError naming the options of ``names`` given on the command line when ``used``
    is false: a command never accepts an option it would ignore (``needs`` says when it
    is used, e.g. "--console")."""
    if not used and (ignored := given_options(ctx, *names)):
        raise click.UsageError(f"{' and '.join(ignored)}: only with {needs}")


def kappa_option(help: str) -> Decorator:
    """``--kappa``: the control gain, positive and at most what a Domain carries (MAX_KAPPA)."""
    return float_option("--kappa", low=0.0, low_open=True, high=MAX_KAPPA, help=help)


def deploy_options(timeout: float) -> Decorator:
    """``--deploy-error``, ``--deploy-timeout`` (default ``timeout`` s) and ``--deploy-kappa``:
    the deploy hold (covswarm.coordinator.pace) of covswarm coordinator, covswarm run and
    covswarm sim."""
    error_option = float_option(
        "--deploy-error",
        low=0,
        low_open=True,
        help="Deploy first: S waits at S(0) from the start until e_a is this low (m), so the "
        "team spreads over it before it moves; the script then runs its whole duration "
        "[no deploy hold].",
    )
    timeout_option = float_option(
        "--deploy-timeout",
        low=0,
        low_open=True,
        default=timeout,
        help="Longest deploy hold, s of mission time (S then moves whatever e_a).",
    )
    kappa_option = float_option(
        "--deploy-kappa",
        low=0,
        low_open=True,
        help="The gain during the deploy hold (S still: Lloyd's iterations, each control "
        "period closing this x the period of the gap to the centroid, at most 0.8 of it in "
        "an agent); above the mission's, reached from it over the hold's first second "
        "[the mission's kappa].",
    )
    return lambda command: error_option(timeout_option(kappa_option(command)))


def check_deploy_options(ctx: click.Context, deploy_error: float | None) -> None:
    """UsageError for ``--deploy-timeout`` without a deploy hold (``--deploy-error``)."""
    refuse_unused(ctx, ("deploy_timeout",), deploy_error is not None, "--deploy-error")


def switch_option(name: str, help: str, *, default: bool = True, **extra: Any) -> Decorator:
    """A ``--name/--no-name`` pair (``config_argv`` writes every bool field that way)."""
    return click.option(f"--{name}/--no-{name}", default=default, help=help, **extra)


class EndpointType(click.ParamType):
    """A Zenoh endpoint such as ``tcp/127.0.0.1:7447`` (covswarm.protocol.session.check_endpoint),
    refused with the reason as the command line is read."""

    name = "endpoint"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        from covswarm.protocol.session import check_endpoint  # imports zenoh: when used

        try:
            return check_endpoint(value)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)


ENDPOINT = EndpointType()


class SizesType(click.ParamType):
    """Comma-separated positive integers such as ``10,100,1000`` (team or process sizes),
    as a tuple; refused with the reason as the command line is read."""

    name = "n,n,..."

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, tuple):
            return value
        parts = [part.strip() for part in str(value).split(",")]
        if not all(part.isdigit() and int(part) >= 1 for part in parts):
            self.fail(f"{value!r}: expected positive integers separated by commas", param, ctx)
        return tuple(int(part) for part in parts)


SIZES = SizesType()


def connect_option(help: str) -> Decorator:
    """``--connect``: the Zenoh endpoints a process joins, required and repeatable."""
    return click.option("--connect", type=ENDPOINT, multiple=True, required=True, help=help)


def id_options(ids_help: str) -> Decorator:
    """``--id N`` or ``--ids 0-9`` (one of the two: :func:`id_selection`)."""
    robot_id = click.option("--id", type=click.IntRange(0, MAX_ID), help="Robot id.")
    ids = click.option("--ids", help=ids_help)
    return lambda command: robot_id(ids(command))


ROUTER_HELP = "Router endpoint, e.g. tcp/127.0.0.1:7447."

# The agent and robot processes' own: `covswarm run` names its swarm itself.
SWARM_OPTION = click.option(
    "--swarm", default="default", show_default=True, help="Swarm (run) name."
)

VERBOSE_OPTION = switch_option("verbose", "Log at INFO level.", default=False)


def pose_loss_option(help: str) -> Decorator:
    """``--pose-loss``: fault injection, a fraction in [0, 1) of received poses dropped."""
    return float_option("--pose-loss", low=0.0, high=1.0, high_open=True, default=0.0, help=help)


# s: the longest delay a fault injection adds (a pose delivered late, a step made slow):
# beyond it a team only waits for its start-up timeout.
FAULT_DELAY_MAX = 60.0


def pose_delay_option(help: str) -> Decorator:
    """``--pose-delay``: fault injection, received poses delivered this many s late."""
    return float_option("--pose-delay", low=0.0, high=FAULT_DELAY_MAX, default=0.0, help=help)


def agents_option(help: str) -> Decorator:
    """``--agents``: the team size, at least one."""
    return click.option("--agents", type=click.IntRange(min=1), help=help)


def law_option(help: str, choices: tuple[str, ...] = ("da", "d1")) -> Decorator:
    """``--law``: the agents' control law (covswarm.tvd.control), da by default."""
    return click.option(
        "--law", type=click.Choice(choices), default="da", show_default=True, help=help
    )


def out_option(*decls: str, help: str, **extra: Any) -> Decorator:
    """``--out`` (or ``decls``): an output folder, as a Path."""
    kind = click.Path(file_okay=False, path_type=Path)
    return click.option("--out", *decls, type=kind, help=help, **extra)


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


def default_out(kind: str, name: str) -> Path:
    """runs/<kind>-<name>-<date-time>, a folder that does not exist yet (-2, -3, ... added
    when two runs start within the same second)."""
    from datetime import datetime

    stem = Path("runs") / f"{kind}-{name}-{datetime.now():%Y%m%d-%H%M%S}"
    path, k = stem, 1
    while path.exists():
        k += 1
        path = stem.with_name(f"{stem.name}-{k}")
    return path


def check_new_folder(path: Path, option: str = "--out") -> None:
    """BadParameter unless ``path`` is new or an empty folder: a run's files are never mixed
    with an earlier run's (a replay reads every run-N.mcap of its folder, a plot or log left
    over reads as this run's)."""
    if not path.exists():
        return
    if not path.is_dir():
        raise click.BadParameter(f"{path} is a file, not a folder", param_hint=option)
    entries = sorted(entry.name for entry in path.iterdir())
    if entries:
        shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
        raise click.BadParameter(
            f"{path} already holds {shown}: give a new folder, or remove that one",
            param_hint=option,
        )


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
