"""Fixtures shared by the test modules.

``require``: a test that needs a system tool or privilege skips without it on a
contributor's machine, with the reason, but fails under CI (``CI=true``, as .ci/run sets
it), where a missing tool means a broken install step, not an optional test.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest


def running_in_ci() -> bool:
    """True when the environment says CI (CI=true/1/yes, as .ci/run and most CI systems set)."""
    return os.environ.get("CI", "").strip().lower() in {"1", "true", "yes"}


@pytest.fixture(scope="session")
def require() -> Callable[[bool, str], None]:
    """require(condition, reason): skip (here) or fail (under CI) when ``condition`` is false."""

    def check(condition: bool, reason: str) -> None:
        if condition:
            return
        if running_in_ci():
            pytest.fail(f"{reason} (CI=true: required here)")
        pytest.skip(reason)

    return check


@pytest.fixture(scope="module")
def browser(require: Callable[[bool, str], None]) -> Iterator[object]:
    """Debian's Chromium driven by Playwright (never ``playwright install``)."""
    from browser_pages import CHROMIUM, CHROMIUM_ARGS
    from playwright.sync_api import sync_playwright

    require(
        Path(CHROMIUM).exists(), f"needs Debian's chromium at {CHROMIUM} (apt-get install chromium)"
    )
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()
