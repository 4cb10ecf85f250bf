"""The operator console measured on a live run: drag latency, frame rate, its own CPU.

Usage: .venv/bin/python scripts/console_measure.py [--agents 10] [--scenario passage]
       [--drags 10] [--cpu-window 20] [--screenshot docs/img/console.png] [--out DIR]

Starts ``covswarm run`` and ``covswarm console`` (real processes, loopback Zenoh), opens the
page in Debian's chromium through Playwright and

- drags S with the mouse ``--drags`` times (0.3 m down, then back up, ...), each from rest
  (a first steering request takes S over from the scenario's script), and times, from the
  mouse button's release, (a) the page's round trip (POST /api/steer answered by the
  coordinator) and (b) the arrival, at a Zenoh subscriber of this script's own, of the first
  Domain broadcast whose S differs from the one held before the drag. The coordinator's
  broadcast in the tick that accepts the request still shows S at rest (the motion's
  progress starts with zero velocity), so (b) is that of the next one, up to one broadcast
  period (50 ms at 20 Hz) later;
- measures the console process's CPU (utime + stime from /proc) over ``--cpu-window`` s
  with no page open, then as long with the page open, the frames per second the page
  received and the size of one frame;
- optionally saves a screenshot of the page in the middle of a drag.

Prints one JSON document (also written to OUT/console-measure.json).
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import subprocess
import time
from pathlib import Path

import click
import numpy as np

from covswarm.deploy.plan import covswarm_argv

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
DRAG = 0.3  # m per drag


def cpu_seconds(pid: int) -> float:
    """utime + stime of ``pid`` in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_until(predicate, timeout: float, period: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


def swarm_pids(swarm: str) -> set[int]:
    pids = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if swarm.encode() in (entry / "cmdline").read_bytes().split(b"\0"):
                    pids.add(int(entry.name))
            except OSError:
                continue
    return pids


class Domains:
    """This script's own subscriber: (arrival wall time, vertices, velocities) per Domain."""

    def __init__(self, session, swarm: str) -> None:
        from covswarm.protocol import Domain, domain_key

        self.seen: list[tuple[float, np.ndarray, np.ndarray]] = []

        def on_domain(sample) -> None:
            d = Domain.decode(sample.payload.to_bytes())
            self.seen.append((time.time(), np.array(d.vertices), np.array(d.velocities)))

        self._sub = session.declare_subscriber(domain_key(swarm), on_domain)

    def first_change_after(self, wall: float, held: np.ndarray) -> float | None:
        for arrived, vertices, velocities in list(self.seen):
            if arrived > wall and (
                np.abs(vertices - held).max() > 1e-9 or np.abs(velocities).max() > 1e-9
            ):
                return arrived
        return None


def drag(page, dy_m: float, screenshot: Path | None = None) -> float:
    """Drag S's centroid by ``dy_m`` metres on screen; the wall time of the release."""
    handles = page.evaluate("window.covswarm.handles()")
    x, y = page.evaluate(f"window.covswarm.clientXY({handles['c'][0]}, {handles['c'][1]})")
    scale = page.evaluate("window.covswarm.view()")["scale"]
    page.evaluate("window.covswarm.hooks.lastReply = null")
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x, y - dy_m * scale, steps=8)
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(screenshot))
    released = time.time()
    page.mouse.up()
    return released


