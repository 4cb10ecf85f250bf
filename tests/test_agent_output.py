"""What a brain sends after its step: the relay of its AgentState, built without a call per
entry, is what clamping every entry gives (same numbers, same signs of zero, NaN kept for
the message's check to refuse)."""

from __future__ import annotations

import math
import random

from covswarm import protocol
from covswarm.agent.neighborhood import Neighborhood, clamp_position

B = protocol.MAX_COORD
EDGES = [
    0.0, -0.0, 1.5, -2.25, B, -B, math.nextafter(B, math.inf), math.nextafter(-B, -math.inf),
    math.nextafter(B, 0.0), 1e300, -1e300, math.inf, -math.inf, math.nan,
]  # fmt: skip


def test_the_relay_is_the_reckoned_first_hand_neighbours_clamped() -> None:
    rng = random.Random(5)
    for _ in range(300):
        nb = Neighborhood(0, 1.0, 10.0, 0.5)
        ids = rng.sample(range(1, 200), rng.randint(0, 90))  # past MAX_RELAY at times
        nb.reckoned = {
            rid: (rng.choice(EDGES), rng.choice(EDGES), rng.uniform(-1, 1), rng.uniform(-1, 1))
            for rid in ids
        }
        nb.first_hand = {rid for rid in ids if rng.random() < 0.8}
        nb.one_hop = frozenset(rid for rid in ids if rng.random() < 0.7) | {250}
        expected = [
            (rid, *clamp_position(*nb.reckoned[rid][:2]), *nb.reckoned[rid][2:])
            for rid in sorted(nb.one_hop & nb.first_hand)
        ][: protocol.MAX_RELAY]
        assert repr(nb.relay()) == repr(expected)
