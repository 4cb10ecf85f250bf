"""A packed agent process (covswarm.agent.pack): one subscription per key, each brain's
inputs as in a process of its own, and a late brain holding its robot. Sans-IO, over the
in-memory LocalBus."""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from covswarm import protocol
from covswarm.agent import decoding
from covswarm.agent import pack as pack_module
from covswarm.agent.brain import AgentBrain, AgentConfig
from covswarm.agent.decoding import MessageDecoder
from covswarm.agent.pack import DOMAIN_RING, PHASES, RING_PER_KEY, LocalBus, Pack
from covswarm.deploy.bench import bench_command
from covswarm.tvd.coverage import aggregate_error

SWARM = "t"
WALL = 1.7e9
SIDE = 2.0
TILE = 0.6


def square(offset: float) -> list[list[float]]:
    return [[offset, 0.0], [offset + SIDE, 0.0], [offset + SIDE, SIDE], [offset, SIDE]]


def _intercept(brain: AgentBrain, hear: Callable[[str, bytes, int | None], object]) -> None:
    """Hand each payload of ``brain``'s turns to ``hear(kind, payload, key_id)`` instead of
    the brain (a pack hands them over with one receive_all call per turn)."""

    def receive_all(items, now, wall):  # type: ignore[no-untyped-def]
        for kind, key_id, payload in items:
            hear(kind, payload, key_id)
        return 0

    brain.receive_all = receive_all  # type: ignore[method-assign]


class World:
    """Robots, a coordinator and packed brains on one LocalBus, stepped on a fake clock.

    The robots sit still but for the commands they get (unicycle, integrated over each
    period); the domain translates along x at ``speed`` m/s. ``packing``: the ids of each
    process; ``timer``: the packs' clock (Pack's ``clock``: step timers and phases).
    """

    def __init__(
        self,
        packing: list[list[int]],
        positions: np.ndarray,
        speed: float = 0.05,
        config: AgentConfig | dict[int, AgentConfig] | None = None,
        hold_after: float = 0.3,
        chunk: int = 32,
        timer: Callable[[], float] = lambda: 0.0,
    ) -> None:
        self.bus = LocalBus()
        self.positions = positions.astype(float).copy()
        self.headings = np.zeros(len(positions))
        self.speed = speed
        configs = config if isinstance(config, dict) else {}
        config = AgentConfig(safety=True) if isinstance(config, dict) else config
        # These robots drive a command for one period only (_move): a command timeout the
        # brains must know, since they predict their robots and turn them by it.
        config = config or AgentConfig(cmd_timeout=0.1)
        self.packs = []
        self.received: dict[int, list] = {}
        for ids in packing:
            decoder = MessageDecoder()
            brains = [
                AgentBrain(i, configs.get(i, config), decoder, clock=lambda: 0.0) for i in ids
            ]
            for brain in brains:
                self._record(brain)
            self.packs.append(Pack(self.bus, SWARM, brains, hold_after, chunk=chunk, clock=timer))
        self.round = 0
        self.sent_commands: list[protocol.WheelCommand] = []
        self.sent_states: list[protocol.AgentState] = []

    def _record(self, brain: AgentBrain) -> None:
        log = self.received[brain.id] = []
        receive_all = brain.receive_all  # what receive() and a pack's turn go through

        def recording(items, now, now_wall):  # type: ignore[no-untyped-def]
            items = list(items)
            log.extend((self.round, kind, key_id, payload) for kind, key_id, payload in items)
            return receive_all(items, now, now_wall)

        brain.receive_all = recording  # type: ignore[method-assign]

    def publish(self, t: float) -> None:
        """The coordinator's domain and every robot's pose at mission time ``t``."""
        offset = self.speed * t
        self.bus.put(
            protocol.domain_key(SWARM),
            protocol.Domain(
                seq=self.round + 1,
                stamp=WALL + t,
                t=t,
                state="running",
                vertices=square(offset),
                velocities=[[self.speed, 0.0]] * 4,
                kappa=1.0,
                tile_size=TILE,
            ).encode(),
        )
        for rid, ((x, y), theta) in enumerate(zip(self.positions, self.headings, strict=True)):
            self.bus.put(
                protocol.pose_key(SWARM, rid),
                protocol.Pose(
                    id=rid, x=x, y=y, theta=theta, stamp=WALL + t, seq=self.round
                ).encode(),
            )

    def run(
        self,
        rounds: int,
        period: float = 0.1,
        cost: float = 0.0,
        separately: bool = False,
        order: list[int] | None = None,
    ) -> list[float]:
        """``rounds`` control periods; e_a after each. ``cost``: s of the fake clock each
        brain's turn takes (an injected delay: a starved process); ``separately``: every
        pack drains before any steps (processes of their own see the same traffic);
        ``order``: the packs' stepping order (a subscription declared before a teammate
        publishes gets its message, after it does not, packed or not)."""
        errors = []
        for _ in range(rounds):
            t = self.round * period
            self.publish(t)
            clock = [t]
            if separately:
                for pack in self.packs:
                    pack.drain()
            for pack in [self.packs[i] for i in order or range(len(self.packs))]:
                if not separately:
                    pack.drain()
                self._step(pack, clock, t + period, cost)
            self._move(period)
            self.round += 1
            errors.append(self.error(self.round * period))
        return errors

    @staticmethod
    def _step(pack: Pack, clock: list[float], deadline: float, cost: float) -> None:
        """pack.step with each brain's step advancing the fake clock by ``cost`` s."""
        originals = {bid: brain.begin for bid, brain in pack.brains.items()}

        def costly(bid: int):  # type: ignore[no-untyped-def]
            def begin(now: float, now_wall: float):  # type: ignore[no-untyped-def]
                clock[0] += cost
                return originals[bid](now, now_wall)

            return begin

        for bid, brain in pack.brains.items():
            brain.begin = costly(bid)  # type: ignore[method-assign]
        try:
            pack.step(lambda: clock[0], lambda: WALL + clock[0], deadline)
        finally:
            for bid, brain in pack.brains.items():
                brain.begin = originals[bid]  # type: ignore[method-assign]

    def _move(self, period: float) -> None:
        """Each robot integrates its newest command over the period (differential drive)."""
        latest: dict[int, protocol.WheelCommand] = {}
        for key, payload in self.bus.sent:
            if key.endswith("/cmd"):
                command = protocol.WheelCommand.decode(payload)
                latest[command.id] = command
            elif key.endswith("/state"):
                self.sent_states.append(protocol.AgentState.decode(payload))
        self.sent_commands.extend(latest.values())
        self.bus.sent.clear()
        axle = AgentConfig().robot.wheel_separation
        for rid, command in latest.items():
            forward = 0.5 * (command.left + command.right)
            turn = (command.right - command.left) / axle
            theta = self.headings[rid]
            self.positions[rid] += forward * period * np.array([math.cos(theta), math.sin(theta)])
            self.headings[rid] = theta + turn * period
        self.commands = latest

    def error(self, t: float) -> float:
        return aggregate_error(self.positions, np.array(square(self.speed * t)))


