"""Loop timing of a covswarm process: mission time, fixed-rate ticks, stopping on signals."""

from __future__ import annotations

import math
import signal
import time
from collections.abc import Callable


def scaled(clock: Callable[[], float], time_scale: float) -> Callable[[], float]:
    """``clock`` in mission seconds: mission time runs at ``time_scale`` x wall time.

    A simulated swarm too big for the CPU runs slower than real time: every process of a
    run multiplies its monotonic and wall clocks (message stamps included) by the same
    scale, so periods, timeouts, velocities and the robots' integration all stay in
    mission seconds while the wall-clock load drops by the scale. Processes with different
    scales disagree about stamps and drop each other's messages (stamp_future/stamp_old).
    """
    if time_scale == 1.0:
        return clock
    return lambda: clock() * time_scale


class StopFlag:
    """Set by SIGINT/SIGTERM so the main loop can exit and close its session cleanly.

    Zenoh callbacks run on background threads that keep a process alive until the session
    is closed, so processes must leave their ``with zenoh.open(...)`` block, not just die.
    The handler only sets a bool: Python runs handlers between bytecodes of the main
    thread, which may be holding any lock at that moment (setting a threading.Event from
    the handler deadlocked a robot that was inside Event.wait). Loops notice the flag at
    their next tick, at most one period late.
    """

    def __init__(self) -> None:
        self._stop = False
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._handle)

    def _handle(self, signum: int, frame: object) -> None:
        self._stop = True

    def set(self) -> None:
        self._stop = True

    def is_set(self) -> bool:
        return self._stop

    def sleep(self, seconds: float) -> None:
        """Sleep (a signal handler runs in between, and the caller then sees the flag)."""
        time.sleep(max(0.0, seconds))


class Ticker:
    """Fixed-rate loop timing on the monotonic clock, with overrun accounting.

    Deadlines advance by whole periods so the average rate holds; after an overrun of more
    than one period the schedule restarts from now (from the next tick of its phase) instead
    of bursting to catch up.
    ``time_scale`` s makes the ticker run on mission time (``clock() * s``, see
    :func:`scaled`): ``rate_hz`` ticks per mission second are ``rate_hz * s`` per wall second.
    ``phase`` in [0, 1): the ticks fall at (k + phase) periods of the clock rather than one
    period after the start, so processes of one machine (one monotonic clock) can take
    turns within the period instead of starting their work at chance moments.
    """

    def __init__(
        self,
        rate_hz: float,
        clock: Callable[[], float] = time.monotonic,
        time_scale: float = 1.0,
        phase: float | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate must be positive, got {rate_hz!r}")
        if not (time_scale > 0 and math.isfinite(time_scale)):
            raise ValueError(f"time scale must be positive, got {time_scale!r}")
        if phase is not None and not 0.0 <= phase < 1.0:
            raise ValueError(f"phase must be in [0, 1), got {phase!r}")
        self.period = 1.0 / rate_hz
        self._scale = time_scale
        self._clock = scaled(clock, time_scale)
        self._phase = phase
        self._next = self._after(self._clock() + self.period)
        self.ticks = 0
        self.overruns = 0

    def _after(self, moment: float) -> float:
        """The first tick time at or after ``moment``: ``moment`` itself without a phase."""
        if self._phase is None:
            return moment
        return (math.ceil(moment / self.period - self._phase) + self._phase) * self.period

    def now(self) -> float:
        """The ticker's clock (mission seconds when scaled)."""
        return self._clock()

    @property
    def deadline(self) -> float:
        """End of the current period (the next tick's scheduled time), on the ticker's clock."""
        return self._next

    def wait(self, stop: StopFlag) -> float:
        """Sleep until the next deadline (or a stop); returns the monotonic time of the tick."""
        now = self._clock()
        if now > self._next:
            self.overruns += 1  # the deadline passed before we were ready to wait for it
        if now > self._next + self.period:
            self._next = self._after(now)
            if self._next > now:  # back on the phase
                stop.sleep((self._next - now) / self._scale)
        else:
            stop.sleep((self._next - now) / self._scale)  # mission seconds -> wall seconds
        self._next += self.period
        self.ticks += 1
        return self._clock()
