"""runtime.ratelog: per-key rate-limited log lines, with the rest counted."""

from __future__ import annotations

import logging

import pytest

from covswarm.runtime.ratelog import OVERFLOW_KEY, RateLog


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_at_most_burst_lines_per_key_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    log = RateLog(logging.getLogger("test.ratelog"), interval=10.0, burst=2, clock=clock)
    with caplog.at_level(logging.WARNING, logger="test.ratelog"):
        logged = [log.warning("a", "bad %d", k) for k in range(1000)]
        assert logged[:2] == [True, True] and not any(logged[2:])
        assert log.warning("b", "other key")  # another key has its own budget
        clock.t = 10.0
        assert log.warning("a", "bad again")
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["bad 0", "bad 1", "other key", "bad again (998 similar lines suppressed)"]
    assert log.suppressed == {"a": 998}
    assert log.total_suppressed == 998


def test_distinct_keys_are_bounded(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    log = RateLog(logging.getLogger("test.ratelog2"), burst=1, max_keys=4, clock=clock)
    with caplog.at_level(logging.WARNING, logger="test.ratelog2"):
        logged = sum(log.warning(f"id {k}", "forged id %d", k) for k in range(10_000))
    # 4 keys, then one overflow key for all the others: 5 lines for 10 000 calls.
    assert logged == 5
    assert log.suppressed[OVERFLOW_KEY] == 10_000 - 5
    assert len(caplog.records) == 5


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="RateLog"):
        RateLog(logging.getLogger("x"), interval=0.0)
    with pytest.raises(ValueError, match="RateLog"):
        RateLog(logging.getLogger("x"), burst=0)
