"""Robots driving into S from outside it: how close they come, at which step rates and
command latencies, and how much the unseen-speed limit slows them.

Usage: .venv/bin/python scripts/approach_safety.py [--seeds 3] [--out DIR] [--cost]

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

``--cost``: what the moving beacons cost a team that rides S, instead: the beacons each
robot sent in 20 s of the 100-robot circle (S translating at 0.19 m/s, 10 Hz), and the
share of the robots that beaconed in each second, per seed.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from approaches import approach, ring, scattered  # noqa: E402

from covswarm.agent import brain as brain_module  # noqa: E402
from covswarm.deploy.netsim import run_netsim, steady_state  # noqa: E402
from covswarm.mission.scenario_files import load_scenario  # noqa: E402

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


def beacon_cost(seeds: int) -> None:
    """Print the beacons per robot of 20 s of the 100-robot circle, per seed."""
    sent: collections.Counter[int] = collections.Counter()
    beacon = brain_module.AgentBrain.beacon

    def counted(self, now, stamp):  # type: ignore[no-untyped-def]
        out = beacon(self, now, stamp)
        sent[int(now)] += out is not None
        return out

    brain_module.AgentBrain.beacon = counted  # type: ignore[method-assign]
    scenario = load_scenario("circle")
    print("| seed | beacons per robot in 20 s | robots beaconing per second (%) | e_a (m) |")
    print("|---|---|---|---|")
    for seed in range(seeds):
        sent.clear()
        result = run_netsim(scenario, duration=20.0, seed=seed)
        shares = [100.0 * sent[k] / scenario.agents for k in sorted(sent)]
        print(
            f"| {seed} | {sum(sent.values()) / scenario.agents:.2f} "
            f"| {' '.join(f'{s:.0f}' for s in shares)} | {steady_state(result):.4f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("runs/approach-safety"))
    parser.add_argument("--cost", action="store_true", help="the beacons of a team riding S")
    args = parser.parse_args()
    if args.cost:
        beacon_cost(args.seeds)
        return
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
