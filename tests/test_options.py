"""The shared command-line option factories (covswarm.runtime.options), through click."""

from __future__ import annotations

from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from covswarm.runtime.options import (
    float_option,
    id_options,
    id_selection,
    law_option,
    switch_option,
)


@click.command()
@float_option("--gain", low=0.0, low_open=True, high=2.0, default=1.0, help="A gain.")
@float_option("--phase", low=0.0, high=1.0, high_open=True)
@float_option("--angle")
@switch_option("fast", "Go fast.")
@law_option("The law.")
@id_options("Several ids.")
def probe(**options: object) -> None:
    click.echo(repr(sorted(options.items())))


def run(*args: str) -> click.testing.Result:
    return CliRunner().invoke(probe, list(args))


def test_defaults_and_values_parse() -> None:
    done = run()
    assert done.exit_code == 0, done.output
    defaults = [("fast", True), ("gain", 1.0), ("id", None), ("ids", None), ("law", "da")]
    assert done.output.strip() == repr([("angle", None), *defaults, ("phase", None)])
    done = run("--gain", "2", "--phase", "0", "--no-fast", "--law", "d1", "--id", "7")
    assert done.exit_code == 0, done.output
    assert "('fast', False)" in done.output and "('gain', 2.0)" in done.output
    assert "('phase', 0.0)" in done.output and "('law', 'd1')" in done.output
    assert "('id', 7)" in done.output


@pytest.mark.parametrize(
    "args",
    [
        ("--gain", "0"),  # open low end
        ("--gain", "2.01"),
        ("--phase", "1"),  # open high end
        ("--phase", "-0.1"),
        ("--law", "c"),  # not among the choices
        ("--id", "-1"),
        ("--id", "65536"),
    ],
)
def test_out_of_range_values_are_refused(args: tuple[str, str]) -> None:
    done = run(*args)
    assert done.exit_code == 2 and "Invalid value" in done.output, done.output


@pytest.mark.parametrize(
    ("option", "value"),
    [("--angle", "nan"), ("--angle", "NaN"), ("--angle", "inf"), ("--angle", "-inf"),
     ("--gain", "nan"), ("--phase", "nan")],
)  # fmt: skip
def test_a_float_option_is_a_finite_number(option: str, value: str) -> None:
    """Bounded or not: "nan" fails every comparison with a bound, and "inf" passes a
    missing one, so both would reach the code behind the option."""
    done = run(option, value)
    assert done.exit_code == 2 and "is not a finite number" in done.output, done.output
    assert run("--angle", "-3.5").exit_code == 0


def test_help_shows_defaults_only_where_there_are_some() -> None:
    text = run("--help").output
    assert "[default: 1.0; 0.0<x<=2.0]" in text
    assert "--phase FLOAT RANGE" in text and "default: None" not in text


def test_id_selection_needs_exactly_one() -> None:
    assert id_selection(3, None) == [3]
    assert id_selection(None, "0-2") == [0, 1, 2]
    with pytest.raises(click.UsageError):
        id_selection(None, None)
    with pytest.raises(click.UsageError):
        id_selection(1, "0-2")
    with pytest.raises(click.BadParameter):
        id_selection(None, "2-0")


# Values that passed every option's own range and then crashed a process mid-run (clocks,
# step counts, sleeps the platform cannot make) or spun a core: refused as the command line
# is read, whatever the command.
EXTREMES = [
    ("run", "--rate", "1e308"), ("run", "--time-scale", "1e308"), ("run", "--time-scale", "1e-300"),
    ("run", "--fault-step-delay", "1e308"), ("run", "--pose-delay", "1e308"),
    ("run", "--brain-tick", "1e308"), ("run", "--duration", "1e308"), ("run", "--seed", "-1"),
    ("sim", "--dt", "1e-300"), ("sim", "--damping", "1e308"), ("sim", "--seed", "-1"),
    ("agent", "--rate", "1e308"), ("agent", "--time-scale", "1e-300"),
    ("agent", "--pose-seed", "-1"), ("coordinator", "--rate", "1e308"),
    ("coordinator", "--time-scale", "1e308"), ("robot", "--rate", "1e308"),
    ("steer", "--timeout", "1e308"), ("bench", "--brain-tick-late", "1e308"),
    ("run", "--swarm", ""),  # a random name had stood in for it
]  # fmt: skip


@pytest.mark.parametrize(("command", "option", "value"), EXTREMES)
def test_extreme_values_are_refused_as_the_command_line_is_read(
    command: str, option: str, value: str
) -> None:
    from covswarm.deploy.cli import main

    done = CliRunner().invoke(main, [command, option, value])
    assert done.exit_code == 2, done.output
    said = done.output.replace("'", "")  # click quotes an option's name, a param_hint not
    assert f"Invalid value for {option}:" in said and "Traceback" not in done.output


