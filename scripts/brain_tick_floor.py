"""What a brain-tick cannot go below while each brain keeps its own tables: the messages.

Usage: .venv/bin/python scripts/brain_tick_floor.py [--brains 500] [--ticks 100]

Runs one pack of ``--brains`` brains over the team of ``covswarm bench --brain-tick`` (0.2 m
apart, 10 Hz, deploy.bench) and prints, in microseconds of CPU:

1. **Messages.** What decoding and encoding cost per message, timed over one tick's real
   payloads (the AgentStates and commands the pack's brains put, the poses the bench's
   robots put): msgpack alone, then the whole decode of covswarm.agent.decoding (checks
   and the StateFacts every receiver takes), each payload once per pass (its cache cold,
   as in a pack: each payload is decoded once for the process), and encode.
   Every brain publishes a state and a command and takes its own pose each period, so
   their sum is a floor of a brain-tick in any design that keeps today's wire format.
2. **Zenoh.** CPU per put of a 320-byte payload through 500 declared publishers of one
   client session, to a second client's 500 ring subscribers, over a router in this
   process (so the figure includes the router's work), and per sample taken off the rings
   (try_recv, key, bytes): loopback only, scouting off.
3. **Python's calls.** The function calls (built-ins included) a brain-tick makes, by
   cProfile over ten periods of the pack.
4. **The math by batch size.** One tick's views and safety filters of the pack (as its
   chunks handed them to covswarm.tvd.control.local_steps and agent.brain.filter_all),
   stepped again in batches of 32 (the pack's CHUNK) to all of them at once: CPU per brain.
5. **The tables' size.** Two packs stepped in turn (interleaved: this VM's speed drifts)
   whose brains differ only in the beacon timeout (25 s, the default, and 3 s), which
   sets how many beacon-only robots each brain keeps as candidates: CPU per brain-tick
   and the mean number of candidates of each.

docs/scaling.md quotes it.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import json
import math
import os
import pstats
import statistics
import time
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np

from covswarm import protocol
from covswarm.agent import pack as pack_module
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.agent.decoding import MessageDecoder, _received
from covswarm.agent.pack import LocalBus, Pack, collect_less
from covswarm.deploy import bench
from covswarm.deploy.router import free_port

PERIOD = 0.1  # s, the bench's 10 Hz
PASSES = 5  # passes over a tick's payloads per timing


def make_pack(brains: int, config: AgentConfig) -> tuple[LocalBus, Pack]:
    bus = LocalBus()
    decoder = MessageDecoder()
    return bus, Pack(bus, "bench", [AgentBrain(i, config, decoder) for i in range(brains)])


def tick(bus: LocalBus, pack: Pack, layout: bench.Layout, k: int) -> float:
    """Period ``k`` of ``pack``: the bench's poses and domain put, then the pack's tick;
    its CPU s."""
    t = k * PERIOD
    bench.publish_period(bus, "bench", layout, k, PERIOD, 1)
    started = time.process_time()
    pack.tick(lambda: t, lambda: bench.BRAIN_TICK_WALL + t, math.inf)
    return time.process_time() - started


def per_item(items: list[Any], work: Callable[[Any], Any]) -> float:
    """us of CPU per item of ``work`` over ``items``, PASSES passes, the best pass."""
    best = math.inf
    for _ in range(PASSES):
        started = time.process_time()
        for item in items:
            work(item)
        best = min(best, time.process_time() - started)
    return best / len(items) * 1e6


def messages(brains: int, layout: bench.Layout) -> dict[str, float]:
    bus, pack = make_pack(brains, AgentConfig())
    for k in range(bench.BRAIN_TICK_WARM):
        tick(bus, pack, layout, k)
    # A second more, the pack's puts kept: its states (a tenth with stats, sent once a
    # second) and commands.
    sent = []
    for k in range(bench.BRAIN_TICK_WARM, bench.BRAIN_TICK_WARM + round(1.0 / PERIOD)):
        tick(bus, pack, layout, k)  # publish_period clears what the last tick sent
        sent += bus.sent
    t = (bench.BRAIN_TICK_WARM + round(1.0 / PERIOD)) * PERIOD
    states = [p for key, p in sent if key.endswith("/state")]
    commands = [p for key, p in sent if key.endswith("/cmd")]
    poses = [
        protocol.Pose(id=i, x=x, y=y, theta=0.0, stamp=bench.BRAIN_TICK_WALL + t, seq=1).encode()
        for i, (x, y) in enumerate(layout.positions.tolist())
    ]
    decoded_states = [protocol.AgentState.decode(p) for p in states]
    decoded_commands = [protocol.WheelCommand.decode(p) for p in commands]
    return {
        "AgentState bytes (mean)": statistics.mean(map(len, states)),
        "AgentStates with stats (%)": 100.0
        * sum(m.stats is not None for m in decoded_states)
        / len(states),
        "AgentState: msgpack unpack": per_item(states, msgpack.unpackb),
        "AgentState: decode (checks, StateFacts)": per_item(
            states, lambda p: _received("state", p)
        ),
        "AgentState: encode": per_item(decoded_states, lambda m: m.encode()),
        "Pose: decode": per_item(poses, lambda p: _received("pose", p)),
        "WheelCommand: encode": per_item(decoded_commands, lambda m: m.encode()),
    }


def calls_per_brain_tick(brains: int, layout: bench.Layout) -> float:
    bus, pack = make_pack(brains, AgentConfig())
    for k in range(bench.BRAIN_TICK_WARM):
        tick(bus, pack, layout, k)
    profile = cProfile.Profile()
    periods = 10
    profile.enable()
    for k in range(bench.BRAIN_TICK_WARM, bench.BRAIN_TICK_WARM + periods):
        tick(bus, pack, layout, k)
    profile.disable()
    return pstats.Stats(profile).total_calls / (periods * brains)


@contextlib.contextmanager
def batches_kept(kept: dict[str, list]) -> Any:
    """Within: the pack's batched local steps and filters record their inputs in ``kept``
    ("steps": (views, arguments) per batch; "filters": filterings per batch)."""
    steps, filters = pack_module.local_steps, pack_module.filter_all

    def keep_steps(views: Any, *arguments: Any) -> Any:
        kept["steps"].append((list(views), arguments))
        return steps(views, *arguments)

    def keep_filters(filterings: Any) -> Any:
        kept["filters"].append(list(filterings))
        return filters(filterings)

    pack_module.local_steps, pack_module.filter_all = keep_steps, keep_filters
    try:
        yield
    finally:
        pack_module.local_steps, pack_module.filter_all = steps, filters


def one_ticks_batches(brains: int, layout: bench.Layout) -> dict[str, list]:
    """The batched local steps' and filters' inputs (batches_kept) of the period after the
    bench's warm-up, in a pack of ``brains`` brains over ``layout``."""
    bus, pack = make_pack(brains, AgentConfig())
    for k in range(bench.BRAIN_TICK_WARM):
        tick(bus, pack, layout, k)
    kept: dict[str, list] = {"steps": [], "filters": []}
    with batches_kept(kept):
        tick(bus, pack, layout, bench.BRAIN_TICK_WARM)
    return kept


