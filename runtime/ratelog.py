"""Log lines that a flood could repeat, rate-limited per key, with a count of the rest.

A process that logs one warning per bad message logs as fast as an attacker sends (the
console logged refused POSTs at 270 KiB/s, issue 21). :class:`RateLog` lets at most
``burst`` lines per key through per ``interval`` seconds; the lines it suppresses are
counted per key, and the first line let through after suppression says how many were
suppressed since. ``suppressed`` is cumulative, for summaries at exit.

Keys are bounded too (``max_keys``): a flood of distinct keys (one per forged id) shares
one overflow key rather than growing the table without end.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

RATELOG_INTERVAL = 10.0  # s
RATELOG_BURST = 3  # lines per key per interval
RATELOG_MAX_KEYS = 256
OVERFLOW_KEY = "(other keys)"


class RateLog:
    """At most ``burst`` log lines per key per ``interval`` s; the rest counted.

    ``clock`` gives monotonic seconds (injected for tests).
    """

    def __init__(
        self,
        logger: logging.Logger,
        interval: float = RATELOG_INTERVAL,
        burst: int = RATELOG_BURST,
        max_keys: int = RATELOG_MAX_KEYS,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (interval > 0.0 and burst >= 1 and max_keys >= 1):
            raise ValueError(f"RateLog: interval {interval} > 0, burst {burst} >= 1 needed")
        self._logger, self._interval, self._burst = logger, interval, burst
        self._max_keys, self._clock = max_keys, clock
        # key -> (start of its window, lines logged in it, suppressed since the last line)
        self._windows: dict[str, tuple[float, int, int]] = {}
        self.suppressed: dict[str, int] = {}  # key -> lines suppressed in all

    def log(self, level: int, key: str, message: str, *args: object) -> bool:
        """Log ``message % args`` at ``level`` unless ``key`` used up its burst; True if
        logged."""
        if key not in self._windows and len(self._windows) >= self._max_keys:
            self._expire()
            if len(self._windows) >= self._max_keys:
                key = OVERFLOW_KEY
        now = self._clock()
        start, lines, pending = self._windows.get(key, (now, 0, 0))
        if now - start >= self._interval:
            start, lines = now, 0
        if lines >= self._burst:
            self._windows[key] = (start, lines, pending + 1)
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            return False
        self._windows[key] = (start, lines + 1, 0)
        if pending:
            message += f" ({pending} similar lines suppressed)"
        self._logger.log(level, message, *args)
        return True

    def warning(self, key: str, message: str, *args: object) -> bool:
        return self.log(logging.WARNING, key, message, *args)

    @property
    def total_suppressed(self) -> int:
        return sum(self.suppressed.values())

    def _expire(self) -> None:
        """Forget keys whose window ended with nothing suppressed in it."""
        now = self._clock()
        for key in [
            k
            for k, (start, _, pending) in self._windows.items()
            if now - start >= self._interval and not pending
        ]:
            del self._windows[key]