def layout(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.2, SIDE - 0.2, (n, 2))


def decoded(commands: dict[int, protocol.WheelCommand]) -> dict[int, tuple]:
    """The commands' fields: wheel speeds to be compared to 1e-9 (a batched step may round
    differently from a lone one), the rest exactly."""
    return {i: (c.left, c.right, c.stamp, c.seq, c.pose_stamp) for i, c in commands.items()}


# Brains of one process with other laws and without feedforward: their local steps are
# batched apart (by law and feedforward), each as its own lone brain would step.
MIXED = {i: AgentConfig(law="d1") for i in (1, 4, 9)} | {
    i: AgentConfig(feedforward=False) for i in (2, 7)
}


@pytest.mark.parametrize(("chunk", "configs"), [(32, None), (4, MIXED)])
def test_packed_brains_get_and_do_what_lone_brains_do(
    chunk: int, configs: dict[int, AgentConfig] | None
) -> None:
    n = 14
    positions = layout(n, 3)
    packed = World([list(range(n))], positions, config=configs, chunk=chunk)
    alone = World([[i] for i in range(n)], positions, config=configs)
    commands_packed, commands_alone = [], []
    for _ in range(25):
        order = list(packed.packs[0].order)
        packed.run(1, separately=False)
        alone.run(1, separately=True, order=order)
        commands_packed.append(decoded(packed.commands))
        commands_alone.append(decoded(alone.commands))
    # Same messages in ...
    for rid in range(n):
        assert packed.received[rid] == alone.received[rid], rid
        assert {kind for _, kind, _, _ in packed.received[rid]} == {
            "domain",
            "pose",
            "state",
            "beacon",
        }
    # ... same commands out, and they move the robots.
    for ours, theirs in zip(commands_packed, commands_alone, strict=True):
        assert ours.keys() == theirs.keys()
        for rid, (left, right, *rest) in ours.items():
            assert left == pytest.approx(theirs[rid][0], abs=1e-9), rid
            assert right == pytest.approx(theirs[rid][1], abs=1e-9), rid
            assert rest == list(theirs[rid][2:]), rid
    assert all(b.counters.batch_fallbacks == 0 for b in packed.packs[0].brains.values())
    assert np.abs(packed.positions - positions).max() > 0.01
    # One subscription per key for the process, against one per brain and key alone.
    pack = packed.packs[0]
    assert pack.followers(protocol.domain_key(SWARM)) == frozenset(range(n))
    alone_subs = sum(p.subscriptions for p in alone.packs)
    assert pack.subscriptions < alone_subs / 2
    for rid in range(n):  # the reference count is exactly the brains that follow the key
        key = protocol.agent_state_key(SWARM, rid)
        following = {p.order[0] for p in alone.packs if p.followers(key) == frozenset(p.order)}
        assert pack.followers(key) == following


