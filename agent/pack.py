"""A packed agent process: many brains that hear once (issue 24), sans-IO.

The brains of one process (``covswarm agent --ids``) share one subscription per key: the
domain is subscribed once for all of them, each AgentState, pose and beacon tile once per
process with the set of brains that follow it (its reference count: the subscription is
undeclared when the last one stops following). Each sample is drained once per control
tick (a brain's own pose right before its turn) and handed to every brain that follows the
key as the same :class:`~covswarm.agent.decoding.Heard` (its bytes, decoded and validated
once for the process when a follower first reads it, into the message or the ProtocolError
it raised): a brain looks nothing up. A brain still receives only the keys it follows
itself, newest payload per key (the newest DOMAIN_RING domains), in a canonical order
(kind, id, key): what it would receive in a process of its own (tests/test_pack.py).
Liveliness token changes are recorded once for the process
(covswarm.agent.neighborhood.Liveliness), not once per brain; each brain takes them as
applied after its turn's data, as a process of its own would.

Brains due together step together (:meth:`Pack.step`): ``chunk`` at a time, at one clock
reading, each brain's step split in phases (AgentBrain.begin, the local steps of the
chunk in one batched call per law and feedforward, AgentBrain.conclude). The deadline is
checked before each brain begins its step, so it stays per brain.

Overload (issue 24, item 4): a brain whose turn comes after the end of the period it was
to step for does not step on that period's inputs as if they were fresh: it skips the
period, and the next tick starts with it. Its robot runs on the command of its last step
(as at a lower rate: the gain is sampled for the period actually held,
covswarm.agent.brain.sampled_gain) until that step is older than ``hold_after`` (three
periods in ``covswarm agent``) and than the hold its command was computed for; then the
brain commands (0, 0) once and says so in an AgentState of velocity 0
(:meth:`AgentBrain.hold`: the robot stops rather than overshoot). A process that
cannot hold K steps per period thus steps its brains in turn at the rate it can hold, and
each brain's ``rate_hz`` and ``late_held`` (the fraction of the mission's periods skipped)
stats say so. Its neighbours' brains then publish at that rate too: each brain is told the
time since its last turn and judges their states by it (:meth:`AgentBrain.pace`).

The bus (:class:`Bus`) is Zenoh in a live process (:class:`covswarm.agent.link.ZenohBus`)
and :class:`LocalBus`, an in-memory router, in tests and ``covswarm bench --brain-tick``.
"""

from __future__ import annotations

import gc
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from covswarm import protocol
from covswarm.agent.brain import (
    Action,
    AgentBrain,
    Begun,
    Decision,
    DeclareAlive,
    Filtering,
    FollowStates,
    FollowStranded,
    FollowTiles,
    PublishBeacon,
    PublishState,
    SafeVelocity,
    SendCommand,
    filter_all,
    filter_one,
    local_step_of,
)
from covswarm.agent.decoding import DECODE_CACHE, heard
from covswarm.agent.faults import InboxItem, PoseImpairment
from covswarm.agent.neighborhood import Liveliness
from covswarm.tvd.control import MAX_AMPLIFICATION, LocalStep, local_steps

log = logging.getLogger("covswarm.agent")

# Allocations (net) before a collection of the youngest generation in a process of packed
# brains. At Python's 700 one runs every few brains, every 10th goes on to the middle
# generation and every 100th to the oldest, which holds every brain's tables: ~15 % of a
# 500-brain tick (covswarm bench --brain-tick, 08:50 UTC 2026-11-27). Most of the brains'
# garbage is freed by reference counting anyway; the collector only finds cycles.
# CPython counts allocations minus frees (never below 0): in a steady pack of 500 brains
# the count hovers at 20-27 thousand (a brain's tables are rebuilt as the old ones are
# freed), so at 10 000 it was crossed every ~3 ticks, and each young collection then walked
# what had been allocated since and still lived, nearly every brain's state: 63 ms of CPU
# each, ~45 us per brain-tick (17:06 UTC 2026-11-27, gc.callbacks, load 4.9). At 100 000
# none ran in 375 ticks; the count grows only with what stays alive (caches filling up)
# and with unreachable cycles, which it still bounds.
GC_YOUNG_THRESHOLD = 100_000


