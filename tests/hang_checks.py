"""Shared helper of the tests that feed a reader a FIFO (not a test module)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any


def value_errors_within(read: Callable[[Path], Any], path: Path, seconds: float = 5.0) -> list:
    """``read(path)`` in a daemon thread given ``seconds``: the ValueError it raised, in a
    list, or an empty list when it returned or still hangs (a reader blocked on a FIFO)."""
    errors: list[BaseException] = []

    def load() -> None:
        try:
            read(path)
        except ValueError as exc:
            errors.append(exc)

    worker = threading.Thread(target=load, daemon=True)
    worker.start()
    worker.join(seconds)
    return errors
