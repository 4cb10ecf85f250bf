"""Where a live run's CPU goes: per process, per thread, and how starved each process is.

Usage: .venv/bin/python scripts/live_cpu.py [--window 8] [--py-spy DIR] -- RUN-OPTIONS...
e.g.   .venv/bin/python scripts/live_cpu.py -- --agents 100 --scenario circle --duration 20
       --rate 30

Starts ``covswarm run RUN-OPTIONS --out DIR`` (DIR: ``--out`` if given among them, else a
dated folder under runs/), waits for its Status to say "running" (a Zenoh client of the
run's router, found in launch.json), lets the mission settle for two seconds, then reads
/proc of the launcher (its embedded router) and of every child at the start and the end of
``--window`` seconds and prints, per process:

- its CPU, % of a core, and that of each of its threads by name (``python``/``covswarm``:
  the main thread; ``rx-*``, ``tx-*``, ``app-*``, ``acc-*``: Zenoh's);
- its main thread's share of wall time running, waiting runnable (starved: other processes
  held the cores) and sleeping (/proc/PID/task/PID/schedstat);
- its minor page faults and voluntary/involuntary context switches per second.

``--py-spy DIR``: also ``py-spy record`` (if on PATH or next to this interpreter) every
agent, robot and coordinator process over the window, at 50 Hz without pausing them, as
speedscope files in DIR. After the run, the held rate, the periods missed and the live
brain-tick (resources.json) are printed. The machine's load (``uptime``) is printed before
and after: compare runs made back to back.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import zenoh

from covswarm.deploy.plan import covswarm_argv
from covswarm.protocol import Status, status_key
from covswarm.protocol.session import session_config

SETTLE = 2.0  # s after "running" before the window starts


def proc_stat(pid: int, tid: int | None = None) -> list[str] | None:
    """The fields of /proc/PID[/task/TID]/stat after the command name (field 3 first)."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    try:
        with open(path, encoding="ascii", errors="replace") as stat:
            return stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return None


def snapshot(pid: int) -> dict | None:
    """CPU s (user + system) of the process and of each thread, by thread name; minor
    faults; context switches; the main thread's run and run-queue wait, s."""
    ticks = os.sysconf("SC_CLK_TCK")
    fields = proc_stat(pid)
    if fields is None:
        return None
    threads: dict[str, float] = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        sub = proc_stat(pid, int(tid))
        try:
            with open(f"/proc/{pid}/task/{tid}/comm", encoding="utf-8") as comm:
                name = comm.read().strip()
        except OSError:
            continue
        if sub is not None:
            threads[name] = threads.get(name, 0.0) + (int(sub[11]) + int(sub[12])) / ticks
    status = {}
    with open(f"/proc/{pid}/status", encoding="utf-8") as lines:
        for line in lines:
            key, _, value = line.partition(":")
            status[key] = value.strip()
    with open(f"/proc/{pid}/task/{pid}/schedstat", encoding="ascii") as sched:
        run_ns, wait_ns, _ = sched.read().split()
    return {
        "cpu": (int(fields[11]) + int(fields[12])) / ticks,
        "threads": threads,
        "minflt": int(fields[7]),
        "voluntary": int(status["voluntary_ctxt_switches"]),
        "involuntary": int(status["nonvoluntary_ctxt_switches"]),
        "run": int(run_ns) / 1e9,
        "wait": int(wait_ns) / 1e9,
    }


def children(parent: int) -> dict[int, str]:
    """pid -> name (role and ids, e.g. agent-0-49) of the launcher's children."""
    found = {parent: "launcher"}
    listing = subprocess.run(
        ["ps", "--ppid", str(parent), "-o", "pid=,args="], capture_output=True, text=True
    ).stdout
    for line in listing.splitlines():
        pid, _, args = line.strip().partition(" ")
        words = args.split()
        role = next((w for w in words if w in ("agent", "robot", "coordinator", "console")), "?")
        flag = next((f for f in ("--ids", "--id") if f in words), None)
        found[int(pid)] = role if flag is None else f"{role}-{words[words.index(flag) + 1]}"
    return found


def wait_running(out: Path, launcher: subprocess.Popen) -> None:
    """Block until the run's coordinator says the mission runs (or the launcher exits)."""
    while not (out / "launch.json").exists():
        if launcher.poll() is not None:
            sys.exit(f"the run exited with {launcher.returncode} before it started")
        time.sleep(0.5)
    launch = json.loads((out / "launch.json").read_text(encoding="utf-8"))
    with zenoh.open(session_config([launch["endpoint"]])) as session:
        status = session.declare_subscriber(
            status_key(launch["swarm"]), zenoh.handlers.RingChannel(1)
        )
        while launcher.poll() is None:
            sample = status.try_recv()
            if sample is not None and Status.decode(sample.payload.to_bytes()).state != "waiting":
                return
            time.sleep(0.1)


