"""``covswarm bench``: is one robot's work really independent of the team size?

The paper's Section 5 claims each robot's control step is O(1) on average because it needs
only its two-hop neighbourhood. This benchmark measures it in this implementation:

1. per-agent compute vs N: every robot's complete ``covswarm.tvd.control.local_step`` (building
   its local partial Voronoi diagram included) from exactly its two-hop neighbourhood, on
   random and near-CVT layouts, several seeds; uniform, and with a moving Gaussian density
   (``bench_density``) timed interleaved with the uniform step on the same view;
2. the centralised baseline: full-team ``tvd_c`` and ``tvd_d1`` per step vs N;
3. the neighbour-count histogram vs N (the paper's Table 1 at N = 100);
4. with ``--live``: real distributed runs (``covswarm run`` over Zenoh, LIVE_PER_PROCESS
   brains per agent process and robots per robot process by default) for N in LIVE_SIZES,
   reporting what the agents measure on the wire (compute per step, messages received,
   pose-to-command latency, control rate held, missed deadlines) and the memory per
   process (rows with layout "live", which record the launch settings).

The domain is a square whose side grows as sqrt(N) (constant density), so N changes and the
local geometry does not. Timings are wall-clock on this machine, reported, never asserted.

Pose-to-command latency is measured by each agent: its robot's pose stamp to the stamp of
the command computed from it (network delivery, waiting for the next control tick, and the
step itself; one clock, since the live runs are on one machine).
"""

from __future__ import annotations

import csv
import gc
import json
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np

from covswarm.runtime.options import (
    MAX_RATE,
    SIZES,
    count_option,
    float_option,
    given_options,
    out_option,
    refuse_unused,
)
from covswarm.tvd.control import local_step, tvd_c, tvd_d1, tvd_da
from covswarm.tvd.coverage import mass_centroid, neighbors
from covswarm.tvd.density import Density

FULL_SIZES = (10, 30, 100, 300, 1000, 3000)
QUICK_SIZES = (10, 30, 100, 300)
SPACING = 0.5  # metres between robots on average: side = SPACING * sqrt(N)
LIVE_SIZES = (10, 25, 50, 100)
LIVE_RATE = 10.0  # Hz asked of every agent in the live runs
# Hz: the robots' poses and the coordinator's domains (`covswarm robot --pose-rate`,
# `covswarm coordinator --rate`: their defaults)
LIVE_SEND_RATE = 20.0
# Brains (robots) per agent (robot) process in the live runs: on a 2-core machine the
# per-process cost (interpreter, imports, a Zenoh session and its threads, one more
# client for the router to serve) is what a team of 100 cannot afford 100 times
# (docs/scaling.md); a team smaller than this runs in one agent and one robot process.
LIVE_PER_PROCESS = 20


@dataclass(frozen=True)
class Layout:
    """A team layout to time: positions (n, 2) in a square of side ``side``."""

    kind: str
    seed: int
    positions: np.ndarray
    polygon: np.ndarray
    spacing: float = SPACING  # m between robots on average


def square(side: float) -> np.ndarray:
    """Counter-clockwise square [0, side]^2: (4, 2)."""
    return np.array([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]])


def make_layout(
    n: int, kind: str, seed: int, lloyd_iterations: int = 40, spacing: float = SPACING
) -> Layout:
    """Random uniform positions, or near-CVT ones after Lloyd iterations (p <- c(p)), in a
    square of side ``spacing`` (m) x sqrt(n)."""
    side = spacing * np.sqrt(n)
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0.0, side, size=(n, 2))
    polygon = square(side)
    if kind == "cvt":
        for _ in range(lloyd_iterations):
            positions = mass_centroid(positions, polygon)[1]
    return Layout(kind, seed, positions, polygon, spacing)


def bench_density(side: float) -> Density:
    """A bump of standard deviation ~side / 4 on the centre of [0, side]^2, drifting and
    growing, as in a real mission (docs/density-peer.md times the peer's narrower bumps)."""
    spread = (side / 4.0) ** 2
    return Density(
        floor=1.0,
        means=[[0.5 * side, 0.5 * side]],
        covariances=[[[spread, 0.3 * spread], [0.3 * spread, 0.6 * spread]]],
        weights=[4.0],
        mean_rates=[[0.05, 0.02]],
        covariance_rates=[[[0.01, 0.0], [0.0, 0.01]]],
        weight_rates=[0.1],
    )


def two_hop(adjacency: list[set[int]], me: int) -> set[int]:
    """Robot ``me``, its neighbours and their neighbours."""
    known = {me} | adjacency[me]
    for j in adjacency[me]:
        known |= adjacency[j]
    return known


def sampled_robots(layout: Layout, sample: int | None) -> tuple[list[set[int]], np.ndarray]:
    """The layout's Voronoi adjacency, and the robots timed: ``sample`` of them drawn with the
    layout's seed, or all where ``sample`` is None or not below N."""
    adjacency = neighbors(layout.positions, layout.polygon)
    n = len(layout.positions)
    if sample is not None and sample < n:
        return adjacency, np.random.default_rng(layout.seed).choice(n, size=sample, replace=False)
    return adjacency, np.arange(n)


def translating(layout: Layout) -> np.ndarray:
    """Vertex velocities (m/s, shape (V, 2)) of the layout's polygon translating at (0.05, 0.02)."""
    return np.tile([0.05, 0.02], (len(layout.polygon), 1))