def test_a_subscription_lives_while_a_brain_follows_it() -> None:
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1)])
    key = protocol.agent_state_key(SWARM, 5)
    pack.follow(0, "state", frozenset({5}))
    pack.follow(1, "state", frozenset({5, 6}))
    assert pack.followers(key) == {0, 1}
    state = protocol.AgentState(id=5, x=1.0, y=1.0, stamp=WALL, neighbors=[])
    bus.put(key, state.encode())
    pack.drain()
    pack.follow(0, "state", frozenset())  # 0 stops following before its turn: not for it
    assert pack.followers(key) == {1}
    seen = []
    for brain in pack.brains.values():
        _intercept(brain, lambda kind, payload, key_id, b=brain.id: seen.append((b, kind, key_id)))
    pack.receive(0, 0.0, WALL)
    pack.receive(1, 0.0, WALL)
    assert seen == [(1, "state", 5)]
    pack.follow(1, "state", frozenset())
    assert pack.followers(key) == frozenset() and key not in bus._exact
    with pytest.raises(ValueError, match="twice"):
        Pack(bus, SWARM, [AgentBrain(2), AgentBrain(2)])


@pytest.mark.parametrize("chunk", [1, 4])
def test_a_late_brain_skips_its_period_then_holds_its_robot(chunk: int) -> None:
    n = 6
    world = World([list(range(n))], layout(n, 5), speed=0.0, chunk=chunk)
    world.run(3)  # warm: every brain steps, robots move
    pack = world.packs[0]
    assert all(b.counters.late == 0 for b in pack.brains.values())
    first = list(pack.order)
    # Each turn costs 0.04 s of a 0.1 s period, the deadline checked before each brain
    # begins its step, in chunks or not: three brains step, three skip the period, their
    # robots on the command of their last step 0.1 s ago (no new one, no stop).
    world.run(1, cost=0.04)
    late = first[3:]
    assert [pack.brains[b].counters.late for b in first] == [0, 0, 0, 1, 1, 1]
    assert pack.order[0] == late[0]  # the next tick starts with them
    assert sorted(world.commands) == sorted(first[:3])
    # At 0.15 s a turn, one brain steps per period: the others' last steps grow older than
    # hold_after (0.3 s) and they stop their robots, once per stretch without a step.
    steps = {bid: pack.brains[bid].counters.steps for bid in first}
    world.sent_commands.clear()
    world.sent_states.clear()
    world.run(8, cost=0.15)
    for bid in first:
        mine = [c for c in world.sent_commands if c.id == bid]
        zeros = [c for c in mine if (c.left, c.right) == (0.0, 0.0)]
        stepped = pack.brains[bid].counters.steps - steps[bid]
        assert 1 <= len(zeros) <= stepped + 1 and len(mine) == stepped + len(zeros), bid
        # With the stop goes an AgentState saying so: neighbours must not dead-reckon the
        # robot on at the velocity of its last step.
        stopped = [s for s in world.sent_states if s.id == bid and (s.vx, s.vy) == (0.0, 0.0)]
        assert len(stopped) >= len(zeros), bid
    stats = pack.brains[late[0]].stats()
    assert 0.5 < stats["late_held"] < 1.0
    with pytest.raises(ValueError, match="hold_after"):
        Pack(LocalBus(), SWARM, [AgentBrain(9)], hold_after=0.0)


def test_a_late_brain_holds_its_robot_no_earlier_than_its_command_was_meant_for() -> None:
    """Six brains at 0.15 s a turn in 0.1 s periods: each steps every ~0.65 s of the fake
    clock. A command is computed to hold that gap up to the robot's command timeout
    (command_hold), so with a 0.5 s timeout the robot is stopped only once its step is
    older than 0.5 s, not at hold_after (0.3 s), where a 0.1 s timeout still stops it."""
    n = 6

    def hold_ages(cmd_timeout: float) -> tuple[list[float], float]:
        """The age of the last step at every stop after a warm-up, and the largest
        command_hold then."""
        world = World(
            [list(range(n))], layout(n, 5), speed=0.0, config=AgentConfig(cmd_timeout=cmd_timeout)
        )
        world.run(3)
        world.run(12, cost=0.15)  # until every brain's hold reflects its late turns
        pack, ages = world.packs[0], []
        for brain in pack.brains.values():
            hold = brain.hold

            def recording(now, wall, brain=brain, hold=hold):  # type: ignore[no-untyped-def]
                ages.append(now - pack._stepped[brain.id])
                return hold(now, wall)

            brain.hold = recording  # type: ignore[method-assign]
        world.run(24, cost=0.15)
        return ages, max(b.command_hold for b in pack.brains.values())

    ages, hold = hold_ages(0.5)
    assert hold == pytest.approx(0.5)
    assert len(ages) >= n and min(ages) > 0.5
    ages, hold = hold_ages(0.1)
    assert hold == pytest.approx(0.1)
    assert len(ages) >= n and 0.3 < min(ages) <= 0.4


