"""Fixtures of the network lab: one lab of topology 1 shared by the package (built once, ~10 s;
each test starts by putting it back in order), topology 2 built by its own module.

Each test module that is a row of the fault matrix names it (``ROW = "1"``) and reports its
figures through ``row_report``; with pytest's verdict each becomes a record in
``artifacts/netlab/rows.jsonl`` and the table of ``artifacts/netlab/report.md`` is rendered
again (``testkit.labrows``), from which ``scripts/docs_results.py`` refreshes the page."""

from __future__ import annotations

from collections.abc import Generator, Iterator

import pytest

from tests.netlab.fleetlab import LAB_DEVICES, LabFleet, one_router
from tests.netlab.lab import netem_available, why_no_lab
from tests.netlab.rowreport import RowReport, record, row_of

WHY_NOT = why_no_lab()
ARMS = 5


@pytest.hookimpl(tryfirst=True)  # before xdist's own, which reads the groups
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


@pytest.fixture
def row_report(request: pytest.FixtureRequest) -> RowReport:
    """This test's ``RowReport`` (its module names its row: ``ROW``)."""
    assert isinstance(request.node, pytest.Item)
    assert row_of(request.node), f"{request.node.nodeid}: its module names no ROW"
    return RowReport(request.node)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    """A fault-matrix test's record, with its verdict, once it ran (or failed to set up)."""
    report = yield
    row = row_of(item)
    if row and (report.when == "call" or (report.when == "setup" and report.failed)):
        record(item, row, report, call)
    return report
