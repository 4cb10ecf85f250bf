"""Follows a distributed run: staggered start-up, liveliness, children that die, resources."""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from covswarm.coordinator.core import WAITING_FOR
from covswarm.deploy.display import PlainLines, Progress, progress_line, render
from covswarm.deploy.plan import ChildSpec
from covswarm.deploy.processes import (
    LAUNCHER,
    Child,
    RunResult,
    cpu_seconds,
    interrupts,
    rss_mb,
    spawn,
    stop_children,
)

TICK = 0.1  # s between launcher loop iterations (display, liveness, child polling)
COORDINATOR_GRACE = 60.0  # s for an interrupted coordinator to write its outputs
# A child not ready after this long stops holding a start-up slot. Generous: on an
# overloaded machine starting more processes at once only makes every start slower.
STALL = 120.0
# s a child's exit before the mission started waits for a Status saying it had (they come
# at the coordinator's broadcast rate, 20 Hz by default) before it stops the run.
START_GRACE = 1.0


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
        # A child that exited before the mission started (its log's last line says why):
        # the run cannot be the one asked for. A simulated robot refused because its id
        # already runs in the swarm (a bridge's real robot) left the mission to drive
        # whoever held that id, and that robot's token made the launcher count it ready.
        self.failed_start: tuple[Child, str] | None = None
        # One that exited while the mission had not started as far as we know, and when:
        # a failed start unless a Status says within START_GRACE that it had (a child that
        # died as the mission began, its Status still on the way).
        self._exited_early: tuple[Child, float] | None = None
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
            elif spec.role == "console":
                self.startup.ready.add(spec.name)  # it holds no liveliness token
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
                if not self._started() and self._exited_early is None:
                    self._exited_early = (child, now)
                elif child is not self.coordinator:
                    self._tell_exit(child, now)
        if self._exited_early is not None and self.failed_start is None:
            child, when = self._exited_early
            if self._started():
                self._exited_early = None
                if child is not self.coordinator:
                    self._tell_exit(child, when)
            elif now - when >= START_GRACE:
                self.failed_start = (child, last_line(child.log_path))
        status = self.progress.status
        if status is not None and status.state == "running" and self._cpu_at_start is None:
            self._cpu_at_start = (now, self._cpu_times())
        if status is not None and status.state == "done":
            self.measure_resources(now)

    def _started(self) -> bool:
        """Whether a Status has said the mission is under way (or over)."""
        status = self.progress.status
        return status is not None and status.state != "waiting"

    def _tell_exit(self, child: Child, when: float) -> None:
        self.console.log(
            f"[red]{child.spec.name} (pid {child.process.pid}) exited with {child.exit_code} "
            f"{when - self.began:.1f} s after launch; see {child.log_path}"
        )

    def _cpu_times(self) -> dict[str, float | None]:
        times = {name: cpu_seconds(c.process.pid) for name, c in self.children.items()}
        times[LAUNCHER] = cpu_seconds(os.getpid())  # its embedded router serves every child
        return times

    def measure_resources(self, now: float | None = None) -> None:
        """RSS of every child at the end of the mission (all still up: when it is done, or
        when the operator interrupts it) and its CPU use since the mission started; once."""
        if self.rss:
            return
        now = time.monotonic() if now is None else now
        started, before = self._cpu_at_start or (now, {})
        after = self._cpu_times()
        for child in self.children.values():
            if (mb := rss_mb(child.process.pid)) is not None:
                self.rss.setdefault(child.spec.role, []).append(mb)
                self.members.setdefault(child.spec.role, []).append(len(child.spec.members))
        roles = {name: child.spec.role for name, child in self.children.items()}
        for name, role in {**roles, LAUNCHER: LAUNCHER}.items():
            if now > started and before.get(name) is not None and after[name] is not None:
                share = 100.0 * (after[name] - before[name]) / (now - started)
                self.cpu.setdefault(role, []).append(share)

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


def last_line(path: Path, containing: str = "") -> str:
    """The last non-blank line of a child's log that holds ``containing`` ("" if none):
    what it said before exiting."""
    try:
        lines = path.read_text("utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    said = (line.strip() for line in reversed(lines) if line.strip() and containing in line)
    return next(said, "")


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
    routes: tuple[str, ...] = (),
) -> RunResult:
    """Start the children, follow the run until the coordinator exits, stop everyone.

    Without a coordinator among ``specs`` (it runs on another host) the run ends when the
    coordinator's Status says "done". routes: a planned route's lines
    (mission.scenarios.route_lines), shown with the start-up (logged once when the output
    is not a terminal, where the live display shows nothing).
    """
    from rich.live import Live

    progress = Progress(agents, duration, routes=routes)
    if not console.is_terminal:
        for line in routes:
            console.log(line)
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
            plain = PlainLines(console)  # a pipe or a file: the live display shows nothing
            with Live(render(progress), console=console, transient=False) as live:
                while True:
                    supervisor.tick()
                    live.update(render(progress))
                    plain(lambda: progress_line(progress))
                    if received:
                        console.log("interrupted: stopping the coordinator (it writes outputs)")
                        exit_code = 128 + received[0]
                        supervisor.measure_resources()  # while every child is still up
                        supervisor.stop_coordinator(received)
                        break
                    if supervisor.failed_start is not None:
                        child, said = supervisor.failed_start
                        console.log(
                            f"[red]{child.spec.name} (pid {child.process.pid}) exited with "
                            f"{child.exit_code} before the mission started: {said or 'no output'} "
                            f"(see {child.log_path}); stopping the run"
                        )
                        exit_code = 1
                        break
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
                    waited = time.monotonic() - supervisor.began
                    if not supervisor.startup.done and waited > startup_timeout:
                        console.log(f"[red]start-up took more than {startup_timeout:.0f} s")
                        if supervisor.coordinator is not None:  # who it was waiting for
                            said = last_line(supervisor.coordinator.log_path, WAITING_FOR)
                            if said:  # without the log line's time and name
                                said = WAITING_FOR + said.split(WAITING_FOR, 1)[1]
                                console.log(f"[red]the coordinator: {said}")
                        exit_code = 1
                        break
                    time.sleep(TICK)
        finally:
            supervisor.close()
    return RunResult(exit_code, supervisor.rss, supervisor.cpu, supervisor.members)
