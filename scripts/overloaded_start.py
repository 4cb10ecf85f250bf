"""Close approaches in an overloaded team: its start, and a stalled agent process.

Usage: .venv/bin/python scripts/overloaded_start.py [--scenario scenarios/circle-400.toml]
       [--seeds 0,1,2,3] [--duration 12] [--gaps 0.45,1.15] [--pace 0.125]
       [--cmd-timeout 1.0] [--stall 6,2.5] [--no-settle] [--hold-after 0.3]
       [--json out.json]

Runs the scenario in the deterministic in-process network simulation
(covswarm.deploy.netsim: the agents' own brains, robot models, no Zenoh) as an overloaded
live run behaves (docs/scaling.md, "the overloaded start"): each brain steps after a gap
drawn in ``--gaps`` s rather than every 0.1 s, S runs at ``--pace`` of its speed as the
coordinator slows it, robots stop ``--cmd-timeout`` s after a command (the brains know it,
as ``covswarm run`` tells them) and the mission starts when the coordinator would start
it. ``--stall START,LENGTH``: the brains of the first half of the ids (one of two agent
processes, as ``covswarm run`` packs them) take no turn for LENGTH s from START s of the
simulated clock. ``--hold-after S``: a brain whose next turn comes later than S s (or than
the hold its command was computed for) after its last stops its robot then, as a packed
process does (``covswarm agent`` at 10 Hz: 0.3 s); without it each robot drives its
command until the next or its timeout.

Prints a Markdown table, a row per seed: the closest pair of robot centres from the start
on, the pairs that came within a body diameter, and e_a's mean over the first 5 s of the
mission, over all of it, and at its end; ``--json`` writes them with the team's counters
of the rules that keep robots apart (COUNTERS). About a minute of CPU per seed at 400
robots, three at 1000.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from covswarm.agent.brain import AgentConfig
from covswarm.deploy.netsim import NetsimResult, Stall, run_netsim
from covswarm.mission.physical import proximity
from covswarm.mission.scenario_files import load_scenario

FIRST_SECONDS = 5.0  # s of mission time over which the start's e_a is averaged
COUNTERS = (
    "arc_turned",
    "obstacles_kept",
    "speed_limited",
    "beacon_doubted",
    "safety_relaxed",
    "overrun_gained",
    "slid",
)


def summary(result: NetsimResult, diameter: float) -> dict[str, float]:
    closest, _, episodes = proximity(result.t, result.trajectories, diameter)
    pairs = len({episode.pair for episode in episodes})
    first = result.error[result.t <= FIRST_SECONDS]
    row = {
        "closest_m": closest,
        "pairs_within_diameter": pairs,
        "e_a_first_s_m": float(first.mean()),
        "e_a_mean_m": float(result.error.mean()),
        "e_a_end_m": float(result.error[-1]),
        "started_s": result.started,
    }
    for name in COUNTERS:
        row[name] = int(sum(stats.get(name, 0) for stats in result.stats.values()))
    return row


@click.command()
@click.option("--scenario", "scenario_path", default="scenarios/circle-400.toml", show_default=True)
@click.option("--seeds", default="0,1,2,3", show_default=True)
@click.option("--duration", type=click.FloatRange(1.0), default=12.0, show_default=True)
@click.option("--gaps", default="0.45,1.15", show_default=True, help="s between a brain's turns.")
@click.option("--pace", type=click.FloatRange(0.0, 1.0, min_open=True), default=0.125)
@click.option("--cmd-timeout", type=click.FloatRange(0.1), default=1.0, show_default=True)
@click.option("--stall", default=None, help="START,LENGTH s: half the brains take no turn.")
@click.option(
    "--settle/--no-settle", default=True, show_default=True,
    help="Start when the coordinator would (no: 2 s after launch, its rule before 30 Nov).",
)  # fmt: skip
@click.option(
    "--hold-after", type=click.FloatRange(0.0, min_open=True), default=None,
    help="s: a late brain stops its robot then, as a packed process does (default: never).",
)  # fmt: skip
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None)
def main(
    scenario_path: str,
    seeds: str,
    duration: float,
    gaps: str,
    pace: float,
    cmd_timeout: float,
    stall: str | None,
    settle: bool,
    hold_after: float | None,
    json_path: str | None,
) -> None:
    scenario = load_scenario(scenario_path)
    n = scenario.agents
    lo, hi = (float(g) for g in gaps.split(","))
    stalled = None
    if stall is not None:
        start, length = (float(v) for v in stall.split(","))
        stalled = Stall(range(n // 2), start, length)
    config = AgentConfig(cmd_timeout=cmd_timeout)
    diameter = config.robot.body_diameter
    print(
        f"{scenario.name}, {n} robots, {duration:g} s, brains every {lo:g}-{hi:g} s, S at "
        f"{pace:g} of its speed, robots stop {cmd_timeout:g} s after a command"
        + (f", ids below {n // 2} stalled {stall} s" if stall else "")
        + ("" if settle else ", started 2 s after launch")
        + ("" if hold_after is None else f", a late brain's robot stopped after {hold_after:g} s")
    )
    print("| seed | closest, m | pairs within a diameter | e_a first 5 s / mean / end, m |")
    print("|---|---|---|---|")
    rows = []
    for seed in (int(s) for s in seeds.split(",")):
        result = run_netsim(
            scenario, seed=seed, duration=duration, config=config, cmd_timeout=cmd_timeout,
            pace=pace, turn_gaps=(lo, hi), stall=stalled, settle=settle, hold_after=hold_after,
        )  # fmt: skip
        row = {"seed": seed, **summary(result, diameter)}
        rows.append(row)
        print(
            f"| {seed} | {row['closest_m']:.3f} | {row['pairs_within_diameter']} | "
            f"{row['e_a_first_s_m']:.3f} / {row['e_a_mean_m']:.3f} / {row['e_a_end_m']:.3f} |",
            flush=True,
        )
    if json_path is not None:
        Path(json_path).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
