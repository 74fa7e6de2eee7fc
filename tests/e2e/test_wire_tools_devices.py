"""``fleet echo``, ``hz`` and ``diag`` on device keys (issue 21): real processes (router,
``fleet sim`` with one arm, a Dex1-1 and a G1, the arm's agent, one devices agent)."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from testkit.harness import FleetHarness, wait_until
from tests.e2e.test_wire_tools import fleet_cli

EXTRA = '[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    with FleetHarness(tmp_path_factory.mktemp("wire_devices"), extra=EXTRA) as h:
        h.start_fleet()
        h.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "h1"])
        client = h.client()
        wait_until(lambda: all(s is not None for s in client.device_snapshot().values()), 40.0)
        yield h


def test_echo_decodes_device_states(mixed: FleetHarness) -> None:
    done = fleet_cli(mixed, "echo", "*/*/state", "--json", "--count", "20")
    assert done.returncode == 0, done.stderr
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    assert lines and all("error" not in x for x in lines), lines[:3]
    assert {"gripper/state", "g1/state"} >= {x["kind"] for x in lines}
    grip = [x for x in lines if x["kind"] == "gripper/state"]
    assert grip and grip[0]["payload"]["mount"] == "a1"
    assert "no channel" not in done.stdout + done.stderr


def test_hz_measures_a_device_state(mixed: FleetHarness) -> None:
    done = fleet_cli(mixed, "hz", "g1/h1/state", "--for-s", "2.5", "--json")
    assert done.returncode == 0, done.stderr
    reports = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert reports and reports[-1]["key"] == "fleet/test/g1/h1/state"
    assert reports[-1]["samples"] >= 5


def test_diag_names_devices_and_reads_their_diag(mixed: FleetHarness) -> None:
    """The device agent's own diag (1 Hz): its link and what it relayed from the simulated
    gripper, read by ``fleet diag`` by the device's id."""
    done = fleet_cli(mixed, "diag", "gl", "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    diag = json.loads(done.stdout)["gripper/gl"]
    assert diag["link"] == "ok" and diag["relayed"] > 0 and diag["feedback_rate_hz"] > 0, diag
    table = fleet_cli(mixed, "diag", "g1/h1")
    assert table.stdout.splitlines()[1].split()[0] == "g1/h1"
