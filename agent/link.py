"""The Zenoh side of a packed agent process: :class:`ZenohBus`, the bus of
:class:`covswarm.agent.pack.Pack`.

Subscribers (liveliness included) use ring channels that the main loop polls once per
tick, so no Python callback thread exists: a subscriber declared with a Python callable
gets a thread of its own (1000 brains of ~30 subscribers each exhausted the kernel's
threads), and those threads take the GIL from the main loop whenever a put releases it.
All decoding and math happen in the main loop.
"""

from __future__ import annotations

from collections.abc import Callable

import zenoh

# Token changes kept between two ticks: a ring never blocks Zenoh's threads, and only a
# whole team starting at once (two tokens per robot) comes near it.
LIVELINESS_RING = 8192


class _TokenChanges:
    """A liveliness subscriber's ring as (key, alive) changes."""

    def __init__(self, subscriber: zenoh.Subscriber) -> None:
        self._subscriber = subscriber
        self._delete = zenoh.SampleKind.DELETE

    def try_recv(self) -> tuple[str, bool] | None:
        sample = self._subscriber.try_recv()
        if sample is None:
            return None
        return str(sample.key_expr), sample.kind != self._delete


class ZenohBus:
    """covswarm.agent.pack.Bus over one Zenoh session (puts drop under congestion: a
    newer command or state follows within a period)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._drop = zenoh.CongestionControl.DROP

    def subscribe(self, key: str, capacity: int) -> zenoh.Subscriber:
        return self.session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))

    def unsubscribe(self, source: zenoh.Subscriber) -> None:
        source.undeclare()

    def publisher(self, key: str) -> Callable[[bytes], None]:
        return self.session.declare_publisher(key, congestion_control=self._drop).put

    def put(self, key: str, payload: bytes) -> None:
        self.session.put(key, payload, congestion_control=self._drop)

    def declare_token(self, key: str) -> zenoh.LivelinessToken:
        return self.session.liveliness().declare_token(key)

    def liveliness(self, selector: str) -> _TokenChanges:
        # With history: the tokens alive now come first, as appearances. Without it, a
        # token being declared while the subscriber was (a team starting in waves) was
        # sometimes never undeclared to it when its process was killed: one agent in ~60 of
        # test_faults' dead-robot test kept naming the dead robot until its data went stale
        # (2 s), against none in 54 with history (30 Nov 2026, docs/faults.md).
        return _TokenChanges(
            self.session.liveliness().declare_subscriber(
                selector, zenoh.handlers.RingChannel(LIVELINESS_RING), history=True
            )
        )
