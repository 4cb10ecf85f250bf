"""Fault injection in an agent: seeded loss and delay of the positions it receives, and
control steps that take longer than the machine needs (a starved process)."""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

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


def delay_steps(
    brains: Iterable[Any], delay: float, sleep: Callable[[float], None] = time.sleep
) -> None:
    """Make every control tick of each of ``brains`` (covswarm.agent.brain.AgentBrain) take
    ``delay`` s more of wall time: a sleep after the tick, before its actions are carried
    out (``covswarm agent --fault-step-delay``).

    An artificially starved process (issue 24, item 4): a process of K brains at R Hz holds
    about 1 / (R * delay) of its K steps per period, as on an overloaded machine, but the
    sleep loads no core, so the test of graceful overload does not depend on the machine's
    speed or on the other processes running.
    """
    if not (math.isfinite(delay) and delay >= 0.0):
        raise ValueError(f"the step delay must be >= 0 s, got {delay!r}")
    if delay == 0.0:
        return
    for brain in brains:
        tick = brain.tick

        def slow(now: float, now_wall: float, tick: Callable = tick) -> Any:
            actions = tick(now, now_wall)
            sleep(delay)
            return actions

        brain.tick = slow
