"""Fixtures of the network lab: one lab of topology 1 shared by the package (built once, ~10 s;
each test starts by putting it back in order), topology 2 built by its own module."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.netlab.fleetlab import LAB_DEVICES, LabFleet, one_router
from tests.netlab.lab import netem_available, why_no_lab

WHY_NOT = why_no_lab()
ARMS = 5


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Every lab test in one xdist group (one worker builds the shared lab once, and its fault
    timings are not shared with another lab); skipped, with the reason, where namespaces cannot
    be made."""
    for item in items:
        if "netlab" in item.nodeid.split("::")[0]:
            item.add_marker(pytest.mark.xdist_group("netlab"))
            if WHY_NOT is not None:
                item.add_marker(pytest.mark.skip(reason=WHY_NOT))


@pytest.fixture(scope="package")
def lab1(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LabFleet]:
    """Topology 1: one router, the coordinator, a client, five arm hosts (a Dex1-1 mounted on
    a1) and a G1 host, every link clean."""
    if not netem_available():
        print("\nnetlab: this kernel has no sch_netem; the links are userspace cables (cable.py)")
    fleet = one_router(tmp_path_factory.mktemp("netlab1"), arms=ARMS, devices=LAB_DEVICES)
    try:
        yield fleet
    finally:
        fleet.lab.close()
