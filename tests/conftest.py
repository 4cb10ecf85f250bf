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


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Two workers (pytest-xdist, pyproject's addopts ``-n 2 --dist loadgroup``), each taking
    whole groups: every end-to-end test in one group, so they run one at a time as they were
    measured (each runs a machine's worth of processes and checks their rates and errors),
    beside the other tests grouped by module (a module's fixtures are then built once)."""
    for item in items:
        group = "e2e" if item.get_closest_marker("e2e") else item.nodeid.partition("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))


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
