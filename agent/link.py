"""The Zenoh side of one agent: its subscriptions, publishers, and the actions of its brain.

Subscribers (liveliness included) use ring channels that the main loop polls once per
tick (:class:`Inbox`), so no Python callback thread exists; all decoding and math happen in
the main loop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import zenoh

from covswarm import protocol
from covswarm.agent.brain import (
    Action,
    AgentBrain,
    DeclareAlive,
    FollowStates,
    FollowTiles,
    PublishBeacon,
    PublishState,
    SendCommand,
)
from covswarm.agent.decoding import DECODE_CACHE
from covswarm.agent.faults import InboxItem, PoseImpairment

# Samples kept per subscriber between two ticks: only the newest per key is used, but a
# beacon tile carries one key per robot in it.
RING_PER_KEY = 4
# The domain's ring, every sample of which is delivered (Inbox ``every``): a forger that
# puts right after each real broadcast must not make it vanish by coalescing (issue 21: the
# agents then never saw a running domain). 16 holds 8 ticks' worth of a 20 Hz coordinator
# at 10 Hz plus forgeries; only a flood beyond it can push the real ones out.
DOMAIN_RING = 16
RING_PER_TILE = 256
# Token changes kept between two ticks: a ring never blocks Zenoh's threads, and only a
# whole team starting at once (two tokens per robot) comes near it.
LIVELINESS_RING = 8192


class RingSource(Protocol):
    def try_recv(self) -> zenoh.Sample | None: ...


class Inbox:
    """Newest payload per key from polled Zenoh ring channels, drained by the main loop.

    Every subscriber gets a ring-channel handler that the main loop empties once per tick:
    no Python thread per subscriber (a Python callback gets one, and 1000 agents of ~30
    subscribers each exhaust the kernel's threads) and no GIL taken on Zenoh's threads. A
    newer payload on a key replaces an unprocessed older one (latest-value semantics; the
    replaced ones are counted as coalesced).

    A source subscribed to one key (``wildcard=False``) needs no key handling at all: its
    newest sample is the key's, and the id in its key is known when subscribing; with
    ``every``, all its queued samples are delivered in order instead (the domain: which
    of them to believe is the brain's to judge, not the newest's). A
    wildcard source (a beacon tile) holds many keys, each parsed once with ``parse``.
    """

    def __init__(self, parse: Callable[[str, str], int] | None = None) -> None:
        self._sources: dict[int, tuple[str, RingSource, int | None, bool, bool]] = {}
        self._parse = parse
        self._ids: dict[str, int | None] = {}  # wildcard sample key -> id (None: malformed)

    def add(
        self,
        kind: str,
        source: RingSource,
        key_id: int | None = None,
        wildcard: bool = False,
        every: bool = False,
    ) -> None:
        """Poll ``source`` (anything with ``try_recv() -> Sample | None``) as ``kind``;
        ``key_id``: the id in its one key (None for the domain)."""
        self._sources[id(source)] = (kind, source, key_id, wildcard, every)

    def remove(self, source: RingSource) -> None:
        self._sources.pop(id(source), None)

    def subscribe(
        self,
        session: zenoh.Session,
        key: str,
        kind: str,
        capacity: int,
        key_id: int | None = None,
        wildcard: bool = False,
        every: bool = False,
    ) -> zenoh.Subscriber:
        """Declare a ring-channel subscriber on ``key`` and poll it as ``kind``."""
        subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        self.add(kind, subscriber, key_id, wildcard, every)
        return subscriber

    def drain(self) -> tuple[list[InboxItem], int, int]:
        """([(kind, key id, payload)], payloads coalesced, samples on malformed keys)."""
        out: list[InboxItem] = []
        coalesced = malformed = 0
        for kind, source, key_id, wildcard, every in self._sources.values():
            if every:
                while (sample := source.try_recv()) is not None:
                    out.append((kind, key_id, sample.payload.to_bytes()))
                continue
            if not wildcard:
                last = None
                while (sample := source.try_recv()) is not None:
                    coalesced += last is not None
                    last = sample
                if last is not None:
                    out.append((kind, key_id, last.payload.to_bytes()))
                continue
            latest: dict[str, bytes] = {}
            while (sample := source.try_recv()) is not None:
                key = str(sample.key_expr)
                coalesced += key in latest
                latest[key] = sample.payload.to_bytes()
            for key, payload in latest.items():
                if (rid := self._key_id(kind, key)) is None:
                    malformed += 1
                else:
                    out.append((kind, rid, payload))
        return out, coalesced, malformed

    def _key_id(self, kind: str, key: str) -> int | None:
        if key not in self._ids:
            if len(self._ids) >= DECODE_CACHE:  # bounded: tiles see robots come and go
                self._ids.clear()
            try:
                self._ids[key] = None if self._parse is None else self._parse(key, kind)
            except ValueError:
                self._ids[key] = None
        return self._ids[key]


class Subscriptions:
    """Per-key subscribers of one kind, reconciled with a wanted set of ids (or tiles).

    capacity: samples each ring keeps between ticks (newest first): a pose key gets two
    per 10 Hz tick, a beacon tile one per robot in it per second. ``key_of`` builds the key
    of an id; keys are only built, and subscribers only declared, for what changed.
    """

    def __init__(
        self,
        session: zenoh.Session,
        inbox: Inbox,
        kind: str,
        capacity: int,
        key_of: Callable[[Any], str],
        wildcard: bool = False,
    ) -> None:
        self._session = session
        self._inbox = inbox
        self._kind = kind
        self._capacity = capacity
        self._key_of = key_of
        self._wildcard = wildcard
        self._subscribers: dict[Any, zenoh.Subscriber] = {}

    def update(self, wanted: set[Any]) -> None:
        if wanted == self._subscribers.keys():
            return  # the usual tick: nothing changed
        for item in self._subscribers.keys() - wanted:
            subscriber = self._subscribers.pop(item)
            self._inbox.remove(subscriber)
            subscriber.undeclare()
        for item in wanted - self._subscribers.keys():
            self._subscribers[item] = self._inbox.subscribe(
                self._session,
                self._key_of(item),
                self._kind,
                self._capacity,
                None if self._wildcard else item,
                self._wildcard,
            )

    def __len__(self) -> int:
        return len(self._subscribers)


class AgentLink:
    """The Zenoh side of one agent: its publishers and its changing subscriptions."""

    def __init__(self, session: zenoh.Session, swarm: str, brain: AgentBrain) -> None:
        self.session, self.swarm, self.brain = session, swarm, brain
        self.inbox = Inbox(lambda key, kind: protocol.parse_id(key, swarm, kind))
        drop = zenoh.CongestionControl.DROP
        self.cmd_pub = session.declare_publisher(
            protocol.cmd_key(swarm, brain.id), congestion_control=drop
        )
        self.state_pub = session.declare_publisher(
            protocol.agent_state_key(swarm, brain.id), congestion_control=drop
        )
        self.inbox.subscribe(session, protocol.domain_key(swarm), "domain", DOMAIN_RING, every=True)
        self.inbox.subscribe(
            session, protocol.pose_key(swarm, brain.id), "pose", RING_PER_KEY, brain.id
        )
        # The arena, repeated every second by the coordinator: the newest is enough.
        self.inbox.subscribe(session, protocol.world_key(swarm), "world", RING_PER_KEY)
        self.states = Subscriptions(
            session, self.inbox, "state", RING_PER_KEY, lambda r: protocol.agent_state_key(swarm, r)
        )
        self.tiles = Subscriptions(
            session,
            self.inbox,
            "beacon",
            RING_PER_TILE,
            lambda tile: protocol.beacon_tile_selector(swarm, *tile),
            wildcard=True,
        )
        # Token changes of every agent and robot: rare events (one sample per process that
        # starts or dies), and they let a dead teammate leave the diagram at once instead of
        # after the staleness timeouts. No history: only changes from now on matter. Polled
        # like the data: a Python callback would get a thread of its own, and those threads
        # (one per brain) take the GIL from the main loop whenever a put releases it: puts
        # then took 0.4 ms on average, 5 to 15 ms at p99 (the GIL switch interval).
        self._delete = zenoh.SampleKind.DELETE
        self._liveliness = session.liveliness().declare_subscriber(
            protocol.alive_selector(swarm), zenoh.handlers.RingChannel(LIVELINESS_RING)
        )
        self.token: zenoh.LivelinessToken | None = None
        config = brain.config
        self.impairment = (
            PoseImpairment(
                config.pose_loss,
                config.pose_delay,
                np.random.default_rng([config.pose_seed, brain.id]),
            )
            if config.pose_loss > 0.0 or config.pose_delay > 0.0
            else None
        )

    def receive(self, now: float, wall: float) -> None:
        """Hand everything that arrived since the last tick to the brain."""
        items, coalesced, malformed = self.inbox.drain()
        self.brain.counters.coalesced += coalesced
        for _ in range(malformed):
            self.brain.drops.drop("wrong_id", "a beacon on a malformed key")
        if self.impairment is not None:
            items = self.impairment.filter(items, now)
        for kind, key_id, payload in items:
            self.brain.receive(kind, payload, now, wall, key_id)
        # After the data: a last message from a process that has just died must not revive it.
        while (sample := self._liveliness.try_recv()) is not None:
            try:
                role, rid = protocol.parse_alive_key(str(sample.key_expr), self.swarm)
            except ValueError:
                continue  # not a key of ours; nothing to count it against
            self.brain.on_liveliness(role, rid, sample.kind != self._delete)

    def carry_out(self, action: Action) -> None:
        """Do what the brain asked (see covswarm.agent.brain's actions)."""
        if isinstance(action, SendCommand):
            self.cmd_pub.put(action.command.encode())
        elif isinstance(action, PublishState):
            self.state_pub.put(action.state.encode())
        elif isinstance(action, PublishBeacon):
            key = protocol.beacon_key(self.swarm, *action.tile, self.brain.id)
            self.session.put(
                key, action.beacon.encode(), congestion_control=zenoh.CongestionControl.DROP
            )
        elif isinstance(action, FollowStates):
            self.states.update(set(action.ids))
        elif isinstance(action, FollowTiles):
            self.tiles.update(set(action.tiles))
        elif isinstance(action, DeclareAlive):
            # Tokens must stay referenced: zenoh undeclares a token when it is collected.
            alive = protocol.alive_key(self.swarm, "agent", self.brain.id)
            self.token = self.session.liveliness().declare_token(alive)
        else:
            raise TypeError(f"unknown action {action!r}")