def math_by_batch(
    brains: int, layout: bench.Layout, sizes: tuple[int, ...]
) -> dict[int, tuple[float, float]]:
    """Batch size -> (local steps, safety filter) us of CPU per brain over one tick's inputs."""
    kept = one_ticks_batches(brains, layout)
    views = [view for batch, _ in kept["steps"] for view in batch]
    arguments = kept["steps"][0][1]
    filterings = [one for batch in kept["filters"] for one in batch]
    out = {}
    for size in sizes:
        batches = range(0, len(views), size)
        steps = per_item(
            [views[s : s + size] for s in batches],
            lambda batch: pack_module.local_steps(batch, *arguments),
        )
        filters = per_item(
            [filterings[s : s + size] for s in range(0, len(filterings), size)],
            pack_module.filter_all,
        )
        out[size] = (steps * len(batches) / len(views), filters * len(batches) / len(views))
    return out


def zenoh_costs(publishers: int = 500, rounds: int = 20) -> dict[str, float]:
    import zenoh

    def config(mode: str, key: str, endpoint: str) -> zenoh.Config:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5(key, json.dumps([endpoint]))
        return conf

    endpoint = f"tcp/127.0.0.1:{free_port('127.0.0.1')}"
    payload = bytes(320)
    put_us, recv_us = [], []
    with (
        zenoh.open(config("router", "listen/endpoints", endpoint)),
        zenoh.open(config("client", "connect/endpoints", endpoint)) as listener,
        zenoh.open(config("client", "connect/endpoints", endpoint)) as talker,
    ):
        rings = [
            listener.declare_subscriber(f"floor/{i}/state", zenoh.handlers.RingChannel(4))
            for i in range(publishers)
        ]
        time.sleep(1.0)  # the subscriptions reach the router
        puts = [
            talker.declare_publisher(
                f"floor/{i}/state", congestion_control=zenoh.CongestionControl.DROP
            ).put
            for i in range(publishers)
        ]
        time.sleep(0.5)
        for _ in range(3):
            started = time.process_time()
            for _ in range(rounds):
                for put in puts:
                    put(payload)
            put_us.append((time.process_time() - started) / (rounds * publishers) * 1e6)
            time.sleep(0.3)  # delivered
            started, taken = time.process_time(), 0
            for ring in rings:
                while (sample := ring.try_recv()) is not None:
                    str(sample.key_expr)
                    sample.payload.to_bytes()
                    taken += 1
            recv_us.append((time.process_time() - started) / max(taken, 1) * 1e6)
    return {
        "Zenoh put (whole process, router included)": statistics.median(put_us),
        "Zenoh sample taken (try_recv, key, bytes)": statistics.median(recv_us),
    }


