"""Shared fixtures: see tests/harness.py for the process harness."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

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
