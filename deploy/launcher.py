"""``covswarm run``: one real distributed run on this machine.

Starts an embedded Zenoh router (a router-mode session in this process, on a free loopback
port), then the coordinator, one ``covswarm robot`` and one ``covswarm agent`` process per
robot, staggered: on a 2-core machine start-up (imports) dominates, so only a few processes
start at a time and the next ones wait until those hold their liveliness token. Shows live
progress, reports children that die, and shuts everything down on completion, Ctrl-C or
SIGTERM. Children die with the launcher even if it is SIGKILLed (PR_SET_PDEATHSIG).

Scaling (docs/scaling.md): ``--agents-per-process K`` packs K brains into one agent
process and K robots into one robot process; ``--time-scale`` runs mission time slower
than wall time. A team spread over several hosts runs one ``covswarm run`` per host with
the same ``--swarm``, ``--agents`` and ``--seed``: ``--ids`` picks the host's slice,
``--router-listen``/``--router-connect`` link the hosts' embedded routers, and every host
but one says ``--no-coordinator``.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import click
import numpy as np

from covswarm.coordinator.monitor import HEADLINE_STATS
from covswarm.coordinator.scenarios import Scenario, load_scenario
from covswarm.protocol.keys import format_ids, parse_ids
from covswarm.protocol.security import SECURE_OPTION
from covswarm.protocol.session import TIME_SCALE_OPTION

ROUTER_HOST = "127.0.0.1"
TICK = 0.1  # s between launcher loop iterations (display, liveness, child polling)
TERMINATE_GRACE = 5.0  # s between SIGTERM and SIGKILL when stopping children
COORDINATOR_GRACE = 60.0  # s for an interrupted coordinator to write its outputs
# A child not ready after this long stops holding a start-up slot. Generous: on an
# overloaded machine starting more processes at once only makes every start slower.
STALL = 120.0
PR_SET_PDEATHSIG = 1  # linux/prctl.h

log = logging.getLogger("covswarm.launcher")


# ---------------------------------------------------------------------------- planning


@dataclass(frozen=True)
class ChildSpec:
    """One process to start: its role, id(s) and command line.

    A robot or agent process may host several robots or brains (``--agents-per-process``):
    ``idents`` lists them (empty: just ``ident``); the process is ready once every one of
    them holds its liveliness token.
    """

    role: str  # "coordinator" | "robot" | "agent"
    ident: int
    argv: tuple[str, ...]
    idents: tuple[int, ...] = ()

    @property
    def members(self) -> tuple[int, ...]:
        return self.idents or (self.ident,)

    @property
    def name(self) -> str:
        return f"{self.role}-{format_ids(list(self.members))}"


def covswarm_argv() -> list[str]:
    """How to run ``covswarm`` with this interpreter, readable in ``ps``.

    The console script next to sys.executable (the venv's), else ``python -c`` on the entry
    point, so children always run the same installation as the launcher.
    """
    script = Path(sys.executable).with_name("covswarm")
    if script.exists():
        return [sys.executable, str(script)]
    return [sys.executable, "-c", "from deploy.cli import main; main()"]


def initial_poses(scenario: Scenario, n: int, seed: int) -> np.ndarray:
    """(n, 3) x, y, heading: positions as ``covswarm sim``, headings from their own stream."""
    positions = scenario.initial_positions(n, seed)
    headings = np.random.default_rng([seed, 1]).uniform(-np.pi, np.pi, size=n)
    return np.column_stack([positions, headings])


def plan_children(
    scenario: Scenario,
    *,
    scenario_arg: str,
    agents: int,
    seed: int,
    endpoint: str,
    swarm: str,
    rate: float,
    kappa: float,
    feedforward: bool,
    duration: float,
    out_dir: Path,
    base: Sequence[str],
    ids: Sequence[int] | None = None,
    per_process: int = 1,
    coordinator: bool = True,
    time_scale: float = 1.0,
    agent_args: Sequence[str] = (),
    secure: Path | None = None,
) -> list[ChildSpec]:
    """Coordinator first (it must see everyone arrive), then robot i and agent i in turn.

    Pairs rather than all robots first: a waiting robot already runs its loop, so starting
    every robot before the (slower to import) agents would load the machine while the
    agents start. The coordinator holds the mission until everyone is up either way.

    ``ids``: the slice of the team of ``agents`` this host runs (default: all of it); a
    robot starts where it would in the full team, so hosts that split a team with the same
    seed reproduce the one-host run. ``per_process`` robots (brains) share a robot (agent)
    process; ``coordinator=False`` leaves the coordinator to another host. ``agent_args``
    are appended to every agent's command line (fault injection). ``secure``: every child
    gets ``--secure`` (protocol.security).
    """
    secured = () if secure is None else ("--secure", str(secure))
    common = ("--connect", endpoint, "--swarm", swarm, *secured)
    ff = () if feedforward else ("--no-feedforward",)
    scale = () if time_scale == 1.0 else ("--time-scale", repr(time_scale))
    specs = []
    if coordinator:
        argv = (
            *base, "coordinator", "--scenario", scenario_arg, *common, "--agents", str(agents),
            "--duration", repr(duration), "--kappa", repr(kappa), "--out", str(out_dir),
            "--feedforward" if feedforward else "--no-feedforward", *scale,
        )  # fmt: skip
        specs.append(ChildSpec("coordinator", 0, argv))
    poses = initial_poses(scenario, agents, seed)
    chosen = list(range(agents)) if ids is None else sorted(ids)
    for start in range(0, len(chosen), per_process):
        group = chosen[start : start + per_process]
        if per_process == 1:
            (i,) = group
            x, y, theta = (repr(float(v)) for v in poses[i])
            robot_ids: tuple[str, ...] = ("--id", str(i), "--x", x, "--y", y, "--theta", theta)
            agent_ids: tuple[str, ...] = ("--id", str(i))
        else:
            listed = format_ids(group)
            agent_ids = ("--ids", listed)
            robot_ids = agent_ids + tuple(
                arg for i in group for arg in ("--pose", ",".join(repr(float(v)) for v in poses[i]))
            )
        robot = (*base, "robot", *robot_ids, *common, *scale)
        agent = (
            *base, "agent", *agent_ids, *common, "--rate", repr(rate), "--kappa", repr(kappa),
            *ff, *scale, *agent_args,
        )  # fmt: skip
        members = tuple(group) if per_process > 1 else ()
        specs += [
            ChildSpec("robot", group[0], robot, members),
            ChildSpec("agent", group[0], agent, members),
        ]
    return specs


def impairment_args(loss: float, delay: float, seed: int) -> tuple[str, ...]:
    """Agent options that inject pose loss and delay (none when both are zero)."""
    if loss == 0.0 and delay == 0.0:
        return ()
    return ("--drop-poses", repr(loss), "--delay-poses", repr(delay), "--pose-seed", str(seed))


# ---------------------------------------------------------------------------- start-up


@dataclass
class Startup:
    """Staggered start: at most ``max_starting`` children between spawn and ready.

    A child counts as starting from spawn until its liveliness token appears, it exits, or
    ``stall`` seconds pass (a stuck child must not hold the rest of the team back).
    """

    pending: list[ChildSpec]
    max_starting: int
    stall: float
    spawned: dict[str, float] = field(default_factory=dict)  # name -> monotonic spawn time
    ready: set[str] = field(default_factory=set)
    exited: set[str] = field(default_factory=set)

    def starting(self, now: float) -> int:
        return sum(
            1
            for name, at in self.spawned.items()
            if name not in self.ready and name not in self.exited and now - at < self.stall
        )

    def next_batch(self, now: float) -> list[ChildSpec]:
        """Children to spawn now (and marks them spawned)."""
        batch: list[ChildSpec] = []
        while self.pending and self.starting(now) + len(batch) < self.max_starting:
            batch.append(self.pending.pop(0))
        for spec in batch:
            self.spawned[spec.name] = now
        return batch

    @property
    def done(self) -> bool:
        """Every child spawned, and every spawned child ready or gone."""
        return not self.pending and set(self.spawned) <= self.ready | self.exited


# ---------------------------------------------------------------------------- processes


_prctl = ctypes.CDLL(None, use_errno=True).prctl  # resolved now: the child only calls it


def _die_with(parent: int) -> Callable[[], None]:
    """preexec_fn: the kernel SIGKILLs the child when the launcher dies, however it dies."""

    def setup() -> None:
        _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() != parent:  # the launcher died before prctl took effect
            os._exit(1)

    return setup


@dataclass
class Child:
    """A started child; ``exit_code`` is set once the launcher has noticed it exited."""

    spec: ChildSpec
    process: subprocess.Popen
    log_path: Path
    exit_code: int | None = None


def spawn(spec: ChildSpec, log_dir: Path) -> Child:
    """Start one child in its own process group (Ctrl-C reaches only the launcher)."""
    log_path = log_dir / f"{spec.name}.log"
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            spec.argv,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            process_group=0,
            preexec_fn=_die_with(os.getpid()),
        )
    return Child(spec, process, log_path)


def stop_children(children: Sequence[Child], grace: float = TERMINATE_GRACE) -> None:
    """SIGTERM every live child, SIGKILL whatever is left after ``grace``, reap all."""
    for child in children:
        if child.process.poll() is None:
            child.process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for child in children:
        try:
            child.process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.process.kill()
            child.process.wait()


def rss_mb(pid: int) -> float | None:
    """Resident set size of a live process in MB (Linux /proc), None if it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a live process in s (Linux /proc), None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    # Fields 14 and 15 of proc(5) (utime, stime); fields[0] is field 3 (state).
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port(host: str = ROUTER_HOST) -> int:
    """A TCP port nobody listens on right now (bind to port 0 and ask the OS)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def local_endpoint(listen: str) -> str:
    """The endpoint this host's children use to reach a router listening on ``listen``:
    the same, except that a wildcard address (every interface) is reached on loopback."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]"):
        return f"{proto}/{ROUTER_HOST}:{port}"
    return listen


