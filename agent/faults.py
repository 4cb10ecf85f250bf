"""Fault injection in an agent: seeded loss and delay of the positions it receives."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

InboxItem = tuple[str, int | None, bytes]  # (kind, id in the key (None: domain), payload)
IMPAIRED = ("pose", "state")  # the kinds of message that carry a robot's position


class PoseImpairment:
    """Seeded loss and delay of received positions, between the inbox and the brain (pure).

    Impairs every message that carries a robot's position: its own robot's poses and the
    AgentStates its neighbours' positions come from. Applied to what the agent would
    consume each tick (after the inbox kept the newest message per key), so ``loss`` is the
    fraction of position updates the controller never sees. Delayed ones are handed over
    in arrival order once ``delay`` s have passed; their receipt time is then, so staleness
    counts from when the agent got them.
    """

    def __init__(self, loss: float, delay: float, rng: np.random.Generator) -> None:
        if not (0.0 <= loss < 1.0 and 0.0 <= delay and math.isfinite(delay)):
            raise ValueError(f"pose loss must be in [0, 1) and delay >= 0, got {loss}, {delay}")
        self.loss, self.delay, self._rng = loss, delay, rng
        self._queue: deque[tuple[float, InboxItem]] = deque()
        self.dropped = 0

    def filter(self, items: list[InboxItem], now: float) -> list[InboxItem]:
        """The items to process at ``now``: the others at once, positions that survived and
        are due."""
        out = [item for item in items if item[0] not in IMPAIRED]
        for item in items:
            if item[0] not in IMPAIRED:
                continue
            if self._rng.random() < self.loss:
                self.dropped += 1
            else:
                self._queue.append((now + self.delay, item))
        while self._queue and self._queue[0][0] <= now:
            out.append(self._queue.popleft()[1])
        return out