@pytest.mark.parametrize(("cost", "chunk"), [(0.0, 32), (0.01, 1), (0.03, 1), (0.3, 1), (0.03, 4)])
def test_a_starved_process_slows_down_and_stays_together(cost: float, chunk: int) -> None:
    """Turns that cost ``cost`` s each (an injected delay: at 0.03 s three of the twelve
    brains step per 0.1 s period, in chunks of four or not; at 0.3 s one) slow the team
    down but never spread it apart: e_a stays within the unstarved run's
    transient over a team standing still (1.33x, the robots turning from random headings),
    ends no worse than it started, and converges when a brain still steps every other
    period."""
    n = 12
    world = World([list(range(n))], layout(n, 7), speed=0.05, chunk=chunk)
    still = np.array([world.error((k + 1) * 0.1) for k in range(60)])
    errors = np.array(world.run(60, cost=cost))
    assert np.all(errors <= 1.35 * still)
    assert errors[-1] <= 1.15 * still[0]
    if cost <= 0.01:
        assert errors[-1] < 0.15
    late = sum(b.counters.late for b in world.packs[0].brains.values())
    assert (late > 0) == (cost * n > 0.1)


def test_bench_brain_tick_reports_every_process_size(tmp_path: Path) -> None:
    out = tmp_path / "bt"
    argv = ["--brain-tick", "--brain-tick-sizes", "1,15", "--brain-tick-team", "30"]
    result = CliRunner().invoke(bench_command, [*argv, "--sample", "5", "--out", str(out)])
    assert result.exit_code == 0, result.output
    alone, packed = json.loads((out / "bench.json").read_text())
    assert (alone["agents_per_process"], packed["agents_per_process"]) == (1, 15)
    for row in (alone, packed):
        assert row["layout"] == "brain-tick" and row["agents"] == 30
        assert 10.0 < row["brain_tick_cpu_us"] < 1e6 and 10.0 < row["local_step_p50_us"] < 1e6
        assert row["rx_per_brain_tick"] >= 2.0  # at least its pose and the domain
    # A process of 15 brains subscribes once per key: fewer subscriptions per brain.
    assert packed["subscriptions_per_brain"] < alone["subscriptions_per_brain"] / 2
    # Where each brain-tick went: every phase, within the tick's time, the math among them.
    for row in (alone, packed):
        split = row["phase_us"]
        assert set(split) == set(PHASES) and min(split.values()) >= 0.0
        assert sum(split.values()) <= row["brain_tick_us"] * (1 + 1e-9)
        assert split["local steps"] > 0.0 and split["receive"] > 0.0
    assert (out / "brain-tick.png").stat().st_size > 0
    assert "where a brain-tick goes" in result.output
    bad = CliRunner().invoke(bench_command, ["--brain-tick", "--brain-tick-sizes", "0"])
    assert bad.exit_code != 0 and "expected positive integers" in bad.output


def test_a_tile_sample_goes_to_each_follower_and_a_malformed_key_is_counted() -> None:
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1), AgentBrain(2)])
    pack.follow(0, "beacon", frozenset({(0, 0)}))
    pack.follow(1, "beacon", frozenset({(0, 0), (1, 0)}))
    beacon = protocol.Beacon(id=7, x=0.1, y=0.1, stamp=WALL)
    bus.put(protocol.beacon_key(SWARM, 0, 0, 7), beacon.encode())
    bus.put(protocol.beacon_key(SWARM, 0, 0, 7), beacon.encode())  # coalesced
    bus.put(protocol.beacon_tile_selector(SWARM, 0, 0)[:-1] + "x", b"junk")
    pack.drain()
    seen: dict[int, list] = {0: [], 1: [], 2: []}
    for bid, brain in pack.brains.items():
        _intercept(brain, lambda kind, payload, key_id, b=bid: seen[b].append((kind, key_id)))
        pack.receive(bid, 0.0, WALL)
    assert seen == {0: [("beacon", 7)], 1: [("beacon", 7)], 2: []}
    for bid, brain in pack.brains.items():
        assert brain.drops.counts["wrong_id"] == (bid < 2)
        assert brain.counters.coalesced == (bid < 2)


