"""Latency compensation of an agent: where its robot is *now*, and what time it is anywhere.

Pure pieces (no I/O), used by the agent brain:

- :class:`CommandHistory` and :meth:`CommandHistory.predict`: a Smith-predictor-style
  estimate of the robot's pose at the time a new command will act. The latest pose is
  stamped when it was taken; the agent knows every wheel command it sent since (and the one
  the robot was driving then), so it integrates them forward in exact arcs, saturated and
  timed out exactly as ``sim_robot`` drives them (covswarm.tvd.drive.integrate_one, the
  robot's ``cmd_timeout``). Controlling from the prediction removes the pose-to-command
  latency from the heading loop, which is what made a late heading over-steer.
- :class:`ClockBound`: how far another host's stamps can be trusted. ``receipt - stamp`` =
  clock offset + one-way transit >= clock offset, so its windowed minimum ``b`` bounds our
  clock minus the sender's from above (tight when the fastest message had ~0 transit).
  ``b < 0`` proves the sender's clock is ahead of ours by at least ``-b``, and its stamps are
  corrected by that; a sender behind ours cannot be told apart from a slow link without a
  round trip, so its lag is compensated as if it were transport delay (bounded by the
  prediction horizon). So the offset is *bounded from the data*, one-sided, and measured
  exactly for a sender that runs ahead; ``b`` is reported.
- The coordinator's mission time: a Domain broadcast's ``t`` plus its age since its stamp,
  on our clock within the ClockBound of the coordinator (exact on one host or between
  synchronised clocks; a coordinator's clock behind ours by an offset no message proves
  puts S that far ahead, as it does a neighbour's state). Not from when the broadcast was
  taken: a packed agent takes it at its tick, a constant 0-50 ms after a 20 Hz broadcast
  whose phase it keeps, so receipt times understated its age by as much on every message.

Times: ``wall`` arguments are seconds on this host's (scaled) wall clock, the clock the
agent stamps its commands with; ``now`` arguments are this host's monotonic seconds.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from covswarm.tvd.drive import KHEPERA_IV, DiffDrive, integrate_one

# s: commands kept for prediction. Poses older than this are not predicted (the agent treats
# its pose as stale long before: --stale-timeout).
HISTORY_SPAN = 2.0
# s: window of the clock estimators: long enough to contain a fast message, short enough to
# follow clock drift (NTP slews at most 0.5 ms/s).
CLOCK_WINDOW = 10.0


class SentCommand(NamedTuple):
    """A wheel command as sent: our wall stamp, rim speeds (m/s, already saturated).

    A NamedTuple: one is built per command of every brain, several times cheaper than a
    frozen dataclass."""

    wall: float
    left: float
    right: float


class CommandHistory:
    """The wheel commands sent to our robot over the last HISTORY_SPAN seconds."""

    def __init__(self, robot: DiffDrive = KHEPERA_IV, cmd_timeout: float = 0.5) -> None:
        if not (cmd_timeout > 0.0 and math.isfinite(cmd_timeout)):
            raise ValueError(f"cmd_timeout must be positive, got {cmd_timeout!r}")
        self.robot, self.cmd_timeout = robot, cmd_timeout
        self._sent: deque[SentCommand] = deque()

    def add(self, wall: float, left: float, right: float) -> None:
        """Record a command sent at ``wall`` (non-finite speeds were sent as 0)."""
        if not (math.isfinite(left) and math.isfinite(right)):
            left = right = 0.0
        sent = self._sent
        if sent and wall < sent[-1].wall:
            sent.clear()  # our own clock stepped back: the history no longer lines up
        sent.append(SentCommand(wall, left, right))
        start = wall - HISTORY_SPAN
        while sent[0].wall < start:  # never the command just added
            sent.popleft()

    def segments(self, start: float, end: float) -> list[tuple[float, float, float]]:
        """[(duration s, left, right)] the robot drove between walls ``start`` and ``end``.

        Each command drives from its stamp until the next one or until ``cmd_timeout`` after
        it (the robot stops), whichever is first; before the first known command the wheels
        count as stopped.
        """
        out: list[tuple[float, float, float]] = []
        if end <= start:
            return out
        sent = self._sent
        # From the last command sent by ``start`` on (found from the newest: a pose is a
        # period old or less, the history HISTORY_SPAN long): every earlier one was
        # replaced by ``start`` and drives none of it.
        first = len(sent) - 1
        while first > 0 and sent[first].wall > start:
            first -= 1
        cursor = start
        for k in range(max(first, 0), len(sent)):
            command = sent[k]
            until = sent[k + 1].wall if k + 1 < len(sent) else math.inf
            driving_end = min(until, command.wall + self.cmd_timeout, end)
            begin = max(command.wall, cursor)
            if begin > cursor and begin <= end:  # a gap with no command: stopped
                out.append((min(begin, end) - cursor, 0.0, 0.0))
                cursor = min(begin, end)
            if driving_end > cursor:
                out.append((driving_end - cursor, command.left, command.right))
                cursor = driving_end
            if cursor >= end:
                break
        if cursor < end:
            out.append((end - cursor, 0.0, 0.0))
        return out

    def predict(self, pose: np.ndarray, taken: float, target: float) -> np.ndarray:
        """Pose (x, y, heading) at wall ``target`` from ``pose`` taken at wall ``taken``.

        Exact arcs of the commands in :meth:`segments` (a ``target`` before ``taken`` returns
        the pose unchanged: nothing to undo). pose: (3,).
        """
        x, y, heading = np.asarray(pose, dtype=float).reshape(3).tolist()
        return np.array(self.move(x, y, heading, taken, target))

    def move(
        self, x: float, y: float, heading: float, taken: float, target: float
    ) -> tuple[float, float, float]:
        """:meth:`predict` in plain floats: (x m, y m, heading rad) at wall ``target`` from
        the pose (x, y, heading) taken at wall ``taken``."""
        for duration, left, right in self.segments(taken, target):
            x, y, heading = integrate_one(x, y, heading, left, right, duration, self.robot)
        return x, y, heading


class ClockBound:
    """Bound on our wall clock minus a sender's, from its stamps (module docstring).

    The bound is the minimum of ``receipt - stamp`` over the last ``window`` s, kept in O(1)
    amortised per message: the samples that could still become the minimum, oldest first,
    their values increasing. Every brain adds one per message it accepts."""

    # Every brain holds one per neighbour it follows (~20 in a dense team) and adds to it
    # per AgentState: no instance dict, and the samples flat in a short list (a deque is
    # 760 bytes: ~8 MB in a 500-brain process, out of the caches; this is ~120).
    __slots__ = ("window", "_samples")

    def __init__(self, window: float = CLOCK_WINDOW) -> None:
        self.window = window
        self._samples: list[float] = []  # now, receipt - stamp, now, receipt - stamp, ...

    def add(self, now: float, received_wall: float, stamp: float) -> float:
        """A message stamped ``stamp`` (sender's clock) received at our ``received_wall``,
        ``now`` monotonic (the window's clock); returns its stamp on our clock with it
        counted (:meth:`to_local`, in the same call: every brain does it per state)."""
        value = received_wall - stamp
        samples = self._samples
        while samples and samples[-1] >= value:
            del samples[-2:]  # never the minimum again: this one is lower and newer
        samples += now, value
        if samples[0] < now - self.window:  # rarely: the minimum is seldom 10 s old
            start = now - self.window
            first = 2
            while samples[first] < start:  # never the sample just added
                first += 2
            del samples[:first]
        bound = samples[1]
        return stamp + bound if bound < 0.0 else stamp

    @property
    def bound(self) -> float:
        """min(receipt - stamp) over the window, s (NaN before any message)."""
        return self._samples[1] if self._samples else math.nan

    def to_local(self, stamp: float) -> float:
        """A sender's stamp on our wall clock: shifted by the bound when it proves the sender
        runs ahead of us, else as stamped."""
        bound = self.bound
        return stamp + bound if bound < 0.0 else stamp

    def clear(self) -> None:
        """Forget the bound (a restarted sender, maybe on another host)."""
        self._samples.clear()