def collect_less() -> tuple[int, int, int]:
    """Collect garbage less often (GC_YOUNG_THRESHOLD) in this process; returns the
    previous thresholds (for gc.set_threshold)."""
    previous = gc.get_threshold()
    gc.set_threshold(GC_YOUNG_THRESHOLD, *previous[1:])
    return previous


# Samples kept per subscriber between two ticks: only the newest per key is used, but a
# beacon tile carries one key per robot in it.
RING_PER_KEY = 4
RING_PER_TILE = 256
# The domain's ring, every sample of which is handed on in order (not only the newest): a
# forger that puts right after each real broadcast must not make it vanish by coalescing
# (issue 21: the agents then never saw a running domain); which to believe is the brain's
# to judge. 16 holds 8 ticks' worth of a 20 Hz coordinator at 10 Hz plus forgeries; only a
# flood beyond it can push the real ones out.
DOMAIN_RING = 16
# Brains stepped together: their local steps in one batch, and their safety filters in
# another. 64 was measured against 32 (covswarm bench --brain-tick at the circle scenarios'
# 0.2 m spacing, 14:55 UTC 2026-11-27, load 1.0): 441-468 -> 499-534 us of CPU per brain-tick
# in packs of 50 (one chunk of 50 rather than 32 + 18), 394 -> 400 in packs of 500; and a
# chunk's commands go out once all of it has stepped, later in the period.
CHUNK = 32
# The phases of a packed process's tick whose clock time it adds up (Pack.spent): what a
# brain-tick costs, split without a profiler (covswarm bench --brain-tick). "drain": taking
# the tick's samples off the bus; "receive": a brain's payloads handed over and applied
# (decoding, shared per process, included); "begin": its neighbourhood reckoned and its
# local view built; "local steps" and "filter": its share of the chunk's batched local steps
# and safety filters (the math); "conclude": the step's bookkeeping between the two;
# "actions": its command, AgentState, beacon and follows, encoded and put; "hold": a brain
# whose turn came after its period ended (Pack._hold).
PHASES = ("drain", "receive", "begin", "local steps", "conclude", "filter", "actions", "hold")
# The order in which a brain gets a tick's payloads (then by id and key): the world (the
# domain is judged against it), the domain and its own pose first, as a process of its own
# drained its subscribers.
KIND_ORDER = {"world": 0, "domain": 1, "pose": 2, "state": 3, "beacon": 4, "stranded": 5}

# Where a payload waits for a brain: the KIND_ORDER of its kind, 1 + the id in its key (0
# for none) in ID_DIGITS digits, then the key; one per key (per key and id in a beacon
# tile, per sample for the domain). Sorted as they are, the slots give a brain its payloads
# in the canonical order, without a sort key; as strings, not (kind, id, key) tuples, since
# a string's hash is kept and strings sort by a plain comparison: a brain's ~19 slots a
# tick, hashed twice each and sorted, took half the time (9 500 a tick in 500 brains).
_Slot = str
ID_DIGITS = len(str(protocol.MAX_ID + 1))
_KEY_AT = 1 + ID_DIGITS  # where the key starts in a slot
# brain -> {slot: (kind, id, payload)}: the newest payload per key for a brain
_Queues = dict[int, dict[_Slot, InboxItem]]


def _slot(kind: str, key_id: int | None, key: str) -> _Slot:
    return f"{KIND_ORDER[kind]}{0 if key_id is None else key_id + 1:0{ID_DIGITS}d}{key}"


class Payload(Protocol):
    def to_bytes(self) -> bytes: ...


class Sample(Protocol):
    key_expr: Any  # str(key_expr) is the key
    payload: Payload


class Source(Protocol):
    def try_recv(self) -> Any: ...


