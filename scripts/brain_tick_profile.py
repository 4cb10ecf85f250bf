"""Where a packed brain-tick's time goes: py-spy over the bench's pack, by phase.

Usage: .venv/bin/python scripts/brain_tick_profile.py [--brains 500] [--ticks 100]

Runs one pack of ``--brains`` brains over the team of ``covswarm bench --brain-tick`` (0.2 m
apart, 10 Hz; deploy.bench.time_brain_ticks) for ``--ticks`` periods under ``py-spy record``
(next to this interpreter or on PATH), then prints the CPU us per brain-tick of the last
three quarters of them and, for the phases named in PHASES, the share of the samples taken
inside Pack.tick whose stack holds that function (inclusive; a sample counts once per
phase). docs/scaling.md quotes it.
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

PHASES = (
    "Pack.drain",
    "AgentBrain.receive_all",
    "Neighborhood.on_agent_states",
    "ClockBound.add",
    "Neighborhood.refresh",
    "local_steps",
    "AgentBrain.actions",
    "Pack._filter",
)


def run_pack(brains: int, ticks: int) -> float:
    """CPU us per brain-tick of the last three quarters of ``ticks`` periods."""
    from covswarm import protocol
    from covswarm.agent.brain import AgentBrain, AgentConfig
    from covswarm.agent.decoding import MessageDecoder
    from covswarm.agent.pack import LocalBus, Pack, collect_less
    from covswarm.deploy.bench import (
        BRAIN_TICK_SPACING,
        BRAIN_TICK_WALL,
        brain_tick_domain,
        make_layout,
    )

    layout = make_layout(brains, "cvt", 0, spacing=BRAIN_TICK_SPACING)
    bus, decoder, config = LocalBus(), MessageDecoder(), AgentConfig()
    pack = Pack(bus, "bench", [AgentBrain(i, config, decoder) for i in range(brains)])
    keys = [protocol.pose_key("bench", i) for i in range(brains)]
    collect_less()
    first, cpu0 = ticks // 4, 0.0
    for k in range(ticks):
        t = k * 0.1
        bus.put(protocol.domain_key("bench"), brain_tick_domain(layout, t, k + 1))
        for rid, (x, y) in enumerate(layout.positions.tolist()):
            pose = protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=BRAIN_TICK_WALL + t, seq=k)
            bus.put(keys[rid], pose.encode())
        bus.sent.clear()
        if k == first:
            cpu0 = time.process_time()
        pack.tick(lambda t=t: t, lambda t=t: BRAIN_TICK_WALL + t, math.inf)
    return (time.process_time() - cpu0) / (ticks - first) / brains * 1e6


def shares(raw: Path) -> dict[str, float]:
    """% of the samples inside Pack.tick whose stack holds each of PHASES."""
    inside, counts = 0, collections.Counter()
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if "Pack.tick" not in stack:
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
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        print(f"{run_pack(args.brains, args.ticks):.0f} us of CPU per brain-tick")
        return
    beside = Path(sys.executable).with_name("py-spy")
    spy = str(beside) if beside.exists() else shutil.which("py-spy")
    if spy is None:
        sys.exit("py-spy not found: pip install py-spy")
    with tempfile.TemporaryDirectory() as folder:
        raw = Path(folder) / "raw.txt"
        inner = [sys.executable, __file__, "--inner", "--brains", str(args.brains)]
        inner += ["--ticks", str(args.ticks)]
        command = [spy, "record", "-r", "250", "--format", "raw", "-o", str(raw), "--", *inner]
        subprocess.run(command, check=True)
        for phase, share in shares(raw).items():
            print(f"{share:5.1f} %  {phase}")


if __name__ == "__main__":
    main()
