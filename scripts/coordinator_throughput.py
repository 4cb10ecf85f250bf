"""Does the coordinator keep up with a big team's poses? Sans-IO, in real time.

Usage: .venv/bin/python scripts/coordinator_throughput.py [--agents 1000] [--seconds 8]
       [--offload/--inline] [--no-record] [--state-rate HZ]

A CoordinatorCore of ``--agents`` robots on scenarios/circle-1000.toml, its mission
running, is handed every robot's encoded Pose at 20 Hz (the robots' pose rate: 20 000
poses per second for 1000) and ticked at its broadcast rate (20 Hz) on the wall clock, with
the recorder writing run.mcap and trajectories.csv to a temporary folder, as
``covswarm coordinator`` does (no Zenoh: the link's own cost per sample is not in it).
``--state-rate``: every agent's AgentState too, at that rate (Hz; 0: none), shaped as an
agent sends it (STATE_NEIGHBORS neighbours, as many relayed, its stats once a second). The
e_a sample and the recorded cells tessellate on a worker thread (``--offload``, what
coordinator.main does) or within the tick (``--inline``, the core's default).

Prints one JSON document: the main thread's CPU per second of mission (taking in the poses;
ticking), the wall time of a tick (p50, p99, max; how many outlast a broadcast period, which
delays the Domain), the e_a samples and the recorder's counts (poses thinned, skipped ticks).
"""

from __future__ import annotations

import json
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click
import numpy as np

from covswarm.coordinator.config import CoordinatorConfig
from covswarm.coordinator.core import WAITING, CoordinatorCore, CoordinatorSettings, run_inline
from covswarm.coordinator.outputs import open_recorder
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol import AgentState, Pose, agent_state_key, alive_key, pose_key

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "circle-1000.toml"
SWARM = "throughput"
RATE = 20.0  # Hz: the robots' poses and the coordinator's broadcasts
STATE_NEIGHBORS = 6  # Voronoi neighbours (and relayed positions) of an AgentState
STATS = 30  # entries of an AgentState's stats (an agent sends ~30, agent.brain.stats)


def agent_state(i: int, agents: int, x: float, y: float, stamp: float, k: int, stats: bool):
    """Agent i's AgentState at (x, y) as an agent builds one: the STATE_NEIGHBORS around it
    (mod the team, each named back), their positions relayed, and with ``stats`` (k: its
    steps so far) its stats."""
    half = STATE_NEIGHBORS // 2
    neighbors = sorted({(i + j) % agents for j in range(-half, half + 1)} - {i})
    relay = [(j, x + 0.1 * n, y - 0.1 * n, 0.01, -0.02) for n, j in enumerate(neighbors)]
    table = {"mission_steps": k, "rate_hz": 10.0, "step_us_p50": 850.5}
    table.update({f"counter_{n}": float(n) for n in range(STATS - len(table))})
    return AgentState(
        id=i, x=x, y=y, stamp=stamp, neighbors=tuple(neighbors), stats=table if stats else None,
        vx=0.01, vy=-0.02, relay=tuple(relay),
    ).encode()  # fmt: skip


@click.command()
@click.option("--agents", type=click.IntRange(1), default=1000, show_default=True)
@click.option("--seconds", type=click.FloatRange(1.0), default=8.0, show_default=True)
@click.option("--offload/--inline", default=True, show_default=True)
@click.option("--record/--no-record", default=True, show_default=True)
@click.option(
    "--state-rate", type=click.FloatRange(0.0, RATE), default=0.0, show_default=True,
    help="Hz of every agent's AgentStates (0: poses only).",
)  # fmt: skip
def main(agents: int, seconds: float, offload: bool, record: bool, state_rate: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="coordinator-throughput-"))
    config = CoordinatorConfig(
        swarm=SWARM, out=out, scenario=str(SCENARIO), agents=agents, duration=seconds + 5.0,
        record=record,
    )  # fmt: skip
    settings = CoordinatorSettings.from_config(config, load_scenario(config.scenario))
    recorder = open_recorder(config, settings)
    with ThreadPoolExecutor(max_workers=1) as pool:
        core = CoordinatorCore(
            settings, recorder=recorder, offload=pool.submit if offload else run_inline
        )
        wall0 = time.time()
        for i in range(agents):
            for role in ("robot", "agent"):
                core.on_liveliness(alive_key(SWARM, role, i), True, 0.0, wall0)
        now = 0.0
        while core.phase.state == WAITING:
            core.tick(now, wall0 + now)
            now += 1.0 / RATE
        # The robots' side, encoded beforehand: a team spread over S, each robot on a small
        # circle, poses stamped 20 ms before the tick that takes them in.
        start = settings.scenario.initial_positions(agents, 0)
        keys = [pose_key(SWARM, i) for i in range(agents)]
        ticks = round(seconds * RATE)
        payloads, states = [], []
        # Tick k carries the states of the agents whose state period ends in it, spread
        # over the agents (each its own phase); stats in one state a second of each.
        phases = np.arange(agents) / agents
        for k in range(ticks):
            t = now + k / RATE
            angle = 0.5 * t + np.arange(agents)
            xy = start + 0.05 * np.column_stack([np.cos(angle), np.sin(angle)])
            stamp = wall0 + t - 0.02
            payloads.append([
                Pose(id=i, x=float(x), y=float(y), theta=0.0, stamp=stamp, seq=k).encode()
                for i, (x, y) in enumerate(xy)
            ])  # fmt: skip
            due = np.floor((k + 1) / RATE * state_rate + phases) - np.floor(
                k / RATE * state_rate + phases
            )
            with_stats = np.floor((k + 1) / RATE + phases) - np.floor(k / RATE + phases)
            states.append([
                (agent_state_key(SWARM, i),
                 agent_state(i, agents, float(xy[i, 0]), float(xy[i, 1]), stamp, k,
                             bool(with_stats[i])))
                for i in np.flatnonzero(due).tolist()
            ])  # fmt: skip
        taking = taking_states = ticking = 0.0
        walls = []
        began = time.monotonic()
        for k in range(ticks):
            time.sleep(max(0.0, began + k / RATE - time.monotonic()))
            t = now + k / RATE
            w0, c0 = time.monotonic(), time.thread_time()
            core.on_poses(list(zip(keys, payloads[k], strict=True)))  # the link's batch
            c1 = time.thread_time()
            for key, payload in states[k]:
                core.on_agent_state(key, payload)
            c2 = time.thread_time()
            core.tick(t, wall0 + t)
            ticking += time.thread_time() - c2
            taking += c1 - c0
            taking_states += c2 - c1
            walls.append(time.monotonic() - w0)
        if recorder is not None:
            recorder.close()
    walls_ms = 1e3 * np.array(walls)
    print(json.dumps({
        "agents": agents, "poses_per_s": agents * RATE, "offload": offload, "record": record,
        "seconds": seconds,
        "states_per_s": sum(map(len, states)) / seconds,
        "cpu_share_taking_poses": taking / seconds,
        "cpu_share_taking_states": taking_states / seconds, "cpu_share_ticks": ticking / seconds,
        "cpu_share_total": (taking + taking_states + ticking) / seconds,
        "tick_wall_ms": {"p50": float(np.median(walls_ms)),
                         "p99": float(np.percentile(walls_ms, 99)), "max": float(walls_ms.max())},
        "ticks_over_a_period": int(np.sum(walls_ms > 1e3 / RATE)), "ticks": ticks,
        "e_a_samples": len(core.observed.record.t), "recording": core.recording,
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
