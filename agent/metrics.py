"""Measurements one agent reports about itself in AgentState.stats (pure)."""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

STATS_WINDOW = 5.0  # s over which rates are measured
TIMING_SAMPLES = 256  # step durations kept for the p50/p99


class Percentiles:
    """Rolling percentiles of the last ``TIMING_SAMPLES`` values (non-finite ones are not
    kept: they have no rank)."""

    def __init__(self) -> None:
        self._values: deque[float] = deque()  # in arrival order, to evict the oldest
        self._ordered: list[float] = []  # the same values, sorted

    def add(self, value: float) -> None:
        if not math.isfinite(value):
            return
        # Kept sorted as they come (a bisection and a short memmove each) rather than sorted
        # on each read: a brain stepping a few times a second reports its stats on most of
        # its steps, and sorting two windows of 256 each time was 4 % of an overloaded live
        # agent process's samples (1000 robots at 1.4 Hz, py-spy, 30 Nov 2026).
        if len(self._values) == TIMING_SAMPLES:
            del self._ordered[bisect.bisect_left(self._ordered, self._values.popleft())]
        self._values.append(value)
        bisect.insort(self._ordered, value)

    def get(self, *qs: float) -> tuple[float, ...]:
        """The ``qs`` quantiles (each 0..1) of the values kept; 0 each before any."""
        ordered = self._ordered
        if not ordered:
            return (0.0,) * len(qs)
        last = len(ordered) - 1
        return tuple(ordered[min(last, int(q * len(ordered)))] for q in qs)


class Rate:
    """Events per second over the last ``STATS_WINDOW`` seconds from a cumulative count."""

    def __init__(self) -> None:
        self._samples: deque[tuple[float, int]] = deque()

    def add(self, now: float, total: int) -> float:
        """Record ``total`` events at ``now`` (s); the rate over the window (1/s)."""
        self._samples.append((now, total))
        while self._samples[0][0] < now - STATS_WINDOW:
            self._samples.popleft()
        (t0, n0), (t1, n1) = self._samples[0], self._samples[-1]
        return (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0


@dataclass
class Counters:
    """Processed input and control steps, reported in AgentState.stats (drops: DropLog)."""

    received: int = 0  # payloads that reached the main loop
    coalesced: int = 0  # overwritten by a newer payload on the same key before processing
    step_errors: int = 0  # control steps that failed (robot commanded to stop)
    steps: int = 0
    mission_steps: int = 0  # steps while the mission runs
    guarded: int = 0  # mission steps whose velocity the control law's amplification guard cut
    # control periods of the mission whose command went out after the period had ended
    overruns: int = 0
    # control periods of the mission a packed process could not step this brain in
    # (its turn came after the period ended: it held its robot, covswarm.agent.pack)
    late: int = 0
    # steps of this brain whose batch of local steps raised (a bad view in it: covswarm.
    # agent.pack), taken again one by one so that only the bad one stops
    batch_fallbacks: int = 0
    # mission steps whose turn rate was capped so that the command, held until the next
    # step, turns the robot no further than to face its velocity (covswarm.tvd.drive.steer)
    turn_capped: int = 0
    # mission steps whose command, held until the next step, would have turned the robot by
    # more than ARC_TURN: it turned in place instead (covswarm.agent.brain.ARC_TURN)
    arc_turned: int = 0
    # safety-filter rows of mission steps whose barrier gain was sampled over the robot's
    # command timeout, not the expected hold: the pair would come within the safe distance
    # in that time, the brain slower than ARC_HOLD (covswarm.agent.brain.filter_all)
    overrun_gained: int = 0
    # mission steps whose robot, stopped dead by the safety filter, turned toward its slide
    # (the velocity the filter leaves a robot that could move sideways: covswarm.tvd.drive.
    # steer), not its aim
    slid: int = 0
    # robots followed as stranded: their token lives without their agent's, and their own
    # poses make them still rows of the safety filter (covswarm.agent.brain.AgentBrain.stranded)
    stranded_followed: int = 0
    # mission steps with no cell in S (the robot outside S, dominated by teammates: it aims
    # at S's centroid, covswarm.tvd.control); a robot stuck so dominates e_a
    cell_empty: int = 0
    # mission steps that took neighbours' states as usable beyond the stale timeout, the
    # brain's turns coming late (covswarm.agent.brain.AgentBrain.pace)
    stale_stretched: int = 0
    # mission steps that stopped the robot because its newest pose was stamped longer ago
    # than the command history predicts (covswarm.agent.brain.MAX_PREDICTION)
    pose_too_old: int = 0
    # mission steps whose velocity was scaled up because the robot's command times out
    # before the next step (covswarm.agent.brain.MAX_DUTY)
    duty_scaled: int = 0
    # mission steps whose velocity was cut to the speed at which a robot the safety filter
    # does not see yet can still be avoided (covswarm.tvd.safety.unseen_speed_limit)
    speed_limited: int = 0
    # robots left out of the safety filter during the mission, summed over steps: known only
    # from a beacon older than BEACON_TRUST while their AgentState is awaited
    # (covswarm.agent.neighborhood.Neighborhood.fresh_rows)
    beacon_doubted: int = 0
    # robots near us, first-hand at the last step, kept in the safety filter where last known
    # since they vanished or (followed) were then named only by a relay or a beacon
    # (covswarm.agent.brain.AgentBrain._safety_inputs, OBSTACLE_MEMORY)
    obstacles_kept: int = 0
    # steps before the mission that turned the robot in place to face S's first motion
    # (covswarm.agent.brain.AgentBrain._standing)
    aligning: int = 0