def test_a_simulation_of_too_many_steps_is_refused() -> None:
    from covswarm.deploy.cli import main

    done = CliRunner().invoke(main, ["sim", "--dt", "1e-5", "--duration", "1000"])
    assert done.exit_code == 2 and "more than 1e+07 steps" in done.output, done.output


# Options a command would accept and then ignore, for want of the option that uses them: a
# user who typed them expects an effect.
UNUSED = [
    (("run", "--console-port", "7481"), "--console-port: only with --console"),
    (("run", "--no-record", "--record-states"), "--record-states: only with a recorded run"),
    (("run", "--deploy-timeout", "30"), "--deploy-timeout: only with --deploy-error"),
    (("coordinator", "--connect", "tcp/127.0.0.1:1", "--swarm", "s", "--out", "/nonexistent",
      "--deploy-timeout", "30"), "--deploy-timeout: only with --deploy-error"),
    (("sim", "--scenario", "circle", "--face-start"), "--face-start: only with unicycles"),
    (("bridge", "ros2", "--ids", "0", "--swarm", "s", "--connect", "tcp/127.0.0.1:1",
      "--frame", "odom"),
     "--frame: only with --publish-state"),
    (("bench", "--live-duration", "5"), "--live-duration: only with --live"),
]  # fmt: skip


@pytest.mark.parametrize(("args", "reason"), UNUSED)
def test_an_option_that_would_be_ignored_is_refused(args: tuple[str, ...], reason: str) -> None:
    from covswarm.deploy.cli import main

    done = CliRunner().invoke(main, list(args))
    assert done.exit_code == 2, done.output
    assert reason in " ".join(done.output.split()) and "Traceback" not in done.output


@click.command()
@click.option("--base", is_flag=True)
@float_option("--extra", default=1.0)
def needs_base(base: bool, extra: float) -> None:
    from covswarm.runtime.options import refuse_unused

    refuse_unused(click.get_current_context(), ("extra",), base, "--base")
    click.echo(f"extra {extra}")


def test_refuse_unused_looks_at_the_command_line_only() -> None:
    # the default is no reason to refuse, nor an option given with what uses it
    assert CliRunner().invoke(needs_base, []).output == "extra 1.0\n"
    assert CliRunner().invoke(needs_base, ["--base", "--extra", "2"]).output == "extra 2.0\n"
    done = CliRunner().invoke(needs_base, ["--extra", "1"])  # even at its default value
    assert done.exit_code == 2 and "--extra: only with --base" in done.output


def test_every_option_of_every_command_says_what_it_is() -> None:
    from covswarm.deploy.cli import main

    silent = []

    def walk(command: click.Command, path: list[str], ctx: click.Context) -> None:
        if isinstance(command, click.Group):
            for name in command.list_commands(ctx):
                sub = command.get_command(ctx, name)
                assert sub is not None
                walk(sub, [*path, name], click.Context(sub, parent=ctx))
            return
        for param in command.params:
            if isinstance(param, click.Option) and not param.hidden and not param.help:
                silent.append(f"covswarm {' '.join(path)} {param.opts[0]}")

    walk(main, [], click.Context(main))
    assert not silent, silent


@pytest.mark.e2e  # were the refusal lost, the run would start its processes
def test_a_run_never_writes_into_an_earlier_runs_folder(tmp_path) -> None:
    from covswarm.deploy.cli import main
    from covswarm.runtime.options import check_new_folder

    check_new_folder(tmp_path / "new")  # new: fine
    (tmp_path / "empty").mkdir()
    check_new_folder(tmp_path / "empty")  # empty: fine
    used = tmp_path / "used"
    used.mkdir()
    (used / "run-1.mcap").write_bytes(b"")  # an earlier, resumed run's record
    for command in (["run", "--agents", "2"], ["sim", "--scenario", "circle"]):
        done = CliRunner().invoke(main, [*command, "--out", str(used)])
        assert done.exit_code == 2, done.output
        said = " ".join(done.output.split())
        assert f"{used} already holds run-1.mcap: give a new folder" in said
    (tmp_path / "file").write_text("")
    with pytest.raises(click.BadParameter, match="is a file"):
        check_new_folder(tmp_path / "file")


def test_the_default_folder_is_new_even_within_the_same_second(tmp_path, monkeypatch) -> None:
    from covswarm.runtime.options import default_out

    monkeypatch.chdir(tmp_path)
    first = default_out("sim", "circle")
    assert first.parent == Path("runs") and first.name.startswith("sim-circle-")
    first.mkdir(parents=True)
    second = default_out("sim", "circle")  # "-2" within the same second, else the next one
    assert second != first and not second.exists()