@contextmanager
def zenoh_session(
    connect: str | None,
    max_sessions: int,
    listen: Sequence[str] = (),
    peers: Sequence[str] = (),
    secure: Path | None = None,
) -> Iterator[tuple[Any, str]]:
    """(session, endpoint children connect to): an embedded router, or a client of ``connect``.

    The embedded router listens on ``listen`` (reachable from other hosts) or else on a free
    loopback port; the free port can be taken by someone else between probing and
    listening, so a failed listen is retried on a fresh port. It connects to the routers
    of ``peers`` (other hosts of the swarm; zenoh keeps retrying until they are up), which
    then route between the hosts' processes. ``secure``: TLS and user/password
    (protocol.security); the free loopback port is then a ``tls/`` endpoint.
    """
    import zenoh

    from covswarm.protocol import session_config

    if connect is not None:
        session = zenoh.open(session_config([connect], secure=secure))
        with _closing(session):
            yield session, connect
        return
    if listen:
        config = session_config(
            list(peers), list(listen), mode="router", max_sessions=max_sessions, secure=secure
        )
        session = zenoh.open(config)
        with _closing(session):
            yield session, local_endpoint(listen[0])
        return
    for attempt in range(5):
        scheme = "tcp" if secure is None else "tls"
        endpoint = f"{scheme}/{ROUTER_HOST}:{free_port()}"
        config = session_config(
            list(peers), [endpoint], mode="router", max_sessions=max_sessions, secure=secure
        )
        try:
            session = zenoh.open(config)
        except zenoh.ZError:
            if attempt == 4:
                raise
            continue
        with _closing(session):
            yield session, endpoint
        return


