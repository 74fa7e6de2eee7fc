"""Fixtures and rules of the whole suite (where a new test goes: tests/README.md).

Each folder is a kind of test, marked by its folder (``-m unit``, ``-m "not browser"``...):
``unit`` (pure, no process, no network: ``make test-fast``), ``e2e`` (real processes on
loopback), ``browser`` (the viewer in a headless Chromium), ``netlab`` (network namespaces).
The helpers are in ``testkit/`` (the process harness: testkit/harness.py)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from testkit.browser import Browser, open_browser
from testkit.harness import FleetHarness, reserved_domain
from testkit.priority import can_reprioritize, nice_for, set_worker_nice


@pytest.fixture
def fleet_harness(tmp_path: Path) -> Iterator[FleetHarness]:
    """A harness with one simulated arm (a1); start what the test needs."""
    with FleetHarness(tmp_path, arms=1) as harness:
        yield harness


@pytest.fixture
def dds_domain() -> Iterator[int]:
    """A DDS domain for a test that starts DDS processes of its own (a demo), reserved
    against every other test process of the host while the test runs."""
    with reserved_domain() as domain:
        yield domain


@pytest.fixture
def fleet3_harness(tmp_path: Path) -> Iterator[FleetHarness]:
    """A harness with three simulated arms (a1, a2, a3)."""
    with FleetHarness(tmp_path, arms=3) as harness:
        yield harness


FOLDERS = ("unit", "e2e", "browser", "netlab")


@pytest.hookimpl(tryfirst=True)  # before xdist's own, which reads the groups (see below)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Each test marked by its folder. Every browser test (its folder, or the fixture) on one
    xdist worker: two software-rendered Chromiums at once on this 2-core machine made a page take
    over 30 s to answer a click."""
    for item in items:
        parts = item.nodeid.split("::")[0].split("/")
        folder = parts[1] if len(parts) > 2 and parts[0] == "tests" else None
        if folder in FOLDERS:
            item.add_marker(getattr(pytest.mark, folder))
        if folder == "browser" or "browser" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("browser"))


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Browser]:
    """One page of a real headless Chromium in a fresh profile."""
    yield from open_browser(tmp_path)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Under ``--dist loadgroup`` every test of an xdist group must carry its group in its node
    id (xdist's mark of the group): without it each test is scheduled alone and the suite runs
    two network labs and two Chromiums at once. It was silently so with pytest 9 (xdist 3.8
    writes the group into ``item._nodeid``, which pytest 9 no longer reads) and with a group
    added after xdist's own collection hook ran."""
    if not getattr(session.config.option, "loadgroup", False):
        return
    lost = [
        item.nodeid
        for item in session.items
        if item.get_closest_marker("xdist_group") is not None and "@" not in item.nodeid
    ]
    if lost:
        raise pytest.UsageError(
            f"{len(lost)} tests lost their xdist group (e.g. {lost[0]}): check the pytest and "
            "pytest-xdist versions (pyproject.toml) and that the hooks adding groups run first"
        )


@pytest.hookimpl(tryfirst=True)  # before the fixtures: the processes they start inherit it
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Under xdist, tests that measure time (the lab, the browser, ``timing``) run ahead of
    the other workers' tests (testkit/priority.py)."""
    if "PYTEST_XDIST_WORKER" not in os.environ or not can_reprioritize():
        return
    group = item.get_closest_marker("xdist_group")
    timing = item.get_closest_marker("timing") is not None
    set_worker_nice(nice_for(group.args[0] if group else None, timing))
