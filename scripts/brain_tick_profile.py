"""Where a packed brain-tick's time goes: py-spy over the bench's pack, by phase.

Usage: .venv/bin/python scripts/brain_tick_profile.py [--brains 500] [--ticks 100] [--late 1]

Runs one pack of ``--brains`` brains over the team of ``covswarm bench --brain-tick`` (0.2 m
apart, 10 Hz; deploy.bench.time_brain_ticks) for ``--ticks`` periods under ``py-spy record``
(next to this interpreter or on PATH), then prints the CPU us per brain-tick of the last
three quarters of them and, for the phases named in PHASES, the share of the samples taken
inside those periods' ticks whose stack holds that function (inclusive; a sample counts
once per phase). ``--late`` G: those periods as in a pack G times short of CPU (each brain
steps about every G periods, the poses and domains at 20 Hz; `covswarm bench --brain-tick
--brain-tick-late G`). docs/scaling.md quotes it.
"""

from __future__ import annotations

import argparse
import collections
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

PHASES = (
    "Pack.drain",
    "Pack.take_own_poses",
    "AgentBrain.receive_all",
    "Neighborhood.on_agent_states",
    "ClockBound.add",
    "AgentBrain.on_domain",
    "AgentBrain.on_beacon",
    "Neighborhood.refresh",
    "local_steps",
    "AgentBrain.actions",
    "AgentBrain.agent_state",
    "Pack._filter",
    "Pack._hold",
)


def run_pack(brains: int, ticks: int, late: float = 1.0) -> float:
    """CPU us per brain-tick of the last three quarters of ``ticks`` periods, the pack
    ``late`` times short of CPU from then on (deploy.bench.time_brain_ticks' ``late``)."""
    from covswarm.agent.brain import AgentBrain, AgentConfig
    from covswarm.agent.decoding import MessageDecoder
    from covswarm.agent.pack import LocalBus, Pack, collect_less
    from covswarm.deploy.bench import (
        BRAIN_TICK_SPACING,
        BRAIN_TICK_WALL,
        SpendingClock,
        make_layout,
        publish_period,
        sends_per_period,
    )

    layout = make_layout(brains, "cvt", 0, spacing=BRAIN_TICK_SPACING)
    bus, decoder, config = LocalBus(), MessageDecoder(), AgentConfig()
    pack = Pack(bus, "bench", [AgentBrain(i, config, decoder) for i in range(brains)])
    collect_less()
    period, first, cpu0, stepped = 0.1, ticks // 4, 0.0, 0
    clock = SpendingClock(period, brains, late)
    for k in range(ticks):
        t = k * period
        publish_period(bus, "bench", layout, k, period, sends_per_period(period, late))
        if k < first:
            pack.tick(lambda t=t: t, lambda t=t: BRAIN_TICK_WALL + t, math.inf)
            continue
        if k == first:
            cpu0 = time.process_time()
            if late > 1.0:
                for brain in pack.brains.values():
                    clock.charge(brain)
        clock.now = t
        stepped += timed_tick(pack, clock, t + period if late > 1.0 else math.inf)
    return (time.process_time() - cpu0) / max(stepped, 1) * 1e6


def timed_tick(pack: Any, clock: Any, deadline: float) -> int:
    """One timed period of ``pack`` (the frame :func:`shares` counts samples under)."""
    return pack.tick(clock, clock.wall, deadline)


def shares(raw: Path) -> dict[str, float]:
    """% of the samples inside a timed tick (timed_tick) whose stack holds each of PHASES."""
    inside, counts = 0, collections.Counter()
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if ";timed_tick (" not in f";{stack}":
            continue
        inside += int(n)
        for phase in PHASES:
            if f";{phase} (" in f";{stack}":
                counts[phase] += int(n)
    return {phase: 100.0 * counts[phase] / max(inside, 1) for phase in PHASES}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--brains", type=int, default=500)
    parser.add_argument("--ticks", type=int, default=100)
    parser.add_argument(
        "--late", type=float, default=1.0, help="the pack this many times short of CPU"
    )
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        print(f"{run_pack(args.brains, args.ticks, args.late):.0f} us of CPU per brain-tick")
        return
    beside = Path(sys.executable).with_name("py-spy")
    spy = str(beside) if beside.exists() else shutil.which("py-spy")
    if spy is None:
        sys.exit("py-spy not found: pip install py-spy")
    with tempfile.TemporaryDirectory() as folder:
        raw = Path(folder) / "raw.txt"
        inner = [sys.executable, __file__, "--inner", "--brains", str(args.brains)]
        inner += ["--ticks", str(args.ticks), "--late", str(args.late)]
        command = [spy, "record", "-r", "250", "--format", "raw", "-o", str(raw), "--", *inner]
        subprocess.run(command, check=True)
        for phase, share in shares(raw).items():
            print(f"{share:5.1f} %  {phase}")


if __name__ == "__main__":
    main()
