"""Robots driving into S from outside it: how close they come, at which step rates and
command latencies, and how much the unseen-speed limit slows them.

Usage: .venv/bin/python scripts/approach_safety.py [--seeds 3] [--out DIR]

Two stress cases, each in the agents' closed loop of covswarm.deploy.netsim (real brains
and robot models; the commands ``latency`` s late and the agents told so), S a still
square the robots start outside of (cells empty on the way in):

- ``deploy``: 20 robots scattered over a 6 m square (none within 1 m of the centre, at
  random headings) into a 1 m S, 15 s;
- ``ring``: 2, 4 and 6 robots on a 1.5 m circle, each facing the centre, into a 0.2 m S,
  15 s: every pair heads for the others at the wheels' top speed.

Prints a markdown table per case (min over seeds of the closest two robots came, m; the
0.1 s samples at which two touched, closer than the 0.14 m body, summed over seeds; the
mission steps slowed by covswarm.tvd.safety.unseen_speed_limit, mean over seeds; e_a at the
end, mean, m) and writes approach_safety.json to ``--out``. docs/real-robots.md quotes it.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from approaches import approach, ring, scattered  # noqa: E402

RATES = (10.0, 5.0, 2.0)  # Hz
LATENCIES = (0.0, 0.1, 0.3)  # s


def cases(seeds: int):
    """(case, robots, rate, latency, [(start poses, S's side, seed) per seed])."""
    for rate in RATES:
        for latency in LATENCIES:
            runs = [(scattered(20, seed), 1.0, seed) for seed in range(seeds)]
            yield "deploy", 20, rate, latency, runs
    for robots in (2, 4, 6):
        for rate in RATES:
            for latency in LATENCIES:
                runs = [(ring(robots, 1.5), 0.2, seed) for seed in range(seeds)]
                yield "ring", robots, rate, latency, runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("approach-safety"))
    args = parser.parse_args()
    rows = []
    for case, robots, rate, latency, runs in cases(args.seeds):
        seen = [approach(p, side, seed, rate, latency) for p, side, seed in runs]
        rows.append(
            {
                "case": case,
                "robots": robots,
                "rate_hz": rate,
                "latency_s": latency,
                "runs": [asdict(s) for s in seen],
                "closest_m": min(s.closest for s in seen),
                "touching_samples": sum(s.touching for s in seen),
                "speed_limited_steps": float(np.mean([s.speed_limited for s in seen])),
                "final_error_m": float(np.mean([s.final_error for s in seen])),
            }
        )
        print(f"{case} {robots} robots {rate:g} Hz {latency:g} s: done", file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "approach_safety.json").write_text(json.dumps(rows, indent=1))
    print(
        "| case | robots | rate (Hz) | latency (s) | closest (m) | samples touching "
        "| steps slowed | e_a at the end (m) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['case']} | {row['robots']} | {row['rate_hz']:g} | {row['latency_s']:g} "
            f"| {row['closest_m']:.3f} | {row['touching_samples']} "
            f"| {row['speed_limited_steps']:.0f} | {row['final_error_m']:.3f} |"
        )


if __name__ == "__main__":
    main()