def report(names: dict[int, str], before: dict, after: dict, seconds: float) -> None:
    for pid, name in sorted(names.items(), key=lambda item: item[1]):
        a, b = before.get(pid), after.get(pid)
        if a is None or b is None:
            continue

        def rate(key: str, a: dict = a, b: dict = b) -> float:
            return (b[key] - a[key]) / seconds

        threads = {
            n: 100.0 * (b["threads"][n] - a["threads"].get(n, 0.0)) / seconds for n in b["threads"]
        }
        busy = ", ".join(
            f"{n} {v:.1f}" for n, v in sorted(threads.items(), key=lambda t: -t[1]) if v >= 0.05
        )
        run, wait = rate("run"), rate("wait")
        print(f"{name:16s} {100 * rate('cpu'):5.1f} % of a core   threads: {busy}")
        print(
            f"{'':16s} main thread: running {run:.0%}, waiting for a core {wait:.0%}, "
            f"sleeping {max(0.0, 1 - run - wait):.0%}; minor faults {rate('minflt'):.0f}/s, "
            f"context switches {rate('voluntary'):.0f}/s voluntary, "
            f"{rate('involuntary'):.0f}/s involuntary"
        )


def py_spy_binary() -> str | None:
    beside = Path(sys.executable).with_name("py-spy")
    return str(beside) if beside.exists() else shutil.which("py-spy")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--window", type=float, default=8.0, help="s of mission measured")
    parser.add_argument("--py-spy", type=Path, default=None, help="folder for speedscope files")
    parser.add_argument("run", nargs=argparse.REMAINDER, help="covswarm run's options")
    args = parser.parse_args()
    run = [a for a in args.run if a != "--"]
    if "--out" in run:
        out = Path(run[run.index("--out") + 1])
    else:
        out = Path("runs") / f"live-cpu-{datetime.now():%Y%m%d-%H%M%S}"
        run += ["--out", str(out)]
    print("load:", os.getloadavg(), flush=True)
    began = time.monotonic()
    log = open(out.with_name(out.name + ".launcher.log"), "wb")  # noqa: SIM115 (the run's life)
    launcher = subprocess.Popen([*covswarm_argv(), "run", *run], stdout=log, stderr=log)
    try:
        wait_running(out, launcher)
        print(f"mission running after {time.monotonic() - began:.1f} s", flush=True)
        time.sleep(SETTLE)
        names = children(launcher.pid)
        spies = []
        if args.py_spy is not None and (spy := py_spy_binary()) is not None:
            args.py_spy.mkdir(parents=True, exist_ok=True)
            for pid, name in names.items():
                if name.split("-")[0] in ("agent", "robot", "coordinator"):
                    target = args.py_spy / f"{name}.speedscope.json"
                    spies.append(subprocess.Popen(
                        [spy, "record", "--pid", str(pid), "--duration", str(int(args.window)),
                         "--rate", "50", "--nonblocking", "--format", "speedscope", "-o",
                         str(target)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                    ))  # fmt: skip
        before, start = {pid: snapshot(pid) for pid in names}, time.monotonic()
        time.sleep(args.window)
        after, seconds = {pid: snapshot(pid) for pid in names}, time.monotonic() - start
        report(names, before, after, seconds)
        for spy_process in spies:
            spy_process.wait()
        code = launcher.wait()
    finally:
        if launcher.poll() is None:
            launcher.terminate()
            launcher.wait()
        log.close()
    print(f"run exited with {code} after {time.monotonic() - began:.1f} s; load:", os.getloadavg())
    summary, resources = out / "summary.json", out / "resources.json"
    if summary.exists() and resources.exists():
        pace = json.loads(summary.read_text(encoding="utf-8"))["pace"]
        tick = json.loads(resources.read_text(encoding="utf-8")).get("brain_tick_s")
        print(
            f"held {pace['held_rate_hz']:.3g} Hz of {pace['asked_rate_hz']:g}, "
            f"{pace['periods_missed']:.0%} of periods missed; live brain-tick "
            + ("-" if tick is None else f"{1e3 * tick:.3f} ms")
        )


if __name__ == "__main__":
    main()