class Bus(Protocol):
    """What a packed process needs of its middleware (Zenoh, or :class:`LocalBus`)."""

    def subscribe(self, key: str, capacity: int) -> Source:
        """A ring of ``capacity`` samples on ``key`` (a ``*`` chunk matches any)."""

    def unsubscribe(self, source: Source) -> None: ...

    def publisher(self, key: str) -> Callable[[bytes], None]: ...

    def put(self, key: str, payload: bytes) -> None: ...

    def declare_token(self, key: str) -> Any:
        """A liveliness token that lives while referenced."""

    def liveliness(self, selector: str) -> Source:
        """Token changes matching ``selector``: ``try_recv() -> (key, alive) | None``."""


@dataclass
class _Subscription:
    kind: str
    key_id: int | None  # the id in its key; None for the domain and wildcard tiles
    wildcard: bool
    source: Source
    slot: _Slot  # where its payloads wait (a single key's; a tile's slots are per id)
    followers: set[int] = field(default_factory=set)


class Pack:
    """The brains of one process over one bus: one subscription per key, payloads handed
    to every brain that follows the key.

    ``drain()`` once per control tick; then, a chunk at a time, ``take_own_poses()`` (its
    robots' poses, taken off the bus only then, so the last of a batch controls from its
    robot's newest pose), each brain's ``receive()`` at a clock read after that,
    ``brain.tick()`` and ``carry_out()``; :meth:`tick` does all that with the overload rule
    of the module docstring.
    """

    def __init__(
        self,
        bus: Bus,
        swarm: str,
        brains: list[AgentBrain],
        hold_after: float = 0.3,
        chunk: int = CHUNK,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        if len({brain.id for brain in brains}) != len(brains):
            raise ValueError("a packed process cannot host one id twice")
        if not hold_after > 0.0:
            raise ValueError(f"hold_after must be positive, got {hold_after!r}")
        if chunk < 1:
            raise ValueError(f"chunk must be at least 1, got {chunk!r}")
        self.hold_after, self.chunk = hold_after, chunk
        # Times the batched local steps and filters (the brains' step timers) and the phases.
        self._clock = clock
        self.spent = dict.fromkeys(PHASES, 0.0)  # s of ``clock`` in each phase, all ticks
        self._stepped: dict[int, float] = {}  # brain -> clock of its last turn
        self.bus, self.swarm = bus, swarm
        self.brains = {brain.id: brain for brain in brains}
        self.order = [brain.id for brain in brains]  # stepping order, rotated every tick
        self.tokens: dict[int, Any] = {}
        self._subs: dict[str, _Subscription] = {}
        self._follows: dict[int, dict[str, frozenset]] = {
            bid: {"state": frozenset(), "beacon": frozenset(), "stranded": frozenset()}
            for bid in self.brains
        }
        # brain -> {(key, id): (kind, id, payload)}: newest per key since its last turn
        self._pending: _Queues = {bid: {} for bid in self.brains}
        # the same, taken out of a ring between two drains: theirs from the next drain on
        self._later: _Queues = {bid: {} for bid in self.brains}
        # Token changes, recorded once for the process; each brain catches up on its turn.
        self.liveliness = Liveliness()
        for brain in brains:
            brain.stop_after = hold_after  # its commands are planned for the stop (_hold)
            brain.neighborhood.share(self.liveliness)
        self._key_id = protocol.KeyIds(swarm, "beacon", DECODE_CACHE)  # a tile's sample keys
        self._every = 0  # samples queued one by one (the domain's), numbering their slots
        self._recent_domains: deque[_Slot] = deque()  # their newest slots, oldest first
        self._held: set[int] = set()  # brains whose last command was a hold
        self._cmd = {bid: bus.publisher(protocol.cmd_key(swarm, bid)) for bid in self.brains}
        self._state = {
            bid: bus.publisher(protocol.agent_state_key(swarm, bid)) for bid in self.brains
        }
        self._own_pose = {bid: protocol.pose_key(swarm, bid) for bid in self.brains}
        self._follow(set(self.brains), protocol.world_key(swarm), "world", None, False)
        self._follow(set(self.brains), protocol.domain_key(swarm), "domain", None, False)
        for bid, key in self._own_pose.items():
            self._follow({bid}, key, "pose", bid, False)
        # Token changes of every agent and robot (rare): a dead teammate leaves the
        # diagrams at once instead of after the staleness timeouts.
        self._token_changes = bus.liveliness(protocol.alive_selector(swarm))
        self._impairment = {
            bid: PoseImpairment(
                brain.config.pose_loss,
                brain.config.pose_delay,
                np.random.default_rng([brain.config.pose_seed, bid]),
            )
            for bid, brain in self.brains.items()
            if brain.config.pose_loss > 0.0 or brain.config.pose_delay > 0.0
        }

    # --- subscriptions -------------------------------------------------------------------

    @property
    def subscriptions(self) -> int:
        """Subscriptions this process holds (liveliness aside)."""
        return len(self._subs)

    def followers(self, key: str) -> frozenset[int]:
        """The brains that follow ``key`` (its reference count is their number)."""
        sub = self._subs.get(key)
        return frozenset(sub.followers) if sub is not None else frozenset()

    def _follow(
        self, brains: set[int], key: str, kind: str, key_id: int | None, wildcard: bool
    ) -> None:
        sub = self._subs.get(key)
        if sub is None:
            capacity = RING_PER_TILE if wildcard else RING_PER_KEY
            capacity = DOMAIN_RING if kind == "domain" else capacity
            source = self.bus.subscribe(key, capacity)
            sub = _Subscription(kind, key_id, wildcard, source, _slot(kind, key_id, key))
            self._subs[key] = sub
        else:
            # What arrived before these brains followed the key is not theirs (a subscriber
            # of their own would not have had it): the followers so far get it, with the
            # next drain (as from their own rings), the newcomers do not.
            self._drain_subscription(key, sub, self._later)
        sub.followers |= brains

    def _unfollow(self, bid: int, key: str) -> None:
        sub = self._subs[key]
        sub.followers.discard(bid)
        if not sub.followers:
            del self._subs[key]
            self.bus.unsubscribe(sub.source)
        # Unread payloads of an undeclared subscriber are lost to a process of its own too:
        # those queued for its next turn, and those set aside for it when a teammate began
        # following the key earlier in this tick (_follow).
        for queue in (self._pending[bid], self._later[bid]):
            for slot in [slot for slot in queue if slot[_KEY_AT:] == key]:
                del queue[slot]

    def follow(self, bid: int, kind: str, wanted: frozenset) -> None:
        """Brain ``bid`` follows exactly ``wanted``: robot ids (kind "state": their
        AgentStates; "stranded": their robots' poses) or tiles ("beacon")."""
        follows = self._follows[bid]
        held = follows[kind]
        if wanted is held or wanted == held:
            return  # the usual tick: nothing changed (often the very same set)
        for item in held - wanted:
            self._unfollow(bid, self._key(kind, item))
        for item in wanted - held:
            wildcard = kind == "beacon"
            self._follow({bid}, self._key(kind, item), kind, None if wildcard else item, wildcard)
        follows[kind] = wanted

    def _key(self, kind: str, item: Any) -> str:
        if kind == "state":
            return protocol.agent_state_key(self.swarm, item)
        if kind == "stranded":
            return protocol.pose_key(self.swarm, item)
        return protocol.beacon_tile_selector(self.swarm, *item)

    # --- input ---------------------------------------------------------------------------

    def drain(self) -> None:
        """Take everything that arrived since the last drain, once for the whole process,
        and queue each payload for every brain that follows its key; but the brains' own
        robots' poses, which :meth:`take_own_poses` takes right before their turns (their
        rings keep the newest): in an overloaded process most brains skip the tick.

        Token changes before the data: a payload that reached the process before a change
        (the last state of a process that has just died) is then drained in the same tick
        and applied before its brain catches up on the change (:meth:`receive`). Drained
        after the data, one that landed in between was applied at the brain's next turn,
        as news heard after the deletion, and revived the dead process until it went stale
        (tests/test_liveliness_race.py)."""
        # What every brain has caught up on is not needed any more (their marks read only
        # when there is something to forget: a pass over every brain each tick, 2 % of an
        # overloaded pack's samples, scripts/brain_tick_profile.py --late 7, 30 Nov 2026).
        if self.liveliness.kept:
            self.liveliness.trim(min(brain.neighborhood.mark for brain in self.brains.values()))
        while (change := self._token_changes.try_recv()) is not None:
            try:
                role, rid = protocol.parse_alive_key(change[0], self.swarm)
            except ValueError:
                continue  # not a key of ours; nothing to count it against
            self.liveliness.change(role, rid, change[1])
        for bid, later in self._later.items():
            if later:
                pending = self._pending[bid]
                self.brains[bid].counters.coalesced += len(later.keys() & pending.keys())
                pending.update(later)
                later.clear()
        for key, sub in self._subs.items():
            if sub.kind != "pose":
                self._drain_subscription(key, sub, self._pending)

    def _drain_subscription(self, key: str, sub: _Subscription, queues: _Queues) -> None:
        """Queue what ``sub`` holds for its followers in ``queues``: its newest sample (one
        key), or the newest per key in it (a beacon tile)."""
        if not sub.wildcard:
            self._drain_key(key, sub, queues)
            return
        latest: dict[str, bytes] = {}
        coalesced = 0
        while (sample := sub.source.try_recv()) is not None:
            skey = str(sample.key_expr)
            coalesced += skey in latest
            latest[skey] = sample.payload.to_bytes()
        if not latest:
            return
        malformed = 0
        items = []
        for skey, payload in latest.items():
            if (rid := self._key_id(skey)) is None:
                malformed += 1
            else:
                items.append((_slot(sub.kind, rid, key), (sub.kind, rid, heard(sub.kind, payload))))
        for bid in sub.followers:
            brain = self.brains[bid]
            pending = queues[bid]
            for slot, item in items:
                brain.counters.coalesced += slot in pending
                pending[slot] = item
            brain.counters.coalesced += coalesced
            for _ in range(malformed):
                brain.drops.drop("wrong_id", "a beacon on a malformed key")

    def _drain_key(self, key: str, sub: _Subscription, queues: _Queues) -> None:
        if sub.kind == "domain":
            self._drain_every(key, sub, queues)
            return
        last = None
        coalesced = 0
        while (sample := sub.source.try_recv()) is not None:
            coalesced += last is not None
            last = sample
        if last is None:
            return
        slot = sub.slot
        item = (sub.kind, sub.key_id, heard(sub.kind, last.payload.to_bytes()))
        for bid in sub.followers:
            pending = queues[bid]
            unread = slot in pending  # rarely: one sample a tick, taken each tick
            if coalesced or unread:
                self.brains[bid].counters.coalesced += coalesced + unread
            pending[slot] = item

    def _drain_every(self, key: str, sub: _Subscription, queues: _Queues) -> None:
        """Queue every sample ``sub`` holds, in arrival order, each in a slot of its own
        (the slots sort in arrival order: same kind and id, increasing numbers); a brain
        keeps the newest DOMAIN_RING of them until its turn, as its own ring would.

        A brain whose turns come late (overload) was otherwise handed every sample since its
        last turn: ~30 domains a turn for 1000 robots on two cores at 0.7 Hz held, each
        checked and most refused as too old, a fifth of the agents' CPU (27 Nov 2026)."""
        recent = self._recent_domains
        while (sample := sub.source.try_recv()) is not None:
            self._every += 1
            slot = _slot(sub.kind, sub.key_id, f"{key}#{self._every:012d}")
            item = (sub.kind, sub.key_id, heard(sub.kind, sample.payload.to_bytes()))
            for bid in sub.followers:
                queues[bid][slot] = item
            recent.append(slot)
            if len(recent) > DOMAIN_RING:
                self._forget_slot(recent.popleft(), sub.followers)

    def _forget_slot(self, slot: _Slot, brains: set[int]) -> None:
        """Take ``slot`` out of the queues of ``brains`` (those that had it unread count it as
        coalesced)."""
        for bid in brains:
            unread = self._pending[bid].pop(slot, None) or self._later[bid].pop(slot, None)
            if unread is not None:
                self.brains[bid].counters.coalesced += 1

    def take_own_poses(self, bids: list[int]) -> None:
        """Queue the newest pose of each robot of ``bids`` for its brain (the last of a
        batch then controls from its robot's newest pose)."""
        for bid in bids:
            key = self._own_pose[bid]
            self._drain_key(key, self._subs[key], self._pending)

    def receive(self, bid: int, now: float, wall: float) -> None:
        """Hand brain ``bid`` everything queued for it since its last turn (in one call,
        AgentBrain.receive_all), then the token changes (after the data: a last message
        from a process that has just died must not revive it). ``now``, ``wall``: read
        after the payloads were taken off the bus (a brain takes them as its receipt times,
        covswarm.agent.latency)."""
        brain = self.brains[bid]
        pending = self._pending[bid]
        items = [pending[slot] for slot in sorted(pending)]
        pending.clear()
        impairment = self._impairment.get(bid)
        if impairment is not None:
            items = impairment.filter(items, now)
        brain.receive_all(items, now, wall)
        brain.catch_up()

    # --- output --------------------------------------------------------------------------

    def carry_out(self, bid: int, action: Action) -> None:
        """Do what brain ``bid`` asked (see covswarm.agent.brain's actions)."""
        # By exact type, in the order a tick asks (a command, a state, the follows): four
        # actions per brain and tick, without an isinstance call per test.
        kind = type(action)
        if kind is SendCommand:
            self._cmd[bid](action.command.encode())
        elif kind is PublishState:
            self._state[bid](action.state.encode())
        elif kind is FollowStates:
            self.follow(bid, "state", action.ids)
        elif kind is FollowTiles:
            self.follow(bid, "beacon", action.tiles)
        elif kind is FollowStranded:
            # Not our own brains' robots: their tokens live with this process.
            self.follow(bid, "stranded", frozenset(action.ids - self.brains.keys()))
        elif kind is PublishBeacon:
            self.bus.put(protocol.beacon_key(self.swarm, *action.tile, bid), action.beacon.encode())
        elif kind is DeclareAlive:
            # Tokens must stay referenced: zenoh undeclares a token when it is collected.
            self.tokens[bid] = self.bus.declare_token(protocol.alive_key(self.swarm, "agent", bid))
            log.info("agent %d ready in swarm %s", bid, self.swarm)
        else:
            raise TypeError(f"unknown action {action!r}")

    # --- the tick ------------------------------------------------------------------------

    def tick(self, clock: Callable[[], float], wall: Callable[[], float], deadline: float) -> int:
        """One control period of the whole process: :meth:`drain`, then :meth:`step`."""
        started = self._clock()
        self.drain()
        self.spent["drain"] += self._clock() - started
        return self.step(clock, wall, deadline)

    def step(self, clock: Callable[[], float], wall: Callable[[], float], deadline: float) -> int:
        """Each brain's turn of one period, in order, ``chunk`` brains at a time; the number
        of brains that stepped.

        ``clock``: the ticker's (monotonic, mission-scaled) clock, read when a chunk's turn
        comes: its brains step at that time together (they extrapolate the same domain to
        the same time, and the last chunk of a large process dead-reckons its neighbours to
        its own time); ``wall``: seconds since the epoch, likewise; ``deadline``: the end of
        this period on ``clock``, checked before each brain begins its step: a brain whose
        turn comes after it holds, and so do the brains after it (module docstring); the
        next tick starts with the first that held, or one brain later when all stepped, so
        no robot is always last.
        """
        stepped = 0
        order = self.order
        for first in range(0, len(order), self.chunk):
            chunk = order[first : first + self.chunk]
            if clock() > deadline:
                # The period is over before this chunk's turn: its brains hold, their robots'
                # poses left on the bus (a turn takes the newest; taken for brains that held,
                # they were 6.6 % of an overloaded pack's CPU: scripts/brain_tick_profile.py
                # --late 18, 28 Nov 2026).
                now, now_wall = clock(), wall()
                for bid in chunk:
                    self._hold(self.brains[bid], now, now_wall)
                continue
            stepped += self._step_chunk(chunk, clock, wall, deadline)
        shift = stepped if 0 < stepped < len(order) else 1
        self.order = order[shift:] + order[:shift]
        return stepped

    def _step_chunk(
        self,
        chunk: list[int],
        clock: Callable[[], float],
        wall: Callable[[], float],
        deadline: float,
    ) -> int:
        """The brains of ``chunk`` step at the time its turn comes: each receives its inputs
        and begins its step (those whose turn comes after the deadline hold instead), their
        local steps run batched (grouped by the law's settings), then each concludes and its
        actions are carried out. The number that stepped."""
        # Their newest poses first, then the chunk's clock: a receipt time read before the
        # payload was taken would precede it, and a pose stamped in between would read as a
        # robot clock running ahead of ours (ClockBound), so every later pose counted as
        # that much older: at 100 robots in packs of 32 on two loaded cores, -26 to -90 ms,
        # each robot predicted ~10 mm ahead of where it was.
        spent, timer = self.spent, self._clock
        started = timer()
        self.take_own_poses(chunk)
        now, now_wall = clock(), wall()
        brains = self.brains
        begun: dict[int, Begun] = {}
        filtering: dict[int, Filtering] = {}
        decisions: dict[int, Decision] = {}
        groups: dict[tuple[bool, str], list[int]] = {}
        beginning = 0.0
        holding = spent["hold"]
        for bid in chunk:
            brain = brains[bid]
            if clock() > deadline:
                self._hold(brain, clock(), wall())
                continue
            self._held.discard(bid)
            brain.pace(now - self._stepped.get(bid, now))
            self._stepped[bid] = now
            self.receive(bid, now, now_wall)
            began = timer()
            early = brain.begin(now, now_wall)
            beginning += timer() - began
            if type(early) is Begun:
                begun[bid] = early
                config = brain.config
                groups.setdefault((config.feedforward, config.law), []).append(bid)
            else:
                decisions[bid] = brain.settle(early)
        # The rest of the loop (poses taken, paces) counts as receiving; holds as holds.
        holding = spent["hold"] - holding
        spent["receive"] += timer() - started - beginning - holding
        spent["begin"] += beginning
        for (feedforward, law), bids in groups.items():
            started = timer()
            try:
                results: list[LocalStep | Exception] = list(
                    local_steps([begun[b].view for b in bids], feedforward, MAX_AMPLIFICATION, law)
                )
            except Exception:  # noqa: BLE001 -- one bad view: step them one by one
                results = [local_step_of(begun[b].view, brains[b].config) for b in bids]
                for bid in bids:
                    brains[bid].counters.batch_fallbacks += 1
            stepped = timer()
            spent["local steps"] += stepped - started
            shared = (stepped - started) / len(bids)
            for bid, result in zip(bids, results, strict=True):
                concluded = brains[bid].conclude(begun[bid], result, shared)
                if type(concluded) is Filtering:
                    filtering[bid] = concluded
                else:
                    decisions[bid] = concluded
            spent["conclude"] += timer() - stepped
        if filtering:
            self._filter(filtering, decisions)
        started = timer()
        for bid in [bid for bid in chunk if bid in decisions]:  # in turn order
            brain = brains[bid]
            for action in brain.actions(decisions[bid], now, now_wall):
                self.carry_out(bid, action)
                # A missed deadline: this period's command went out after the period ended
                # (start-up, while processes are still launching, aside).
                if type(action) is SendCommand and brain.running and clock() > deadline:
                    brain.counters.overruns += 1
        spent["actions"] += timer() - started
        return len(decisions)

    def _filter(self, filtering: dict[int, Filtering], decisions: dict[int, Decision]) -> None:
        """The safety filters of the brains of ``filtering`` in one batch, then their wheel
        speeds, into ``decisions``; a batch that raises is taken again one by one."""
        started = self._clock()
        try:
            safe: list[SafeVelocity | Exception] = list(filter_all(list(filtering.values())))
        except Exception:  # noqa: BLE001 -- one bad input: filter them one by one
            safe = [filter_one(f) for f in filtering.values()]
            for bid in filtering:
                self.brains[bid].counters.batch_fallbacks += 1
        filtered = self._clock()
        self.spent["filter"] += filtered - started
        shared = (filtered - started) / len(filtering)
        for (bid, inputs), answer in zip(filtering.items(), safe, strict=True):
            decisions[bid] = self.brains[bid].drive(inputs, answer, shared)
        self.spent["conclude"] += self._clock() - filtered

    def _hold(self, brain: AgentBrain, now: float, wall: float) -> None:
        """Brain's period is over before its turn: it skips this period (its robot runs on
        the command of its last step, as at a lower rate), and once that step is older
        than ``hold_after`` s and than the hold its command was computed for
        (AgentBrain.command_hold), stops its robot (once) rather than let it run on a
        command computed from inputs that old.

        Not before the command's own hold: a brain stepped every 0.6 s computes its gain,
        barrier and turn for 0.6 s (up to the robot's command timeout), and stopping its
        robot at ``hold_after`` (0.3 s at 10 Hz) drove it half as far as its step meant
        while the coordinator paced S by the steps held: the team fell behind S and its
        trailing robots out of it (scripts/held_commands.py: 100 agents at 1.67 Hz, S at a
        sixth of its speed, e_a's second half 1.78 m with robots stopped 0.3 s after each
        command, 0.53 m at 0.5 s, 0.019 m at 0.9 s; 28 Nov 2026)."""
        started = self._clock()
        try:
            self._hold_unless_stopped(brain, now, wall)
        finally:
            self.spent["hold"] += self._clock() - started

    def _hold_unless_stopped(self, brain: AgentBrain, now: float, wall: float) -> None:
        if not brain.running:
            # Before the mission a robot stands still or turns in place, on a command that
            # turns it no further than to face S's start however long it holds.
            return
        brain.counters.late += 1
        if brain.id in self._held:
            return  # stopped already: most of an overloaded pack's brains, most periods
        if now - self._stepped.get(brain.id, now) <= brain.runs_on_for(self.hold_after):
            return
        self._held.add(brain.id)
        for action in brain.hold(now, wall):
            self.carry_out(brain.id, action)

    def stop(self, wall: float) -> None:
        """Stop every robot at once (rather than after their command timeout)."""
        for bid, brain in self.brains.items():
            self.carry_out(bid, brain.stop(wall))


class _Ring:
    """A ring of samples as :class:`LocalBus` delivers them (newest kept)."""

    def __init__(self, capacity: int) -> None:
        self.samples: deque = deque(maxlen=capacity)

    def try_recv(self) -> Any:
        return self.samples.popleft() if self.samples else None


@dataclass(frozen=True)
class _Bytes:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass(frozen=True)
class LocalSample:
    key_expr: str
    payload: _Bytes


class LocalBus:
    """An in-memory bus with Zenoh's semantics for what a pack uses: exact keys, a ``*``
    last chunk, rings that keep the newest samples, liveliness tokens as (key, alive)
    changes. Subscribers see what is put after they subscribe; ``sent`` records every
    put, in order (key, payload)."""

    def __init__(self) -> None:
        self._exact: dict[str, list[_Ring]] = {}
        self._tiles: dict[str, list[_Ring]] = {}  # selector without its "*"
        self._alive: list[_Ring] = []
        self.sent: list[tuple[str, bytes]] = []

    def subscribe(self, key: str, capacity: int) -> _Ring:
        ring = _Ring(capacity)
        if key.endswith("/*"):
            self._tiles.setdefault(key[:-1], []).append(ring)
        else:
            self._exact.setdefault(key, []).append(ring)
        return ring

    def unsubscribe(self, source: Source) -> None:
        for table in (self._exact, self._tiles):
            for key, rings in list(table.items()):
                if source in rings:
                    rings.remove(source)
                    if not rings:
                        del table[key]
                    return

    def put(self, key: str, payload: bytes) -> None:
        self.sent.append((key, payload))
        sample = LocalSample(key, _Bytes(payload))
        for ring in self._exact.get(key, ()):
            ring.samples.append(sample)
        for ring in self._tiles.get(key[: key.rfind("/") + 1], ()):
            ring.samples.append(sample)

    def publisher(self, key: str) -> Callable[[bytes], None]:
        return lambda payload: self.put(key, payload)

    def declare_token(self, key: str) -> str:
        for ring in self._alive:
            ring.samples.append((key, True))
        return key

    def liveliness(self, selector: str) -> _Ring:
        ring = _Ring(8192)
        self._alive.append(ring)
        return ring