def time_local_steps(
    layout: Layout, sample: int | None, kappa: float = 1.0, density: Density | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Microseconds of each sampled robot's local step, and its two-hop neighbourhood size."""
    adjacency, robots = sampled_robots(layout, sample)
    velocity = translating(layout)
    times, sizes = [], []
    for me in robots:
        known = two_hop(adjacency, int(me))
        view = {j: layout.positions[j] for j in known}
        # Warm, as in a running agent: the first call of a process pays for lazy imports
        # and numpy's first-use caches, which would otherwise land on the smallest N.
        local_step(int(me), view, layout.polygon, velocity, kappa, density=density)
        start = time.perf_counter()
        local_step(int(me), view, layout.polygon, velocity, kappa, density=density)
        times.append((time.perf_counter() - start) * 1e6)
        sizes.append(len(known))
    return np.array(times), np.array(sizes)


def time_da_vs_d1(layout: Layout, sample: int | None, kappa: float = 1.0) -> dict[str, float]:
    """One robot's TVD-DA step beside its TVD-D1 step (docs/tracking.md), interleaved.

    For each sampled robot, both laws on the same two-hop view, alternately, so that the
    machine's drift lands on both. The domain translates, rotates and scales (so the affine
    field is not trivial). Returns the p50 microseconds of the TVD-DA step and the median of
    the per-robot ratio TVD-DA / TVD-D1.
    """
    adjacency, robots = sampled_robots(layout, sample)
    centre = layout.polygon.mean(axis=0)
    turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    velocity = [0.05, 0.02] + 0.01 * (layout.polygon - centre) @ (np.eye(2) + turn).T
    da, ratios = [], []
    for me in robots:
        view = {j: layout.positions[j] for j in two_hop(adjacency, int(me))}
        spent = {}
        for law in ("d1", "da", "d1", "da"):  # the first of each warms
            start = time.perf_counter()
            local_step(int(me), view, layout.polygon, velocity, kappa, law=law)
            spent[law] = (time.perf_counter() - start) * 1e6
        da.append(spent["da"])
        ratios.append(spent["da"] / spent["d1"])
    return {
        "local_step_da_p50_us": float(np.percentile(da, 50)),
        "da_over_d1": float(np.median(ratios)),
    }


def time_density_vs_uniform(
    layout: Layout, sample: int | None, density: Density, kappa: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Microseconds of each sampled robot's local step with ``density`` and, interleaved on
    the same two-hop view, without (uniform), so that the machine's drift lands on both:
    (density times, uniform times)."""
    adjacency, robots = sampled_robots(layout, sample)
    velocity = translating(layout)
    spent: dict[str, list[float]] = {"density": [], "uniform": []}
    for me in robots:
        view = {j: layout.positions[j] for j in two_hop(adjacency, int(me))}
        for name in ("uniform", "density", "uniform", "density"):  # the first of each warms
            # A fresh snapshot per step, as an agent makes one per tick: a snapshot keeps the
            # integrals of its last cells, which a step with the same view would reuse.
            phi = density.at(density.time) if name == "density" else None
            start = time.perf_counter()
            local_step(int(me), view, layout.polygon, velocity, kappa, density=phi)
            spent[name].append((time.perf_counter() - start) * 1e6)
    return np.array(spent["density"][1::2]), np.array(spent["uniform"][1::2])


def time_centralized(layout: Layout, repeats: int, kappa: float = 1.0) -> dict[str, float]:
    """Median milliseconds of one full-team step of each law."""
    velocity = translating(layout)
    result = {}
    for name, law in (("tvd_c", tvd_c), ("tvd_d1", tvd_d1), ("tvd_da", tvd_da)):
        samples = []
        for _ in range(repeats):
            start = time.perf_counter()
            law(layout.positions, layout.polygon, velocity, kappa)
            samples.append((time.perf_counter() - start) * 1e3)
        result[f"{name}_ms"] = float(np.median(samples))
    return result


def bench_world(layout: Layout, obstacles: int) -> Any:
    """The layout's square as the workspace with ``obstacles`` boxes of 0.2 m x 0.2 m at
    random (seeded by the layout): a covswarm.world.model.World."""
    from covswarm.world.model import World

    side = float(layout.polygon[:, 0].max())
    rng = np.random.default_rng([layout.seed, obstacles])
    corners = rng.uniform(0.0, side - 0.2, size=(obstacles, 2))
    boxes = [[x, x + 0.2, y, y + 0.2] for x, y in corners]
    return World.from_boxes_and_polygons((0.0, side, 0.0, side), boxes)


def time_safety_filter(
    layout: Layout, sample: int | None, kappa: float = 1.0, obstacles: int = 0
) -> dict:
    """The barrier-certificate filter (covswarm.tvd.safety) against the local step it follows.

    For each sampled robot, interleaved: its local step, then the filter of that step's
    velocity against its two-hop neighbours (what an agent does every tick). Returns p50 and
    p99 microseconds of the filter and the median of the per-robot ratio filter / step.

    With ``obstacles`` > 0 (bench_world), the filter is also timed as an agent that knows
    the world runs it: the obstacles whose bounding box is within SAFETY_RADIUS (the filter
    keeps those within it) and the workspace walls as rows (covswarm.agent.brain._safe),
    interleaved with the robots-only filter;
    adds its p50 and p99, the median per-robot added time, and the mean obstacles nearby.
    """
    from covswarm.agent.brain import SAFETY_RADIUS, WALL_GAMMA_FRACTION
    from covswarm.tvd.drive import KHEPERA_IV
    from covswarm.tvd.safety import DEFAULT_GAMMA, safe_velocity, wall_distance

    adjacency, robots = sampled_robots(layout, sample)
    velocity = translating(layout)
    # Robots 0.5 m apart on average: a safe distance of 0.3 m makes some rows active.
    safe = 0.6 * SPACING
    world = bench_world(layout, obstacles) if obstacles > 0 else None
    filters, ratios, walled, added, nearby = [], [], [], [], []
    for me in robots:
        known = two_hop(adjacency, int(me)) - {int(me)}
        view = {j: layout.positions[j] for j in known | {int(me)}}
        others = layout.positions[sorted(known)]
        local_step(int(me), view, layout.polygon, velocity, kappa)  # warm
        start = time.perf_counter()
        step = local_step(int(me), view, layout.polygon, velocity, kappa)
        step_us = (time.perf_counter() - start) * 1e6
        start = time.perf_counter()
        safe_velocity(layout.positions[me], step.velocity, others, safe)
        filter_us = (time.perf_counter() - start) * 1e6
        filters.append(filter_us)
        ratios.append(filter_us / step_us)
        if world is None:
            continue
        p = layout.positions[me]
        start = time.perf_counter()
        x, y = float(p[0]), float(p[1])
        near = [world.obstacles[j].vertices for j in world.candidates((x, x, y, y), SAFETY_RADIUS)]
        safe_velocity(
            p,
            step.velocity,
            others,
            safe,
            obstacles=near,
            workspace=world.workspace,
            obstacle_distance=wall_distance(KHEPERA_IV.body_diameter),
            reach=SAFETY_RADIUS,
            obstacle_gamma=WALL_GAMMA_FRACTION * DEFAULT_GAMMA,
        )
        walled.append((time.perf_counter() - start) * 1e6)
        added.append(walled[-1] - filter_us)
        nearby.append(len(world.nearby(p, SAFETY_RADIUS)))  # untimed: within reach
    result = {
        "safety_filter_p50_us": float(np.percentile(filters, 50)),
        "safety_filter_p99_us": float(np.percentile(filters, 99)),
        "safety_over_step": float(np.median(ratios)),
    }
    if world is not None:
        result |= {
            "safety_walls_p50_us": float(np.percentile(walled, 50)),
            "safety_walls_p99_us": float(np.percentile(walled, 99)),
            "walls_added_p50_us": float(np.median(added)),
            "obstacles_nearby_mean": float(np.mean(nearby)),
        }
    return result


def run_bench(
    sizes: tuple[int, ...],
    seeds: int,
    sample: int | None,
    repeats: int,
    progress=None,
    obstacles: int = 0,
) -> list[dict]:
    """One row per (N, layout kind): per-agent and centralised figures pooled over seeds
    (``obstacles``: see time_safety_filter)."""
    rows = []
    for n in sizes:
        for kind in ("random", "cvt"):
            times, hood, histogram, central, weighted = [], [], Counter(), [], []
            safety: list[dict] = []
            laws: list[dict] = []
            for seed in range(seeds):
                layout = make_layout(n, kind, seed)
                t, s = time_local_steps(layout, sample)
                times.append(t)
                hood.append(s)
                side = float(layout.polygon[:, 0].max())
                weighted.append(time_density_vs_uniform(layout, sample, bench_density(side)))
                histogram.update(len(a) for a in neighbors(layout.positions, layout.polygon))
                central.append(time_centralized(layout, repeats))
                safety.append(time_safety_filter(layout, sample, obstacles=obstacles))
                laws.append(time_da_vs_d1(layout, sample))
                if progress is not None:
                    progress(n, kind, seed)
            t = np.concatenate(times)
            with_phi = np.concatenate([pair[0] for pair in weighted])
            without_phi = np.concatenate([pair[1] for pair in weighted])
            rows.append(
                {
                    "agents": n,
                    "layout": kind,
                    "seeds": seeds,
                    "steps_timed": int(t.size),
                    "local_step_p50_us": float(np.percentile(t, 50)),
                    "local_step_p99_us": float(np.percentile(t, 99)),
                    "local_step_mean_us": float(np.mean(t)),
                    "local_step_density_p50_us": float(np.percentile(with_phi, 50)),
                    "density_over_uniform": float(
                        np.percentile(with_phi, 50) / np.percentile(without_phi, 50)
                    ),
                    "two_hop_mean": float(np.mean(np.concatenate(hood))),
                    "tvd_c_ms": float(np.median([c["tvd_c_ms"] for c in central])),
                    "tvd_d1_ms": float(np.median([c["tvd_d1_ms"] for c in central])),
                    "tvd_da_ms": float(np.median([c["tvd_da_ms"] for c in central])),
                    **{
                        key: float(np.median([entry[key] for entry in safety])) for key in safety[0]
                    },
                    **{key: float(np.median([entry[key] for entry in laws])) for key in laws[0]},
                    "neighbor_histogram": {
                        str(k): round(v / seeds, 2) for k, v in sorted(histogram.items())
                    },
                }
            )
    return rows


# --- brain-tick: the end-to-end cost of one brain's control period in a packed process ---

BRAIN_TICK_SIZES = (1, 50, 200, 500)  # brains per process
BRAIN_TICK_TEAM = 500  # robots in the team the packs share (near-CVT)
# m between them: the circle scenarios' (2 m square for 100 robots, circle-1000's 6.32 m
# for 1000). The cost of a brain-tick grows with the density: the local diagrams and safety
# filters hold more robots (a brain follows the AgentStates of ~7, its Voronoi neighbours
# and the robots within the filter's radius that no neighbour's relay carries).
BRAIN_TICK_SPACING = 0.2
# Periods before timing: the first beacons find every neighbour (~1 s), the local sets
# shrink from the beacons' whole tiles to the two-hop sets, and the states a brain followed
# before its neighbours' relays came stop coming (~3 s); the timed periods are then the
# steady state of a mission. At 25 the last of those was timed, where following fewer
# states (29 Nov 2026) saved nothing yet, and 0.8-0.9x from 40 on (docs/scaling.md).
BRAIN_TICK_WARM = 40
BRAIN_TICK_ROUNDS = 6  # control periods timed


def brain_tick_domain(layout: Layout, t: float, seq: int) -> bytes:
    """The coordinator's Domain at mission time ``t`` as on the wire: the layout's square,
    running, moving at 2 cm/s, tile size 2.5 of its spacings (as the coordinator picks it)."""
    from covswarm import protocol

    velocity = [0.02, 0.01]
    return protocol.Domain(
        seq=seq,
        stamp=BRAIN_TICK_WALL + t,
        t=t,
        state="running",
        vertices=(layout.polygon + np.array(velocity) * t).tolist(),
        velocities=[velocity] * len(layout.polygon),
        kappa=1.0,
        tile_size=2.5 * layout.spacing,
    ).encode()


# us: the amortised brain-tick in a packed process of 500 brains that issue 24 asks for
BRAIN_TICK_TARGET_US = 100.0
BRAIN_TICK_WALL = 1.7e9  # s since the epoch at mission time 0 (a fixed, synthetic clock)


class SpendingClock:
    """A packed process's clock when it is ``late`` times short of CPU: each brain's step
    (:meth:`charge`, around AgentBrain.begin) costs ``late`` / ``brains`` of a ``period``
    s, so about ``brains`` / ``late`` brains step before each period's deadline and the
    rest hold, which costs them next to nothing (covswarm.agent.pack.Pack.step)."""

    def __init__(self, period: float, brains: int, late: float) -> None:
        self.now, self.cost = 0.0, period * late / brains

    def __call__(self) -> float:
        return self.now

    def wall(self) -> float:
        """The wall clock (the bench's synthetic epoch + mission time)."""
        return BRAIN_TICK_WALL + self.now

    def charge(self, brain: Any) -> None:
        """Make each of ``brain``'s steps cost its share of a period on this clock."""
        begin = brain.begin

        def charged(now: float, now_wall: float) -> Any:
            self.now += self.cost
            return begin(now, now_wall)

        brain.begin = charged


def sends_per_period(period: float, late: float) -> int:
    """The poses of each robot and the domains the bench's team sends per control period
    of ``period`` s: one at the asked rate; packs ``late`` > 1 times short of CPU get them
    as live, at LIVE_SEND_RATE (the robots' and the coordinator's rates do not drop with
    the agents')."""
    return 1 if late <= 1.0 else max(1, round(LIVE_SEND_RATE * period))


def publish_period(bus: Any, swarm: str, layout: Layout, k: int, period: float, sends: int) -> None:
    """Put on ``bus`` (covswarm.agent.pack.LocalBus) what the coordinator and the robots of
    ``layout`` send in control period ``k`` of ``period`` s, ``sends`` times each, evenly
    spaced: the Domain (brain_tick_domain) and every robot's Pose at its layout position,
    stamped at their times on the bench's synthetic clock. The bus forgets what was put."""
    from covswarm import protocol

    for j in range(sends):
        t = (k + j / sends) * period
        seq = k * sends + j
        stamp = BRAIN_TICK_WALL + t
        bus.put(protocol.domain_key(swarm), brain_tick_domain(layout, t, seq + 1))
        for rid, (x, y) in enumerate(layout.positions.tolist()):
            pose = protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=stamp, seq=seq)
            bus.put(protocol.pose_key(swarm, rid), pose.encode())
    bus.sent.clear()


def time_brain_ticks(
    per_process: int,
    layout: Layout,
    warm: int = BRAIN_TICK_WARM,
    rounds: int = BRAIN_TICK_ROUNDS,
    rate: float = LIVE_RATE,
    late: float = 1.0,
) -> dict[str, Any]:
    """Amortised cost of one brain-tick in packed processes of ``per_process`` brains.

    The whole team of ``layout`` runs sans-IO: its brains in packs of ``per_process``
    (covswarm.agent.pack.Pack) over one in-memory bus (LocalBus), its robots as poses
    re-published at their layout positions every period, the coordinator as a Domain every
    period, all encoded as on the wire. What is timed is each pack's whole tick: draining
    its subscriptions, handing payloads to the brains that follow them, decoding and
    validating (shared per process), each brain's bookkeeping, the local steps (batched,
    the brains due together in chunks: covswarm.agent.pack.Pack.step), each brain's safety
    filter, wheel speeds, AgentState (with relay) and beacons, encoding the command and the state,
    and the in-memory put that stands in for Zenoh's, under the agent process's garbage
    collection thresholds (covswarm.agent.pack.collect_less). Not timed: Zenoh itself (a
    put costs ~30 us of CPU in a live process), the robots, the coordinator. Returns wall and CPU
    (process_time) microseconds per brain-tick, the mean of ``rounds`` periods, the
    messages each brain received per tick, and ``phase_us``: the wall microseconds per
    brain-tick of each of the packs' phases (covswarm.agent.pack.PHASES, Pack.spent),
    whose sum is the brain-tick but for the step loop around them.

    ``late`` > 1: the packs are that many times short of CPU (SpendingClock): each brain
    steps about every ``late`` periods and holds in between, while the robots' poses and
    the coordinator's domains come at 20 Hz as live (the robots' and the coordinator's
    rates do not drop with the agents'). What a brain-tick then costs counts the payloads
    that piled up since its last turn and each pack's drains, beacons and stats, which
    come per second, over fewer brain-ticks: why a live overloaded run's CPU per
    brain-tick (the run's summary) is several times the bench's. ``rounds`` and ``warm``
    count periods; the warm-up runs every brain every period.
    """
    from covswarm.agent.brain import AgentBrain, AgentConfig
    from covswarm.agent.decoding import MessageDecoder
    from covswarm.agent.pack import PHASES, LocalBus, Pack, collect_less

    swarm = "bench"
    n = len(layout.positions)
    bus = LocalBus()
    config = AgentConfig()
    packs = []
    for first in range(0, n, per_process):
        decoder = MessageDecoder()
        ids = range(first, min(first + per_process, n))
        packs.append(Pack(bus, swarm, [AgentBrain(i, config, decoder) for i in ids]))
    period = 1.0 / rate
    clocks = [SpendingClock(period, len(pack.brains), late) for pack in packs]
    sends = sends_per_period(period, late)
    wall_s = cpu_s = 0.0
    received = ticks = 0
    spent = dict.fromkeys(PHASES, 0.0)
    thresholds = collect_less()  # as the agent process does (covswarm.agent.main)
    for k in range(warm + rounds):
        publish_period(bus, swarm, layout, k, period, sends)
        t = k * period
        before = sum(b.counters.received for p in packs for b in p.brains.values())
        phases_before = [dict(pack.spent) for pack in packs]
        wall0, cpu0 = time.perf_counter(), time.process_time()
        stepped = 0
        for pack, clock in zip(packs, clocks, strict=True):
            if k < warm or late <= 1.0:
                stepped += pack.tick(lambda t=t: t, lambda t=t: BRAIN_TICK_WALL + t, math.inf)
            else:
                if k == warm:
                    for brain in pack.brains.values():
                        clock.charge(brain)
                clock.now = t
                stepped += pack.tick(clock, clock.wall, t + period)
        if k >= warm:
            wall_s += time.perf_counter() - wall0
            cpu_s += time.process_time() - cpu0
            received += sum(b.counters.received for p in packs for b in p.brains.values()) - before
            ticks += stepped
            for pack, earlier in zip(packs, phases_before, strict=True):
                for phase, seconds in pack.spent.items():
                    spent[phase] += seconds - earlier[phase]
    gc.set_threshold(*thresholds)
    return {
        "brain_tick_us": wall_s / ticks * 1e6,
        "brain_tick_cpu_us": cpu_s / ticks * 1e6,
        "rx_per_brain_tick": received / ticks,
        "subscriptions_per_brain": sum(p.subscriptions for p in packs) / n,
        "turns_per_period": ticks / (rounds * n),
        "phase_us": {phase: seconds / ticks * 1e6 for phase, seconds in spent.items()},
    }


def run_brain_ticks(
    sizes: tuple[int, ...],
    team: int,
    sample: int | None,
    progress=None,
    rate: float = LIVE_RATE,
    spacing: float = BRAIN_TICK_SPACING,
    late: float = 1.0,
) -> list[dict]:
    """One row per process size: the amortised brain-tick (time_brain_ticks) at ``rate``
    Hz beside the local step alone (time_local_steps' p50 on the same layout), the team
    ``spacing`` m apart, the packs ``late`` times short of CPU. The warm-up lasts as long
    in time at any rate; so do the periods timed, in whole state periods, and ``late``
    times as many when late (as many brain-ticks)."""
    layout = make_layout(team, "cvt", 0, spacing=spacing)
    step_us, _ = time_local_steps(layout, sample)
    scale = max(1.0, rate / LIVE_RATE)
    warm, rounds = math.ceil(BRAIN_TICK_WARM * scale), math.ceil(BRAIN_TICK_ROUNDS * scale)
    rounds = math.ceil(rounds * late)
    rows = []
    for size in sizes:
        row = time_brain_ticks(size, layout, warm=warm, rounds=rounds, rate=rate, late=late)
        rows.append(
            {
                "agents": team,
                "layout": "brain-tick",
                "rate_hz": rate,
                "spacing_m": spacing,
                "late": late,
                "agents_per_process": size,
                **row,
                "local_step_p50_us": float(np.percentile(step_us, 50)),
                "local_step_mean_us": float(np.mean(step_us)),
            }
        )
        if progress is not None:
            progress(size)
    return rows


def brain_tick_table(rows: list[dict]) -> Any:
    from rich.table import Table

    table = Table(title="covswarm bench --brain-tick: one brain's period, amortised per process")
    for name in (
        "team", "spacing m", "rate Hz", "brains per process", "turns per period",
        "brain-tick us (wall)", "brain-tick us (CPU)", "local step p50 us",
        "local step mean us", "rx per tick", "subscriptions per brain",
    ):  # fmt: skip
        table.add_column(name, justify="right")
    for row in rows:
        table.add_row(
            str(row["agents"]),
            f"{row['spacing_m']:g}",
            f"{row['rate_hz']:g}",
            str(row["agents_per_process"]),
            f"{row['turns_per_period']:.2f}",
            f"{row['brain_tick_us']:.0f}",
            f"{row['brain_tick_cpu_us']:.0f}",
            f"{row['local_step_p50_us']:.0f}",
            f"{row['local_step_mean_us']:.0f}",
            f"{row['rx_per_brain_tick']:.1f}",
            f"{row['subscriptions_per_brain']:.2f}",
        )
    return table


def brain_tick_phase_table(rows: list[dict]) -> Any:
    """Where a brain-tick's wall time goes, per process size (``phase_us`` of each row;
    "other": the step loop around the phases)."""
    from rich.table import Table

    from covswarm.agent.pack import PHASES

    phases = [phase for phase in PHASES if rows and phase in rows[0]["phase_us"]]
    table = Table(title="where a brain-tick goes, us of wall time (covswarm.agent.pack.PHASES)")
    for name in ("brains per process", *phases, "other", "brain-tick"):
        table.add_column(name, justify="right")
    for row in rows:
        split = row["phase_us"]
        other = row["brain_tick_us"] - sum(split.values())
        cells = [f"{split[phase]:.0f}" for phase in phases]
        table.add_row(
            str(row["agents_per_process"]), *cells, f"{other:.0f}", f"{row['brain_tick_us']:.0f}"
        )
    return table


def plot_brain_ticks(rows: list[dict], path: Path) -> None:
    """A stacked bar per process size: the wall microseconds of each phase of a brain-tick
    (``phase_us``), beside the issue's 100 us (docs/scaling.md)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covswarm.agent.pack import PHASES

    phases = [phase for phase in PHASES if phase in rows[0]["phase_us"]]
    labels = [str(row["agents_per_process"]) for row in rows]
    fig, ax = plt.subplots(figsize=(8, 1.2 + 0.5 * len(rows)))
    left = np.zeros(len(rows))
    for phase in phases:
        widths = np.array([row["phase_us"][phase] for row in rows])
        ax.barh(labels, widths, left=left, label=phase)
        left += widths
    other = np.array([row["brain_tick_us"] for row in rows]) - left
    ax.barh(labels, np.maximum(other, 0.0), left=left, label="other", color="0.8")
    ax.axvline(BRAIN_TICK_TARGET_US, color="k", linestyle="--", linewidth=1)
    ax.text(BRAIN_TICK_TARGET_US, len(rows) - 0.5, f" {BRAIN_TICK_TARGET_US:.0f} us", fontsize=8)
    ax.set_xlabel("wall us per brain-tick")
    ax.set_ylabel("brains per process")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))  # clear of the axes
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def live_row(
    run_dir: Path,
    n: int,
    rate: float,
    wall_s: float,
    per_process: int = 1,
    time_scale: float = 1.0,
) -> dict:
    """One "live" bench row from a ``covswarm run`` output folder (summary + resources).

    Agent figures are over the team's latest AgentState stats: compute and latency p50 are
    team means of each agent's p50, p99 team means and maxima of each agent's p99. Memory is
    per robot and per agent (a process's RSS split over the robots or brains it hosts).
    ``per_process`` and ``time_scale`` are the launch settings, recorded in the row.
    """
    summary = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    resources = json.loads((run_dir / "resources.json").read_text(encoding="utf-8"))
    team = summary["agent_stats"]["team"]

    def stat(name: str, of: str = "mean") -> float | None:
        return team[name][of] if name in team else None

    def per_member(role: str, table: str) -> float | None:
        values = resources[table].get(role, [])
        members = resources.get("robots_per_process", {}).get(role, [1] * len(values))
        return sum(values) / sum(members) if values else None

    return {
        "agents": n,
        "layout": "live",
        "mission_s": summary["mission_time"],
        "wall_s": round(wall_s, 1),
        "agents_per_process": per_process,
        "time_scale": time_scale,
        "tile_size": summary.get("tile_size"),
        "initial_error": summary["initial_error"],
        "final_error": summary["final_error"],
        "live_step_p50_us": stat("step_us_p50"),
        "live_step_p99_us": stat("step_us_p99"),
        "live_step_p99_max_us": stat("step_us_p99", "max"),
        "rx_per_agent_per_s": stat("rx_per_s"),
        "pose_to_cmd_p50_ms": stat("pose_age_ms_p50"),
        "pose_to_cmd_p99_ms": stat("pose_age_ms_p99"),
        "pose_to_cmd_p99_max_ms": stat("pose_age_ms_p99", "max"),
        "rate_asked_hz": rate,
        "rate_held_mean_hz": stat("rate_hz"),
        "rate_held_min_hz": stat("rate_hz", "min"),
        "missed_deadline_mean": stat("missed_deadline"),
        "missed_deadline_max": stat("missed_deadline", "max"),
        "rss_per_agent_mb": per_member("agent", "rss_mb"),
        "rss_per_robot_mb": per_member("robot", "rss_mb"),
        "cpu_per_agent_pct": per_member("agent", "cpu_percent_of_core"),
        "cpu_per_robot_pct": per_member("robot", "cpu_percent_of_core"),
        "lost_processes": len(summary["lost_processes"]),
    }


def run_live(
    sizes: tuple[int, ...],
    duration: float,
    out: Path,
    per_process: int = LIVE_PER_PROCESS,
    time_scale: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict]:
    """One short ``covswarm run`` (circle scenario) per N, in turn; a "live" row for each.

    ``per_process`` brains per agent process and robots per robot process, ``time_scale``
    mission seconds per wall second (covswarm run's --agents-per-process, --time-scale).
    A run that fails is reported (its folder keeps the logs) and left out of the rows.
    """
    import subprocess

    from covswarm.deploy.plan import covswarm_argv

    rows = []
    for n in sizes:
        run_dir = out / f"live-{n}"
        argv = [
            *covswarm_argv(), "run", "--scenario", "circle", "--agents", str(n), "--duration",
            repr(duration), "--rate", repr(LIVE_RATE), "--out", str(run_dir),
            "--agents-per-process", str(per_process), "--time-scale", repr(time_scale),
        ]  # fmt: skip
        began = time.monotonic()
        with open(out / f"live-{n}.log", "wb") as log:
            code = subprocess.run(argv, stdout=log, stderr=subprocess.STDOUT).returncode
        if code == 0 and (run_dir / "summary.json").exists():
            rows.append(
                live_row(run_dir, n, LIVE_RATE, time.monotonic() - began, per_process, time_scale)
            )
        if progress is not None:
            progress(n, code)
    return rows


def plain_log_ticks(scale: Any, span: float) -> None:
    """Plain numbers on the log axis ``scale`` (matplotlib's labels ticks 3.6x10^2), the
    minor ticks labelled too when the axis spans less than a decade (``span``: its top over
    its bottom), when it would have no major tick."""
    from matplotlib.ticker import FuncFormatter

    scale.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    few = span < 10.0
    scale.set_minor_formatter(FuncFormatter(lambda value, _: f"{value:g}" if few else ""))


def write_bench(out: Path, rows: list[dict]) -> None:
    """bench.json, bench.csv and the log-log plots into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(rows, indent=2, sort_keys=True) + "\n")
    # Compute and live rows have different columns: the union, blank where a row has none.
    columns = list(dict.fromkeys(key for row in rows for key in row if key != "neighbor_histogram"))
    with open(out / "bench.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, restval="", extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow(row)

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for kind, marker in (("random", "o"), ("cvt", "s")):
        subset = [row for row in rows if row["layout"] == kind]
        n = [row["agents"] for row in subset]
        left.loglog(
            n, [row["local_step_p50_us"] for row in subset], marker + "-", label=f"p50 {kind}"
        )
        left.loglog(
            n, [row["local_step_p99_us"] for row in subset], marker + "--", label=f"p99 {kind}"
        )
        right.loglog(
            n, [row["tvd_c_ms"] * 1e3 for row in subset], marker + "-", label=f"TVD-C {kind}"
        )
        right.loglog(
            n, [row["tvd_d1_ms"] * 1e3 for row in subset], marker + "--", label=f"TVD-D1 {kind}"
        )
        right.loglog(
            n,
            [row["local_step_mean_us"] for row in subset],
            marker + ":",
            label=f"one agent {kind}",
        )
    left.set(
        xlabel="team size N", ylabel="one robot's control step [us]", title="Per-agent compute"
    )
    right.set(
        xlabel="team size N",
        ylabel="one step [us]",
        title="Centralised full-team step vs one agent",
    )
    for axis in (left, right):
        axis.grid(True, which="both", alpha=0.3)
        axis.legend(fontsize=7)
        for scale, (low, high) in ((axis.xaxis, axis.get_xlim()), (axis.yaxis, axis.get_ylim())):
            plain_log_ticks(scale, high / low)
    fig.tight_layout()
    fig.savefig(out / "per_agent_compute.png", dpi=120)
    plt.close(fig)

    fig, axis = plt.subplots(figsize=(6, 4))
    cvt = [row for row in rows if row["layout"] == "cvt"]
    width = 0.8 / max(len(cvt), 1)
    for i, row in enumerate(cvt):
        counts = {int(k): v / row["agents"] for k, v in row["neighbor_histogram"].items()}
        keys = np.array(sorted(counts))
        # the group of bars centred on its neighbour count
        offset = (i - (len(cvt) - 1) / 2) * width
        axis.bar(keys + offset, [counts[k] for k in keys], width, label=f"N = {row['agents']}")
    axis.set(xlabel="neighbours", ylabel="fraction of robots", title="Neighbour counts, near-CVT")
    axis.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "neighbor_histogram.png", dpi=120)
    plt.close(fig)


# The options of each mode that another mode would ignore.
BRAIN_TICK_ONLY = (
    "brain_tick_sizes",
    "brain_tick_team",
    "brain_tick_rate",
    "brain_tick_spacing",
    "brain_tick_late",
)
LIVE_ONLY = ("live_sizes", "live_duration", "live_per_process", "live_time_scale")
STEP_ONLY = ("quick", "sizes", "seeds", "repeats", "obstacles", "live", *LIVE_ONLY)


def check_bench_options(ctx: click.Context, brain_tick: bool, live: bool) -> None:
    """UsageError for options given on the command line that the chosen mode ignores."""
    if brain_tick and (ignored := given_options(ctx, *STEP_ONLY)):
        raise click.UsageError(f"--brain-tick times packed processes only: no {', '.join(ignored)}")
    refuse_unused(ctx, BRAIN_TICK_ONLY, brain_tick, "--brain-tick")
    refuse_unused(ctx, LIVE_ONLY, live, "--live")


def table_console() -> Any:
    """A rich Console for the bench's tables: as wide as they need (160 columns) when the
    output is not a terminal (a pipe or a file, where rich would squeeze them into 80)."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=160)


def step_tables(rows: list[dict]) -> tuple[Any, Any]:
    """The compute rows as two rich tables: one robot's step, and the full team's step and
    the safety filter. The ratios are of timings made interleaved on the same views
    (run_bench), not of the p50s printed beside them."""
    from rich.table import Table

    note = "ratios: timed interleaved on the same views, not of the columns beside them"
    step = Table(title="covswarm bench: one robot's control step vs team size", caption=note)
    full = Table(title="the centralised full-team step, and the safety filter", caption=note)
    step_columns = (
        ("N", "agents", "{:d}"), ("layout", "layout", "{}"),
        ("p50 us", "local_step_p50_us", "{:.0f}"), ("p99 us", "local_step_p99_us", "{:.0f}"),
        ("mean us", "local_step_mean_us", "{:.0f}"),
        ("density p50 us", "local_step_density_p50_us", "{:.0f}"),
        ("density / uniform", "density_over_uniform", "{:.2f}"),
        ("DA p50 us", "local_step_da_p50_us", "{:.0f}"), ("DA / D1", "da_over_d1", "{:.2f}"),
        ("two-hop robots", "two_hop_mean", "{:.1f}"),
    )  # fmt: skip
    full_columns = (
        ("N", "agents", "{:d}"), ("layout", "layout", "{}"),
        ("TVD-C ms", "tvd_c_ms", "{:.1f}"), ("TVD-D1 ms", "tvd_d1_ms", "{:.1f}"),
        ("TVD-DA ms", "tvd_da_ms", "{:.1f}"),
        ("safety filter p50 us", "safety_filter_p50_us", "{:.0f}"),
        ("safety / step", "safety_over_step", "{:.2f}"),
    )  # fmt: skip
    for table, columns in ((step, step_columns), (full, full_columns)):
        for name, _, _ in columns:
            table.add_column(name, justify="right")
        for row in rows:
            table.add_row(*(fmt.format(row[key]) for _, key, fmt in columns))
    return step, full


def live_table(rows: list[dict]) -> Any:
    """The live runs as a rich table."""
    from rich.table import Table

    table = Table(title=f"covswarm bench --live: real runs, agents asked {LIVE_RATE:g} Hz")
    columns = (
        ("N", "agents", "{:d}"), ("K", "agents_per_process", "{:d}"),
        ("scale", "time_scale", "{:g}"), ("tile m", "tile_size", "{:.2f}"),
        ("step p50 us", "live_step_p50_us", "{:.0f}"),
        ("step p99 us", "live_step_p99_us", "{:.0f}"), ("rx/s", "rx_per_agent_per_s", "{:.0f}"),
        ("pose->cmd p50 ms", "pose_to_cmd_p50_ms", "{:.1f}"),
        ("pose->cmd p99 ms", "pose_to_cmd_p99_ms", "{:.1f}"),
        ("rate Hz (min)", "rate_held_min_hz", "{:.1f}"),
        ("missed", "missed_deadline_mean", "{:.1%}"), ("MB/agent", "rss_per_agent_mb", "{:.0f}"),
        ("MB/robot", "rss_per_robot_mb", "{:.0f}"),
        ("CPU/agent % of a core", "cpu_per_agent_pct", "{:.2f}"),
        ("e_a final m", "final_error", "{:.3f}"),
    )  # fmt: skip
    for name, _, _ in columns:
        table.add_column(name, justify="right")
    for row in rows:
        table.add_row(
            *("-" if row[key] is None else fmt.format(row[key]) for _, key, fmt in columns)
        )
    return table


@click.command("bench")
@click.option("--quick", is_flag=True, help="N up to 300, 1 seed, sampled robots (< 2 min).")
@click.option("--sizes", type=SIZES, default=None, help="Team sizes, e.g. 10,100 [10..3000].")
@count_option("--seeds", default=3, help="Layouts per (N, kind).")
@count_option(
    "--sample", default=300, help="Robots timed per layout (--brain-tick: at most its team)."
)
@count_option("--repeats", default=3, help="Full-team steps timed per layout.")
@out_option(help="Output folder [runs/bench-<time>].")
@count_option(
    "--obstacles",
    default=0,
    low=0,
    help="Also time the safety filter with this many 0.2 m boxes in the square (per N).",
)
@click.option(
    "--live", is_flag=True, help="Also run the swarm for real (covswarm run) at --live-sizes."
)
@click.option(
    "--live-sizes",
    type=SIZES,
    default=",".join(map(str, LIVE_SIZES)),
    show_default=True,
    help="Team sizes of the live runs.",
)
@float_option(
    "--live-duration",
    low=0.0,
    low_open=True,
    default=20.0,
    help="Mission length of each live run, s.",
)
@count_option(
    "--live-per-process",
    default=LIVE_PER_PROCESS,
    help="Brains per agent process and robots per robot process in the live runs.",
)
@click.option(
    "--brain-tick",
    is_flag=True,
    help="Only time the end-to-end brain-tick of packed processes (sans-IO, no router) "
    "at --brain-tick-sizes brains per process, beside the local step alone.",
)
@click.option(
    "--brain-tick-sizes",
    type=SIZES,
    default=",".join(map(str, BRAIN_TICK_SIZES)),
    show_default=True,
    help="Brains per process for --brain-tick.",
)
@count_option(
    "--brain-tick-team",
    default=BRAIN_TICK_TEAM,
    low=2,
    help="Robots in the team the packs share for --brain-tick.",
)
@float_option(
    "--brain-tick-rate",
    low=0.5,
    high=MAX_RATE,
    default=LIVE_RATE,
    help="Control rate of the brains for --brain-tick, Hz (AgentStates at most every 0.1 s).",
)
@float_option(
    "--brain-tick-spacing",
    low=0.05,
    default=BRAIN_TICK_SPACING,
    help="Metres between the robots of --brain-tick's team (the circle scenarios': 0.2).",
)
@float_option(
    "--brain-tick-late",
    low=1.0,
    default=1.0,
    help="For --brain-tick: the packs this many times short of CPU (a brain steps about "
    "every that many periods, poses and domains still at 20 Hz), as in an overloaded run.",
)
@float_option(
    "--live-time-scale",
    low=0.0,
    low_open=True,
    default=1.0,
    help="Mission seconds per wall second in the live runs (covswarm run --time-scale).",
)
def bench_command(
    quick: bool,
    sizes: tuple[int, ...] | None,
    seeds: int,
    sample: int,
    repeats: int,
    out: Path | None,
    obstacles: int,
    live: bool,
    live_sizes: tuple[int, ...],
    live_duration: float,
    live_per_process: int,
    live_time_scale: float,
    brain_tick: bool,
    brain_tick_sizes: tuple[int, ...],
    brain_tick_team: int,
    brain_tick_rate: float,
    brain_tick_spacing: float,
    brain_tick_late: float,
) -> None:
    """Measure per-agent compute vs team size against the centralised baseline (and, with
    --live, what real distributed runs achieve; with --brain-tick, only what one brain's
    control period costs in packed processes)."""
    from rich.progress import Progress
    from rich.table import Table

    check_bench_options(click.get_current_context(), brain_tick, live)
    console = table_console()
    if brain_tick:
        out = out or Path("runs") / f"bench-brain-tick-{time.strftime('%Y%m%d-%H%M%S')}"
        if max(brain_tick_sizes) > brain_tick_team:
            raise click.BadParameter(
                f"a process of {max(brain_tick_sizes)} brains in a team of {brain_tick_team}: "
                f"give --brain-tick-team {max(brain_tick_sizes)} or more",
                param_hint="--brain-tick-sizes",
            )
        console.log(
            f"timing the local step, then processes of {', '.join(map(str, brain_tick_sizes))} "
            f"brains in a team of {brain_tick_team}"
        )
        tick_rows = run_brain_ticks(
            brain_tick_sizes,
            brain_tick_team,
            min(sample, brain_tick_team),
            progress=lambda size: console.log(f"{size} brains per process: done"),
            rate=brain_tick_rate,
            spacing=brain_tick_spacing,
            late=brain_tick_late,
        )
        out.mkdir(parents=True, exist_ok=True)
        (out / "bench.json").write_text(json.dumps(tick_rows, indent=2, sort_keys=True) + "\n")
        plot_brain_ticks(tick_rows, out / "brain-tick.png")
        console.print(brain_tick_table(tick_rows))
        console.print(brain_tick_phase_table(tick_rows))
        console.print(f"wrote {out}/bench.json and {out}/brain-tick.png")
        return

    chosen = sizes or (QUICK_SIZES if quick else FULL_SIZES)
    if quick:
        seeds, sample, repeats = 1, min(sample, 100), 1
    out = out or Path("runs") / f"bench-{time.strftime('%Y%m%d-%H%M%S')}"
    with Progress() as bar:
        task = bar.add_task("layouts", total=len(chosen) * 2 * seeds)
        rows = run_bench(
            chosen,
            seeds,
            sample,
            repeats,
            progress=lambda n, kind, seed: bar.update(task, advance=1, description=f"N={n} {kind}"),
            obstacles=obstacles,
        )
    live_rows: list[dict] = []
    failed: list[int] = []
    if live:
        out.mkdir(parents=True, exist_ok=True)

        def live_done(n: int, code: int) -> None:
            if code != 0:
                failed.append(n)
            console.log(
                f"live run N={n}: "
                + ("done" if code == 0 else f"[red]failed ({code}), see {out}/live-{n}.log")
            )

        live_rows = run_live(
            live_sizes, live_duration, out, live_per_process, live_time_scale, progress=live_done
        )
    write_bench(out, rows + live_rows)
    for table in step_tables(rows):
        console.print(table)
    if obstacles:
        walls = Table(title=f"safety filter with {obstacles} obstacles and the workspace walls")
        for name in ("N", "layout", "obstacles near", "p50 us", "p99 us", "added p50 us"):
            walls.add_column(name, justify="right")
        for row in rows:
            walls.add_row(
                str(row["agents"]),
                row["layout"],
                f"{row['obstacles_nearby_mean']:.1f}",
                f"{row['safety_walls_p50_us']:.0f}",
                f"{row['safety_walls_p99_us']:.0f}",
                f"{row['walls_added_p50_us']:.0f}",
            )
        console.print(walls)
    if live_rows:
        console.print(live_table(live_rows))
    console.print(
        f"wrote {out}/bench.json, bench.csv, per_agent_compute.png, neighbor_histogram.png"
    )
    if failed:
        raise click.ClickException(
            f"live runs failed at N = {', '.join(map(str, failed))} (their logs in {out})"
        )