@pytest.fixture
def decodes(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """Payloads decoded from now on, by kind (covswarm.agent.decoding's one decoder)."""
    counts: Counter[str] = Counter()
    received = decoding._received

    def counting(kind: str, payload: object) -> object:
        counts[kind] += 1
        return received(kind, payload)

    monkeypatch.setattr(decoding, "_received", counting)
    return counts


def test_a_payload_is_decoded_once_per_process_whatever_its_followers(
    decodes: Counter[str],
) -> None:
    """Five brains follow the same keys: each payload drained is decoded once for the
    process, tick after tick, and every brain takes it as a lone brain takes its bytes (an
    invalid one counted as a drop by each, with the lone brain's reason)."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(i) for i in range(5)])
    for bid in pack.brains:
        pack.follow(bid, "state", frozenset({8, 9}))
        pack.follow(bid, "beacon", frozenset({(0, 0)}))
    domain = protocol.Domain(
        seq=1,
        stamp=WALL,
        t=0.0,
        state="running",
        vertices=square(0.0),
        velocities=[[0.0, 0.0]] * 4,
        kappa=1.0,
    )
    payloads = [
        ("domain", None, protocol.domain_key(SWARM), domain.encode()),
        (
            "state",
            9,
            protocol.agent_state_key(SWARM, 9),
            protocol.AgentState(id=9, x=1.0, y=1.0, stamp=WALL, neighbors=[]).encode(),
        ),
        ("state", 8, protocol.agent_state_key(SWARM, 8), b'{"id": 8}'),  # invalid
        (
            "beacon",
            7,
            protocol.beacon_key(SWARM, 0, 0, 7),
            protocol.Beacon(id=7, x=0.1, y=0.1, stamp=WALL).encode(),
        ),
    ]
    for tick in range(1, 3):
        for _, _, key, payload in payloads:
            bus.put(key, payload)
        pack.drain()
        for bid in pack.brains:
            pack.receive(bid, 0.1 * tick, WALL)
        assert decodes == {"domain": tick, "state": 2 * tick, "beacon": tick}
    lone = AgentBrain(5)
    for tick in range(1, 3):
        for kind, key_id, _, payload in payloads:
            lone.receive(kind, payload, 0.1 * tick, WALL, key_id)
    assert lone.drops.counts and lone.peer_clocks.keys() == {9}
    for brain in pack.brains.values():
        assert brain.drops.counts == lone.drops.counts
        assert brain.peer_clocks.keys() == {9} and brain.domain == lone.domain
        assert brain.counters.received == lone.counters.received == 8


def test_a_brain_gets_its_payloads_by_kind_then_id_then_key() -> None:
    """A turn's payloads reach a brain in the documented order whatever order they arrived
    in: the world, the domain (every sample, in arrival order), its pose, the states by
    id, the beacons by id then tile key; a key it stopped following hands it nothing."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1)])
    pack.follow(0, "state", frozenset({9, 3, 5, 6}))
    pack.follow(0, "beacon", frozenset({(1, 0), (0, 0)}))
    arrivals = [
        (protocol.beacon_key(SWARM, 1, 0, 4), b"beacon 4 in (1, 0)"),
        (protocol.agent_state_key(SWARM, 9), b"state 9"),
        (protocol.domain_key(SWARM), b"domain a"),
        (protocol.beacon_key(SWARM, 0, 0, 8), b"beacon 8"),
        (protocol.agent_state_key(SWARM, 6), b"state 6"),
        (protocol.pose_key(SWARM, 0), b"pose 0"),
        (protocol.agent_state_key(SWARM, 3), b"state 3"),
        (protocol.beacon_key(SWARM, 0, 0, 4), b"beacon 4 in (0, 0)"),
        (protocol.world_key(SWARM), b"world"),
        (protocol.domain_key(SWARM), b"domain b"),
        (protocol.agent_state_key(SWARM, 5), b"state 5"),
        (protocol.pose_key(SWARM, 1), b"pose 1"),
    ]
    for key, payload in arrivals:
        bus.put(key, payload)
    pack.drain()
    pack.follow(0, "state", frozenset({9, 3, 5}))  # 6 unfollowed before the brain's turn
    seen: list[tuple[str, int | None, bytes]] = []
    _intercept(pack.brains[0], lambda kind, payload, key_id: seen.append((kind, key_id, payload)))
    pack.take_own_poses([0])  # as before its turn
    pack.receive(0, 0.0, WALL)
    assert seen == [
        ("world", None, b"world"),
        ("domain", None, b"domain a"),
        ("domain", None, b"domain b"),
        ("pose", 0, b"pose 0"),
        ("state", 3, b"state 3"),
        ("state", 5, b"state 5"),
        ("state", 9, b"state 9"),
        ("beacon", 4, b"beacon 4 in (0, 0)"),
        ("beacon", 4, b"beacon 4 in (1, 0)"),
        ("beacon", 8, b"beacon 8"),
    ]


def test_a_bad_view_stops_only_its_brain_and_the_batch_fallback_is_counted() -> None:
    """A brain whose local step raises (an invalid gain here) in a chunk with others: the
    batch is taken again one by one, the bad brain stops its robot and counts a step
    error, the others step as lone brains would."""
    n = 6
    positions = layout(n, 11)
    configs = {2: AgentConfig(kappa=-1.0)}
    packed = World([list(range(n))], positions, config=configs)
    alone = World([[i] for i in range(n)], positions, config=configs)
    for _ in range(4):
        order = list(packed.packs[0].order)
        packed.run(1)
        alone.run(1, separately=True, order=order)
        assert (packed.commands[2].left, packed.commands[2].right) == (0.0, 0.0)
        for rid in set(range(n)) - {2}:
            assert packed.commands[rid].left == pytest.approx(alone.commands[rid].left, abs=1e-9)
            assert packed.commands[rid].right == pytest.approx(alone.commands[rid].right, abs=1e-9)
    brains = packed.packs[0].brains
    assert brains[2].counters.step_errors == brains[2].counters.steps > 0
    assert all(brains[i].counters.step_errors == 0 for i in set(range(n)) - {2})
    fallbacks = {b.stats()["batch_fallbacks"] for b in brains.values()}
    assert fallbacks == {brains[0].counters.steps}  # every batch held the bad view
    with pytest.raises(ValueError, match="chunk"):
        Pack(LocalBus(), SWARM, [AgentBrain(9)], chunk=0)


def test_a_token_change_is_recorded_once_for_the_process_and_applied_as_alone() -> None:
    """Agent 3's token vanishes (its last states still in flight) and agent 9's appears:
    the packed process records each change once, and every brain drops 3 for the period,
    takes it back with its next fresh state, and owes the newcomer a beacon, as lone
    brains do."""
    n = 6
    positions = layout(n, 13)
    packed = World([list(range(n))], positions)
    alone = World([[i] for i in range(n)], positions)

    def known(world: World) -> dict[int, list[int]]:
        brains = [b for p in world.packs for b in p.brains.values()]
        return {b.id: sorted(b.neighborhood.reckoned) for b in brains}

    def change(world: World, rid: int, alive: bool) -> None:
        for pack in world.packs:
            pack._token_changes.samples.append((protocol.alive_key(SWARM, "agent", rid), alive))

    for _ in range(5):
        order = list(packed.packs[0].order)
        packed.run(1)
        alone.run(1, separately=True, order=order)
    assert any(3 in ids for rid, ids in known(packed).items() if rid != 3)
    serial = packed.packs[0].liveliness.serial
    for alive, rid in ((False, 3), (True, 9)):
        change(packed, rid, alive)
        change(alone, rid, alive)
        order = list(packed.packs[0].order)
        packed.run(1)
        alone.run(1, separately=True, order=order)
        assert known(packed) == known(alone)
        dropped = all(3 not in ids for ids in known(packed).values())
        assert dropped == (not alive)  # back with its next state
    assert packed.packs[0].liveliness.serial == serial + 2  # once each, for all six
    # Every brain owes the newcomer an early beacon, or sent one in the newcomer's period
    # (a robot driving through S beacons as it moves).
    last = (packed.round - 1) * 0.1
    for world in (packed, alone):
        brains = [b for p in world.packs for b in p.brains.values()]
        assert all(b._beacon_due or b._last_beacon == last for b in brains)


def test_a_brain_that_stops_following_gets_nothing_set_aside_for_it() -> None:
    """Brains 0 and 1 follow robot 5's AgentState when it arrives; brain 2 then begins to
    follow it too (the state is set aside for 0 and 1: not 2's, its own subscriber would
    not have had it), and brain 0 stops. Its own subscriber's unread state would be lost
    with it: only brain 1 gets it. Brain 0 got it anyway (a follow pattern of the moving
    beacons broke tests/test_packed_brains_get_and_do_what_lone_brains_do)."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1), AgentBrain(2)])
    for bid in (0, 1):
        pack.follow(bid, "state", frozenset({5}))
    state = protocol.AgentState(id=5, x=1.0, y=1.0, stamp=WALL, neighbors=())
    bus.put(protocol.agent_state_key(SWARM, 5), state.encode())
    pack.follow(2, "state", frozenset({5}))
    pack.follow(0, "state", frozenset())
    pack.drain()
    got = {bid: list(pack._pending[bid]) for bid in (0, 1, 2)}
    assert not got[0] and not got[2]
    assert len(got[1]) == 1


def test_a_receipt_time_never_precedes_the_pose_received() -> None:
    """Robot 1's next pose arrives while brain 0 of the same chunk takes its inputs. A
    chunk that read its clock before draining its robots' poses handed that pose over with
    a receipt time before its stamp: robot 1's clock then seemed 50 ms ahead of ours, and
    each of its later poses 50 ms older than it was (predicted that much too far)."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1)])
    clock = [0.0]
    seq = [0]

    def put_pose(rid: int) -> None:
        seq[0] += 1
        pose = protocol.Pose(id=rid, x=1.0, y=1.0, theta=0.0, stamp=WALL + clock[0], seq=seq[0])
        bus.put(protocol.pose_key(SWARM, rid), pose.encode())

    put_pose(0)
    put_pose(1)
    first = pack.brains[0]
    receive_all = first.receive_all

    def slow_receive(items, now, wall):  # type: ignore[no-untyped-def]
        for _ in items:
            clock[0] += 0.05  # brain 0's inputs take 50 ms each (a loaded machine) ...
            put_pose(1)  # ... during which robot 1 publishes again
        return receive_all(items, now, wall)

    first.receive_all = slow_receive  # type: ignore[method-assign]
    pack.tick(lambda: clock[0], lambda: WALL + clock[0], 1.0)
    for brain in pack.brains.values():
        assert brain.pose is not None
        assert brain.robot_clock.bound >= 0.0, (brain.id, brain.robot_clock.bound)
        assert brain.pose_taken == brain.pose.stamp


def test_bench_brain_tick_at_a_denser_team_and_a_faster_rate(tmp_path: Path) -> None:
    """A denser team puts more robots within the safety filter's radius, but a brain follows
    the AgentStates only of those no neighbour's relay carries: it receives about as much
    per tick at 0.2 m spacing as at 0.5 m (6.9 against 6.6 payloads, 29 Nov 2026; 1.5x and
    more when it followed every robot within the radius). At 30 Hz AgentStates still go out
    at ~10 Hz (fewer per tick)."""
    rows = {}
    for spacing, rate in ((0.5, 10), (0.2, 10), (0.2, 30)):
        out = tmp_path / f"bt-{spacing}-{rate}"
        argv = ["--brain-tick", "--brain-tick-sizes", "30", "--brain-tick-team", "30"]
        argv += ["--brain-tick-spacing", str(spacing), "--brain-tick-rate", str(rate)]
        result = CliRunner().invoke(bench_command, [*argv, "--sample", "5", "--out", str(out)])
        assert result.exit_code == 0, result.output
        (row,) = json.loads((out / "bench.json").read_text())
        assert (row["spacing_m"], row["rate_hz"]) == (spacing, rate)
        rows[spacing, rate] = row["rx_per_brain_tick"]
    assert rows[0.2, 10] < 1.25 * rows[0.5, 10]
    assert rows[0.2, 30] < 0.6 * rows[0.2, 10]


def test_a_late_brain_gets_the_newest_domains_its_own_ring_would_hold() -> None:
    """A brain whose turn comes after several drains (overload) is handed the newest
    DOMAIN_RING domain samples since its last turn, in arrival order, the older ones
    counted as coalesced; a brain that took its turn in between gets only what came since."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(0), AgentBrain(1)])
    seen: dict[int, list[bytes]] = {0: [], 1: []}
    for bid in (0, 1):
        _intercept(
            pack.brains[bid], lambda kind, payload, key_id, bid=bid: seen[bid].append(payload)
        )
    sent = [f"domain {k}".encode() for k in range(3 * DOMAIN_RING + 5)]
    for k, payload in enumerate(sent):
        bus.put(protocol.domain_key(SWARM), payload)
        if k % 3 == 2:  # a drain every three broadcasts, as at 20 Hz broadcast, ~7 Hz held
            pack.drain()
        if k == DOMAIN_RING:
            pack.receive(1, 0.0, WALL)  # brain 1 takes a turn; brain 0 is late throughout
    pack.drain()
    for bid in (0, 1):
        pack.receive(bid, 1.0, WALL)
    assert seen[0] == sent[-DOMAIN_RING:]
    assert pack.brains[0].counters.coalesced == len(sent) - DOMAIN_RING
    # brain 1: the 15 drained by its first turn (fewer than the ring), then the newest
    assert seen[1] == sent[:15] + sent[-DOMAIN_RING:]
    assert pack.brains[1].counters.coalesced == len(sent) - 15 - DOMAIN_RING


def test_a_payload_replaced_before_any_followers_turn_is_never_decoded(
    decodes: Counter[str],
) -> None:
    """A process decodes a payload when a follower first takes it, and takes a brain's own
    pose off the bus only before its turn: poses that a newer pose replaced before their
    brain's turn (a late brain, its robot at 20 Hz) cost no decoding."""
    bus = LocalBus()
    pack = Pack(bus, SWARM, [AgentBrain(i) for i in range(3)])
    for seq in range(6):  # six drains without a turn
        for rid in range(3):
            pose = protocol.Pose(id=rid, x=1.0, y=1.0, theta=0.0, stamp=WALL, seq=seq)
            bus.put(protocol.pose_key(SWARM, rid), pose.encode())
        pack.drain()
    assert decodes == {}
    pack.take_own_poses([1])  # as before a turn: the newest in the ring (RING_PER_KEY)
    pack.receive(1, 0.0, WALL)
    assert decodes == {"pose": 1}
    assert pack.brains[1].pose is not None and pack.brains[1].pose.seq == 5
    assert pack.brains[1].counters.coalesced == RING_PER_KEY - 1


def test_a_chunk_whose_turn_comes_after_the_deadline_leaves_its_poses_on_the_bus(
    decodes: Counter[str],
) -> None:
    """Turns of 0.03 s in 0.1 s periods, chunks of four: the first chunk steps, the period
    is over before the second's turn, whose brains hold without taking their robots' poses
    off the bus (none decoded); at their next turn each steps from its robot's newest."""
    n = 8
    world = World([list(range(n))], layout(n, 3), speed=0.0, chunk=4)
    world.run(3)
    pack = world.packs[0]
    first, second = pack.order[:4], pack.order[4:]
    decodes.clear()
    world.run(1, cost=0.03)
    assert [pack.brains[b].counters.late for b in first] == [0] * 4
    assert [pack.brains[b].counters.late for b in second] == [1] * 4
    assert decodes["pose"] == 4  # the first chunk's own poses only
    assert pack.order[:4] == second  # the next period starts with them
    world.run(1, cost=0.03)
    for bid in second:
        brain = pack.brains[bid]
        assert brain.counters.late == 1 and brain.pose is not None
        assert brain.pose.seq == world.round - 1  # its robot's newest pose


def test_bench_brain_tick_of_an_overloaded_pack(tmp_path: Path) -> None:
    """--brain-tick-late 6: each brain steps about every sixth period (turns per period
    ~1/6), and with the poses and domains at 20 Hz piling up in between, a brain receives
    more per turn than at the asked rate."""
    rows = {}
    for late in (1, 6):
        out = tmp_path / f"late-{late}"
        argv = ["--brain-tick", "--brain-tick-sizes", "30", "--brain-tick-team", "30"]
        argv += ["--brain-tick-late", str(late), "--sample", "5", "--out", str(out)]
        result = CliRunner().invoke(bench_command, argv)
        assert result.exit_code == 0, result.output
        (row,) = json.loads((out / "bench.json").read_text())
        assert row["late"] == late
        rows[late] = row
    assert rows[1]["turns_per_period"] == 1.0
    assert 1 / 9 < rows[6]["turns_per_period"] < 1 / 4
    assert rows[6]["rx_per_brain_tick"] > 1.5 * rows[1]["rx_per_brain_tick"]
    bad = CliRunner().invoke(bench_command, ["--brain-tick", "--brain-tick-late", "0.5"])
    assert bad.exit_code != 0


def test_each_phase_of_a_tick_is_timed_where_it_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pack.spent adds up the packs' clock by phase: each stand-in below advances the clock
    by its own amount when it runs, so each phase must hold exactly its own amounts, once
    per call (no phase counted in another, none twice); a brain whose turn comes after the
    deadline counts as a hold."""
    timer = [0.0]
    calls: Counter[str] = Counter()

    def advancing(name: str, seconds: float, real: Callable) -> Callable:
        def run(*args, **kwargs):  # type: ignore[no-untyped-def]
            calls[name] += 1
            timer[0] += seconds
            return real(*args, **kwargs)

        return run

    costs = {"drain": 13.0, "receive": 2.0, "begin": 3.0, "local steps": 5.0}
    costs |= {"conclude": 19.0, "filter": 7.0, "actions": 11.0, "hold": 23.0}
    for name, owner, attribute in (
        ("drain", Pack, "drain"),
        ("receive", AgentBrain, "receive_all"),
        ("begin", AgentBrain, "begin"),
        ("conclude", AgentBrain, "conclude"),
        ("actions", AgentBrain, "actions"),
        ("hold", Pack, "_hold_unless_stopped"),
        ("local steps", pack_module, "local_steps"),
        ("filter", pack_module, "filter_all"),
    ):
        real = getattr(owner, attribute)
        monkeypatch.setattr(owner, attribute, advancing(name, costs[name], real))
    n = 5
    world = World([list(range(n))], layout(n, 3), config={}, chunk=2, timer=lambda: timer[0])
    (pack,) = world.packs
    for k in range(4):
        t = 0.1 * k
        world.publish(t)
        deadline = math.inf if k < 3 else t - 1.0  # the last period is over before it starts
        pack.tick(lambda t=t: t, lambda t=t: WALL + t, deadline)
        world._move(0.1)
        world.round += 1
    assert calls["filter"] > 0 and calls["hold"] == n  # the safety filter ran, all held once
    assert pack.spent == {phase: costs[phase] * calls[phase] for phase in PHASES}
