"""Receiver-side policy for inbound messages: clock checks and drop accounting.

Clock policy. Every message carries ``stamp`` (s since the epoch, the sender's wall clock).
A receiver drops and counts a message stamped

- more than ``max_skew`` s ahead of its own wall clock ("stamp_future"): a sender with a
  broken clock (or a forged stamp) must not pin a receiver to it; a Domain stamped in the
  future would otherwise make every later, correct Domain look out of date;
- more than ``max_age + max_skew`` s behind it ("stamp_old"): data older than the
  receiver's staleness timeout would be thrown away on arrival anyway, and acting on it
  (a delayed wheel command, a position from seconds ago) is worse than acting on nothing.

``max_skew`` (default MAX_CLOCK_SKEW) is the clock disagreement tolerated between machines;
processes on one machine share a clock. Staleness *after* acceptance is still measured on
the receiver's monotonic clock from receipt, so it does not depend on the sender's clock.

Drop accounting. :class:`DropLog` counts drops per reason (ProtocolError reasons plus the
receiver's own) and logs them rate-limited: the first drop at once, then at most one
summary line per ``interval``, so a flood of bad input cannot flood the log or slow the
process down with logging.

Import-light (stdlib only): robot processes import it.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable

from covswarm.protocol.messages import REASONS, ProtocolError, WheelCommand

MAX_CLOCK_SKEW = 0.5  # s; NTP keeps machines within milliseconds, one machine shares a clock
LOG_INTERVAL = 10.0  # s between two drop summaries in the log
STAMP_REASONS = ("stamp_future", "stamp_old")  # ProtocolError reasons of check_stamp
# Why a robot (simulated or bridged) drops a wheel command: :func:`accept_command`.
COMMAND_REASONS = (*REASONS, *STAMP_REASONS, "wrong_id")


def check_stamp(stamp: float, now_wall: float, max_age: float, max_skew: float) -> None:
    """Raise ProtocolError ("stamp_future" or "stamp_old") if ``stamp`` is out of policy."""
    if stamp > now_wall + max_skew:
        raise ProtocolError(
            f"stamp {stamp - now_wall:.3f} s ahead of this clock (limit {max_skew} s)",
            "stamp_future",
        )
    if stamp < now_wall - max_age - max_skew:
        raise ProtocolError(
            f"stamp {now_wall - stamp:.3f} s old (limit {max_age + max_skew} s)", "stamp_old"
        )


def accept_command(
    payload: object,
    robot_id: int,
    now_wall: float,
    max_age: float,
    max_skew: float,
    drops: DropLog,
) -> WheelCommand | None:
    """Decode a raw WheelCommand for robot ``robot_id`` and apply the clock policy.

    ``now_wall``: the receiver's wall clock (s since the epoch); ``max_age``: its command
    timeout (s); ``max_skew``: the clock disagreement tolerated (s). Returns the command, or
    None after counting the drop in ``drops`` (a ProtocolError reason, a STAMP_REASONS one,
    or "wrong_id" for a command addressed to another robot). Every robot process (the
    simulated robot, the ROS 2 bridge) uses it, so a command one would drive on the other
    would too.
    """
    try:
        command = WheelCommand.decode(payload)
        check_stamp(command.stamp, now_wall, max_age, max_skew)
    except ProtocolError as exc:
        drops.drop(exc.reason, f"command: {exc}")
        return None
    if command.id != robot_id:
        drops.drop("wrong_id", f"command for robot {command.id}")
        return None
    return command


class RateLimit:
    """True at most once per ``interval`` seconds: for log lines that could repeat per tick."""

    def __init__(
        self, interval: float = LOG_INTERVAL, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._interval, self._clock = interval, clock
        self._next = -math.inf

    def ready(self) -> bool:
        now = self._clock()
        if now < self._next:
            return False
        self._next = now + self._interval
        return True


class DropLog:
    """Per-reason counts of dropped input, logged at most once per ``interval`` seconds.

    ``counts`` starts with every name in ``reasons`` at zero so that reports have a stable
    set of keys; an unforeseen reason is counted too. Drops that arrive after the last
    summary are reported with the next drop after ``interval``, and in full by
    :meth:`summary` (processes log it at exit).
    """

    def __init__(
        self,
        logger: logging.Logger,
        who: str,
        reasons: Iterable[str],
        interval: float = LOG_INTERVAL,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.counts: dict[str, int] = dict.fromkeys(reasons, 0)
        self._logger, self._who = logger, who
        self._limit = RateLimit(interval, clock)
        self._pending: dict[str, int] = {}

    def drop(self, reason: str, detail: str) -> None:
        """Count one dropped input; log a summary if the last one is ``interval`` old."""
        self.counts[reason] = self.counts.get(reason, 0) + 1
        self._pending[reason] = self._pending.get(reason, 0) + 1
        if not self._limit.ready():
            return
        pending = ", ".join(f"{n} {r}" for r, n in sorted(self._pending.items()))
        self._pending = {}
        self._logger.warning("%s dropped input (%s); latest: %s", self._who, pending, detail)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> str:
        """Every non-zero count, e.g. "3 nonfinite, 1 stamp_old" (or "none")."""
        return ", ".join(f"{n} {r}" for r, n in sorted(self.counts.items()) if n) or "none"
