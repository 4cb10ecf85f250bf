"""An agent's rolling measurements (covswarm.agent.metrics) against plain references."""

from __future__ import annotations

import numpy as np

from covswarm.agent.metrics import TIMING_SAMPLES, Percentiles


def test_percentiles_are_the_order_statistics_of_the_last_values() -> None:
    """get(*qs): for each q, the value at rank floor(q * n) (capped at the last) of the last
    TIMING_SAMPLES values, sorted, all from one call; zeros before any value."""
    assert Percentiles().get(0.5, 0.99) == (0.0, 0.0)
    rng = np.random.default_rng(11)
    for n in (1, 7, TIMING_SAMPLES, 3 * TIMING_SAMPLES + 5):
        values = rng.exponential(100.0, n).tolist()
        rolling = Percentiles()
        for value in values:
            rolling.add(value)
        kept = sorted(values[-TIMING_SAMPLES:])
        qs = (0.0, 0.5, 0.99, 1.0, float(rng.uniform()))
        expected = tuple(kept[min(len(kept) - 1, int(q * len(kept)))] for q in qs)
        assert rolling.get(*qs) == expected
        assert rolling.get(0.5) == (expected[1],)


def test_percentiles_keep_ties_and_leave_out_non_finite_values() -> None:
    """Repeated values are each kept and evicted once; NaN and infinities are not kept
    (they have no rank), so they never shift the order statistics of the others."""
    rolling = Percentiles()
    values = [1.0, 2.0, 2.0, 3.0] * TIMING_SAMPLES
    for value in values:
        rolling.add(value)
        rolling.add(float("nan"))
        rolling.add(float("inf"))
    kept = sorted(values[-TIMING_SAMPLES:])
    assert rolling.get(0.0, 0.25, 0.5, 0.99, 1.0) == tuple(
        kept[min(len(kept) - 1, int(q * len(kept)))] for q in (0.0, 0.25, 0.5, 0.99, 1.0)
    )