def table_size(brains: int, layout: bench.Layout, ticks: int) -> dict[str, tuple[float, float]]:
    packs = {
        "beacon timeout 25 s": make_pack(brains, AgentConfig()),
        "beacon timeout 3 s": make_pack(brains, AgentConfig(beacon_timeout=3.0)),
    }
    spent = dict.fromkeys(packs, 0.0)
    first = ticks // 2
    for k in range(ticks):
        for name, (bus, pack) in packs.items():
            cpu = tick(bus, pack, layout, k)
            if k >= first:
                spent[name] += cpu
    out = {}
    for name, (_, pack) in packs.items():
        candidates = np.mean([len(b.neighborhood.reckoned) for b in pack.brains.values()])
        out[name] = (spent[name] / ((ticks - first) * brains) * 1e6, float(candidates))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--brains", type=int, default=500)
    parser.add_argument("--ticks", type=int, default=100)
    args = parser.parse_args()
    collect_less()
    layout = bench.make_layout(args.brains, "cvt", 0, spacing=bench.BRAIN_TICK_SPACING)
    print(f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load {os.getloadavg()[0]:.2f}")
    print("\n| message work | us of CPU |\n|---|---|")
    for name, value in messages(args.brains, layout).items():
        print(f"| {name} | {value:.1f} |")
    print("\n| Zenoh, loopback | us of CPU |\n|---|---|")
    for name, value in zenoh_costs().items():
        print(f"| {name} | {value:.1f} |")
    calls = calls_per_brain_tick(args.brains, layout)
    print(f"\nPython function calls per brain-tick (cProfile, built-ins included): {calls:.0f}")
    print("\n| brains per batch | local steps, us a brain | safety filter, us a brain |")
    print("|---|---|---|")
    sizes = (pack_module.CHUNK, 64, 128, args.brains)
    for size, (steps, filters) in math_by_batch(args.brains, layout, sizes).items():
        print(f"| {size} | {steps:.0f} | {filters:.0f} |")
    print(f"\n| {args.brains} brains, interleaved | CPU per brain-tick, us | candidates |")
    print("|---|---|---|")
    for name, (cpu, candidates) in table_size(args.brains, layout, args.ticks).items():
        print(f"| {name} | {cpu:.0f} | {candidates:.0f} |")


if __name__ == "__main__":
    main()