@click.command()
@click.option("--agents", type=int, default=10, show_default=True)
@click.option("--scenario", default="passage", show_default=True)
@click.option("--agents-per-process", type=int, default=1, show_default=True)
@click.option("--drags", type=int, default=10, show_default=True)
@click.option("--cpu-window", type=float, default=20.0, show_default=True, help="s")
@click.option("--screenshot", type=click.Path(path_type=Path), default=None)
@click.option("--out", type=click.Path(path_type=Path), default=Path("runs/console-measure"))
def main(
    agents: int,
    scenario: str,
    agents_per_process: int,
    drags: int,
    cpu_window: float,
    screenshot: Path | None,
    out: Path,
) -> None:
    import zenoh
    from playwright.sync_api import sync_playwright

    from covswarm.protocol.session import session_config

    swarm = f"measure-{secrets.token_hex(4)}"
    out = out / swarm  # fresh: a previous run's logs must not look like this one's
    out.mkdir(parents=True)
    run_log = (out / "launcher.log").open("wb")
    launcher = subprocess.Popen(
        [*covswarm_argv(), "run", "--out", str(out / "run"), "--swarm", swarm,
         "--agents", str(agents), "--scenario", scenario, "--duration", "3600",
         "--agents-per-process", str(agents_per_process)],
        stdout=run_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    console = None
    try:
        coordinator_log = out / "run" / "logs" / "coordinator-0.log"
        if not wait_until(
            lambda: coordinator_log.exists() and "mission started" in coordinator_log.read_text(),
            timeout=300,
            period=0.5,
        ):
            raise click.ClickException(f"the mission did not start: see {out / 'launcher.log'}")
        endpoint = json.loads((out / "run" / "launch.json").read_text())["endpoint"]
        console = subprocess.Popen(
            [*covswarm_argv(), "console", "--connect", endpoint, "--swarm", swarm, "--port", "0"],
            stdout=subprocess.PIPE, stderr=(out / "console.log").open("wb"), text=True,
        )  # fmt: skip
        line = console.stdout.readline()
        url = line[line.index("http://") :].strip()
        result: dict = {"agents": agents, "scenario": scenario, "url": url}
        with zenoh.open(session_config([endpoint])) as session, sync_playwright() as p:
            domains = Domains(session, swarm)
            # CPU with no page open: the console only drains its subscriptions.
            time.sleep(2.0)
            cpu0, wall0 = cpu_seconds(console.pid), time.monotonic()
            time.sleep(cpu_window)
            idle = (cpu_seconds(console.pid) - cpu0) / (time.monotonic() - wall0)
            result["console_cpu_percent_idle"] = round(100 * idle, 1)
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 760})
            page.goto(url)
            page.wait_for_function(
                f"document.body.dataset.robotsDrawn === '{agents}'", timeout=60000
            )
            # CPU with the page open, streaming.
            frames0 = page.evaluate("window.covswarm.hooks.frames")
            cpu0, wall0 = cpu_seconds(console.pid), time.monotonic()
            time.sleep(cpu_window)
            cpu1, wall1 = cpu_seconds(console.pid), time.monotonic()
            frames1 = page.evaluate("window.covswarm.hooks.frames")
            result["console_cpu_percent_of_a_core"] = round(
                100 * (cpu1 - cpu0) / (wall1 - wall0), 1
            )
            result["frames_per_second"] = round((frames1 - frames0) / (wall1 - wall0), 2)
            state = page.evaluate("fetch('/api/state').then(r => r.text())")
            result["frame_bytes"] = len(state.encode())
            # Drag latency, each drag from rest.
            round_trips, to_domain = [], []
            # First towards y = 0 (S stays in the workspace wherever the script left it),
            # then back, and so on.
            first = -DRAG if domains.seen[-1][1][:, 1].mean() > 0 else DRAG
            for k in range(drags + 1 if drags else 0):
                held = domains.seen[-1][1]
                shot = screenshot if screenshot is not None and k == drags else None
                released = drag(page, first if k % 2 == 0 else -first, shot)
                page.wait_for_function("window.covswarm.hooks.lastReply !== null", timeout=10000)
                reply = page.evaluate("window.covswarm.hooks.lastReply")
                if not reply["accepted"]:
                    raise click.ClickException(f"drag {k} refused: {reply['reason']}")
                wait_until(lambda: domains.first_change_after(released, held), timeout=5)  # noqa: B023
                changed = domains.first_change_after(released, held)
                if k > 0:  # the first drag takes S over from the script: not from rest
                    round_trips.append(page.evaluate("window.covswarm.hooks.roundTripMs"))
                    to_domain.append(1e3 * (changed - released))
                time.sleep(reply["duration"] + 0.3)  # S at rest again
            for name, values in (
                ("page_round_trip_ms", round_trips),
                ("drag_to_domain_ms", to_domain),
            ):
                if values:
                    result[name] = {
                        "median": round(float(np.median(values)), 1),
                        "p90": round(float(np.percentile(values, 90)), 1),
                        "max": round(float(np.max(values)), 1),
                        "n": len(values),
                    }
            browser.close()
        (out / "console-measure.json").write_text(json.dumps(result, indent=1) + "\n")
        click.echo(json.dumps(result, indent=1))
    finally:
        if console is not None:
            console.terminate()
            console.wait(timeout=10)
        launcher.send_signal(signal.SIGTERM)
        try:
            launcher.wait(timeout=60)
        except subprocess.TimeoutExpired:
            launcher.kill()
        run_log.close()
        for pid in swarm_pids(swarm):
            os.kill(pid, signal.SIGKILL)


if __name__ == "__main__":
    main()