@contextmanager
def _closing(session: Any) -> Iterator[None]:
    """Close ``session`` on the way out; a close that times out is logged, not raised.

    A router whose 2000 clients all leave at once timed out closing (zenoh's "close
    operation timed out"): the run was over and its outputs not yet written.
    """
    import zenoh

    try:
        yield
    finally:
        try:
            session.close()
        except zenoh.ZError as exc:
            log.warning("closing the Zenoh session: %s", exc)


@contextmanager
def interrupts() -> Iterator[list[int]]:
    """Signals received (SIGINT, SIGTERM) as a list the main loop polls; handlers restored."""
    received: list[int] = []
    previous = {
        sig: signal.signal(sig, lambda signum, _frame: received.append(signum))
        for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        yield received
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


# ---------------------------------------------------------------------------- the run


@dataclass
class Progress:
    """What the display shows; updated by the launcher loop."""

    agents: int
    duration: float
    ready: set[tuple[str, int]] = field(default_factory=set)  # (role, id) seen alive
    status: Any = None  # latest protocol.Status


def render(progress: Progress) -> Any:
    """Start-up: processes ready per role. Mission: time, e_a, processes alive."""
    from rich.progress_bar import ProgressBar
    from rich.table import Table

    def bar(completed: float, total: float, text: str) -> Table:
        row = Table.grid(padding=(0, 1))
        row.add_row(ProgressBar(total=total, completed=completed, width=30), text)
        return row

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    n = progress.agents
    status = progress.status
    if status is None or status.state == "waiting":
        table.add_row("phase", "start-up (waiting for liveliness tokens)")
        for label, role, total in (
            ("coordinator", "coordinator", 1), ("robots", "robot", n), ("agents", "agent", n)
        ):  # fmt: skip
            count = sum(1 for r, _ in progress.ready if r == role)
            table.add_row(f"{label} ready", bar(count, total, f"{count}/{total}"))
        return table
    table.add_row("phase", status.state)
    table.add_row(
        "mission time",
        bar(status.t, progress.duration, f"{status.t:.1f} / {progress.duration:.1f} s"),
    )
    table.add_row("e_a", "-" if status.error is None else f"{status.error:.4f} m")
    table.add_row("robots alive", f"{status.alive_robots}/{n}")
    table.add_row("agents alive", f"{status.alive_agents}/{n}")
    return table


@dataclass
class RunResult:
    exit_code: int
    rss: dict[str, list[float]]  # role -> RSS (MB) of each child at the end of the mission
    cpu: dict[str, list[float]]  # role -> CPU use of each child during the mission, % of a core
    members: dict[str, list[int]] = field(default_factory=dict)  # role -> robots per child


class Supervisor:
    """Starts the children and follows them on the launcher's session, one tick at a time."""

    def __init__(
        self, specs: list[ChildSpec], *, session: Any, swarm: str, progress: Progress,
        log_dir: Path, console: Any,
    ) -> None:  # fmt: skip
        import zenoh

        from covswarm.protocol import alive_selector, status_key

        self.swarm, self.progress, self.log_dir, self.console = swarm, progress, log_dir, console
        self.startup = Startup(list(specs), max_starting=2 * (os.cpu_count() or 2), stall=STALL)
        self.children: dict[str, Child] = {}
        self.coordinator: Child | None = None
        self.rss: dict[str, list[float]] = {}
        self.cpu: dict[str, list[float]] = {}
        self.members: dict[str, list[int]] = {}
        # (role, id) -> the child that runs it: a child is ready once all its ids are up.
        self._owner = {(s.role, i): s for s in specs for i in s.members}
        self._up: set[tuple[str, int]] = set()
        self._cpu_at_start: tuple[float, dict[str, float | None]] | None = None
        self.began = time.monotonic()
        self._put = zenoh.SampleKind.PUT
        self._alive = session.liveliness().declare_subscriber(
            alive_selector(swarm),
            zenoh.handlers.FifoChannel(max(1024, 4 * len(specs))),
            history=True,
        )
        self._status = session.declare_subscriber(status_key(swarm), zenoh.handlers.RingChannel(1))

    def tick(self) -> None:
        """Spawn what is due, take in liveliness and Status, notice children that exited."""
        from covswarm.protocol import ProtocolError, Status, parse_alive_key

        now = time.monotonic()
        for spec in self.startup.next_batch(now):
            self.children[spec.name] = spawn(spec, self.log_dir)
            if spec.role == "coordinator":
                self.coordinator = self.children[spec.name]
        while (sample := self._alive.try_recv()) is not None:
            try:
                role, ident = parse_alive_key(str(sample.key_expr), self.swarm)
            except ValueError:
                continue
            if sample.kind == self._put:
                self._up.add((role, ident))
                self.progress.ready.add((role, ident))
                spec = self._owner.get((role, ident))
                if spec is not None and all((spec.role, i) in self._up for i in spec.members):
                    self.startup.ready.add(spec.name)
        while (sample := self._status.try_recv()) is not None:
            try:
                self.progress.status = Status.decode(sample.payload)
            except ProtocolError:
                continue
        for child in self.children.values():
            if child.exit_code is None and (code := child.process.poll()) is not None:
                child.exit_code = code
                self.startup.exited.add(child.spec.name)
                if child is not self.coordinator:
                    self.console.log(
                        f"[red]{child.spec.name} (pid {child.process.pid}) exited with {code} "
                        f"at {now - self.began:.1f} s; see {child.log_path}"
                    )
        status = self.progress.status
        if status is not None and status.state == "running" and self._cpu_at_start is None:
            self._cpu_at_start = (now, self._cpu_times())
        if status is not None and status.state == "done" and not self.rss:
            self._measure_resources(now)

    def _cpu_times(self) -> dict[str, float | None]:
        return {name: cpu_seconds(c.process.pid) for name, c in self.children.items()}

    def _measure_resources(self, now: float) -> None:
        """RSS of every child at the end of the mission (all still up) and its CPU use
        since the mission started."""
        started, before = self._cpu_at_start or (now, {})
        after = self._cpu_times()
        for name, child in self.children.items():
            if (mb := rss_mb(child.process.pid)) is not None:
                self.rss.setdefault(child.spec.role, []).append(mb)
                self.members.setdefault(child.spec.role, []).append(len(child.spec.members))
            if now > started and before.get(name) is not None and after[name] is not None:
                share = 100.0 * (after[name] - before[name]) / (now - started)
                self.cpu.setdefault(child.spec.role, []).append(share)

    def stop_coordinator(self, received: list[int]) -> None:
        """SIGTERM makes a running coordinator end the mission early and write its outputs;
        wait for that unless the operator interrupts a second time."""
        child = self.coordinator
        if child is None or child.process.poll() is not None:
            return
        child.process.send_signal(signal.SIGTERM)
        deadline, seen = time.monotonic() + COORDINATOR_GRACE, len(received)
        while child.process.poll() is None and time.monotonic() < deadline:
            if len(received) != seen:
                return
            time.sleep(TICK)

    def close(self) -> None:
        """Stop every child by pid and drop the subscriptions."""
        stop_children(list(self.children.values()))
        self._alive.undeclare()
        self._status.undeclare()


def run_processes(
    specs: list[ChildSpec],
    *,
    session: Any,
    swarm: str,
    agents: int,
    duration: float,
    log_dir: Path,
    startup_timeout: float,
    console: Any,
) -> RunResult:
    """Start the children, follow the run until the coordinator exits, stop everyone.

    Without a coordinator among ``specs`` (it runs on another host) the run ends when the
    coordinator's Status says "done".
    """
    from rich.live import Live

    progress = Progress(agents, duration)
    has_coordinator = any(spec.role == "coordinator" for spec in specs)
    exit_code = 0
    with interrupts() as received:
        supervisor = Supervisor(
            specs, session=session, swarm=swarm, progress=progress, log_dir=log_dir,
            console=console,
        )  # fmt: skip
        # try/finally: whatever goes wrong here (a bug, a second Ctrl-C) children are
        # stopped by pid; PR_SET_PDEATHSIG covers the launcher dying outright.
        try:
            with Live(render(progress), console=console, transient=False) as live:
                while True:
                    supervisor.tick()
                    live.update(render(progress))
                    coordinator = supervisor.coordinator
                    if coordinator is not None and coordinator.exit_code is not None:
                        if coordinator.exit_code != 0:
                            console.log(f"[red]coordinator exited with {coordinator.exit_code}")
                            exit_code = 1
                        break
                    status = progress.status
                    if not has_coordinator and status is not None and status.state == "done":
                        console.log("the coordinator (on another host) says the mission is done")
                        break
                    if received:
                        console.log("interrupted: stopping the coordinator (it writes outputs)")
                        exit_code = 128 + received[0]
                        supervisor.stop_coordinator(received)
                        break
                    waited = time.monotonic() - supervisor.began
                    if not supervisor.startup.done and waited > startup_timeout:
                        console.log(f"[red]start-up took more than {startup_timeout:.0f} s")
                        exit_code = 1
                        break
                    time.sleep(TICK)
        finally:
            supervisor.close()
    return RunResult(exit_code, supervisor.rss, supervisor.cpu, supervisor.members)


def summary_table(summary: dict[str, Any], result: RunResult, out_dir: Path) -> Any:
    """The closing table: errors, per-agent figures, memory, processes lost."""
    from rich.table import Table

    table = Table(title=f"covswarm run: {summary.get('scenario')}", show_header=False)
    table.add_column(style="bold")
    table.add_column()

    def fmt(value: Any, unit: str = "") -> str:
        return "-" if value is None else f"{value:.4g}{unit}"

    table.add_row("agents", str(summary.get("agents")))
    table.add_row("feedforward", str(summary.get("feedforward")))
    table.add_row("kappa", fmt(summary.get("kappa")))
    table.add_row("mission time", fmt(summary.get("mission_time"), " s"))
    table.add_row("e_a initial", fmt(summary.get("initial_error"), " m"))
    table.add_row("e_a steady state (2nd half)", fmt(summary.get("steady_state_error_mean"), " m"))
    table.add_row("e_a final", fmt(summary.get("final_error"), " m"))
    team = summary.get("agent_stats", {}).get("team", {})
    for name in HEADLINE_STATS:
        if name in team:
            f = team[name]
            table.add_row(
                f"agent {name}", f"mean {f['mean']:.4g}  min {f['min']:.4g}  max {f['max']:.4g}"
            )
    for role, values in sorted(result.rss.items()):
        table.add_row(
            f"RSS per {role} process", f"mean {np.mean(values):.0f} MB  max {max(values):.0f} MB"
        )
        if (hosted := sum(result.members.get(role, ()))) > len(values):
            table.add_row(f"RSS per {role}", f"{sum(values) / hosted:.1f} MB")
    for role, values in sorted(result.cpu.items()):
        table.add_row(
            f"CPU per {role} process",
            f"mean {np.mean(values):.1f}%  max {max(values):.1f}% of a core (total "
            f"{sum(values):.0f}%)",
        )
    lost = summary.get("lost_processes", [])
    table.add_row("liveliness lost", ", ".join(f"{e['role']} {e['id']}" for e in lost) or "none")
    table.add_row("outputs", str(out_dir))
    return table


@click.command("run")
@click.option(
    "--scenario",
    "scenario_name",
    default="passage",
    show_default=True,
    help="Built-in scenario (circle, passage) or a .toml file.",
)
@click.option("--agents", type=click.IntRange(min=1), help="Team size [scenario default].")
@click.option("--kappa", type=click.FloatRange(min=0, min_open=True), help="Gain [scenario].")
@click.option("--no-feedforward", is_flag=True, help="Drop the dc/dt feedforward term.")
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    help="Mission length, s [scenario default].",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Initial poses.")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Output folder [runs/run-<scenario>-<timestamp>].",
)
@click.option(
    "--rate",
    type=click.FloatRange(min=0.5),
    default=10.0,
    show_default=True,
    help="Control rate of every agent, Hz.",
)
@click.option("--swarm", help="Swarm name (key prefix) [random, unique per run].")
@click.option("--connect", help="Join this Zenoh endpoint instead of an embedded router.")
@click.option(
    "--ids",
    "ids_arg",
    help="Only these robot ids (and their agents) on this host, e.g. 0-49 [all]; needs --swarm.",
)
@click.option(
    "--no-coordinator",
    is_flag=True,
    help="The coordinator runs on another host: end when it says done; needs --swarm.",
)
@click.option(
    "--router-listen",
    multiple=True,
    help="Endpoint the embedded router listens on, e.g. tcp/10.0.0.1:7447 [a free loopback port].",
)
@click.option(
    "--router-connect",
    multiple=True,
    help="Another host's router for the embedded router to connect to (repeatable).",
)
@click.option(
    "--agents-per-process",
    "per_process",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Agent brains per agent process and robots per robot process.",
)
@TIME_SCALE_OPTION
@click.option(
    "--pose-loss",
    type=click.FloatRange(0.0, 1.0, max_open=True),
    default=0.0,
    show_default=True,
    help="Fault injection: every agent drops this fraction of received poses (seeded).",
)
@click.option(
    "--pose-delay",
    type=click.FloatRange(min=0.0),
    default=0.0,
    show_default=True,
    help="Fault injection: every agent receives poses this many s late.",
)
@click.option(
    "--startup-timeout",
    type=click.FloatRange(min=0, min_open=True),
    default=300.0,
    show_default=True,
    help="Give up if the team is not up after this many s.",
)
@SECURE_OPTION
def run_command(
    scenario_name: str,
    agents: int | None,
    kappa: float | None,
    no_feedforward: bool,
    duration: float | None,
    seed: int,
    out_dir: Path | None,
    rate: float,
    swarm: str | None,
    connect: str | None,
    ids_arg: str | None,
    no_coordinator: bool,
    router_listen: tuple[str, ...],
    router_connect: tuple[str, ...],
    per_process: int,
    time_scale: float,
    pose_loss: float,
    pose_delay: float,
    startup_timeout: float,
    secure: Path | None,
) -> None:
    """Run the swarm as real processes over Zenoh on this machine (or this host's slice)."""
    from rich.console import Console

    from covswarm.protocol import check_swarm, new_swarm_name

    if (ids_arg is not None or no_coordinator) and not swarm:
        raise click.UsageError("--ids and --no-coordinator need --swarm (the same on every host)")
    if connect is not None and (router_listen or router_connect):
        raise click.UsageError("--connect joins a router: no --router-listen/--router-connect")
    try:
        scenario = load_scenario(scenario_name)
        swarm = check_swarm(swarm) if swarm else new_swarm_name()
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    n = scenario.agents if agents is None else agents
    try:
        ids = None if ids_arg is None else parse_ids(ids_arg)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--ids") from None
    if ids is not None and ids[-1] >= n:
        raise click.BadParameter(f"ids go up to {ids[-1]} in a team of {n}", param_hint="--ids")
    duration = scenario.duration if duration is None else duration
    kappa = scenario.kappa if kappa is None else kappa
    if out_dir is None:
        out_dir = Path("runs") / f"run-{scenario.name}-{datetime.now():%Y%m%d-%H%M%S}"
    log_dir = out_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    console = Console()
    here = n if ids is None else len(ids)
    with zenoh_session(
        connect, max(1000, 4 * n), router_listen, router_connect, secure=secure
    ) as (session, endpoint):  # fmt: skip
        console.log(
            f"swarm {swarm} on {endpoint}; {here} robots + {here} agents here (team of {n}); "
            f"logs in {log_dir}"
        )
        specs = plan_children(
            scenario, scenario_arg=scenario_name, agents=n, seed=seed, endpoint=endpoint,
            swarm=swarm, rate=rate, kappa=kappa, feedforward=not no_feedforward,
            duration=duration, out_dir=out_dir, base=covswarm_argv(), ids=ids,
            per_process=per_process, coordinator=not no_coordinator, time_scale=time_scale,
            agent_args=impairment_args(pose_loss, pose_delay, seed), secure=secure,
        )  # fmt: skip
        (out_dir / "launch.json").write_text(
            json.dumps({"swarm": swarm, "endpoint": endpoint, "argv": [s.argv for s in specs]},
                       indent=1) + "\n", encoding="utf-8",
        )  # fmt: skip
        result = run_processes(
            specs, session=session, swarm=swarm, agents=n, duration=duration, log_dir=log_dir,
            startup_timeout=startup_timeout, console=console,
        )  # fmt: skip
    (out_dir / "resources.json").write_text(
        json.dumps(
            {
                "rss_mb": result.rss,
                "cpu_percent_of_core": result.cpu,
                "robots_per_process": result.members,
            },
            indent=1,
        )
        + "\n",
        encoding="utf-8",
    )
    console.print()  # the live display's last frame ends without a newline off a terminal
    summary_path = out_dir / "summary.json"
    if summary_path.exists():
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
        console.print(summary_table(summary, result, out_dir))
    elif no_coordinator:
        console.log(f"the coordinator's host writes the summary; resources in {out_dir}")
    else:
        console.log(f"[red]no summary written (see {log_dir / 'coordinator-0.log'})")
        result.exit_code = result.exit_code or 1
    sys.exit(result.exit_code)
