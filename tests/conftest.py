"""Shared fixtures: see tests/harness.py for the process harness."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.browser import Browser, open_browser
from tests.harness import FleetHarness


@pytest.fixture
def fleet_harness(tmp_path: Path) -> Iterator[FleetHarness]:
    """A harness with one simulated arm (a1); start what the test needs."""
    with FleetHarness(tmp_path, arms=1) as harness:
        yield harness


@pytest.fixture
def fleet3_harness(tmp_path: Path) -> Iterator[FleetHarness]:
    """A harness with three simulated arms (a1, a2, a3)."""
    with FleetHarness(tmp_path, arms=3) as harness:
        yield harness


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Every browser test on one xdist worker: two software-rendered Chromiums at once on this
    2-core machine made a page take over 30 s to answer a click."""
    for item in items:
        if "browser" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("browser"))


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Browser]:
    """One page of a real headless Chromium in a fresh profile."""
    yield from open_browser(tmp_path)
