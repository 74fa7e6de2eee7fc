"""``fleet echo``, ``hz`` and ``diag`` on device keys (issue 21): real processes (router,
``fleet sim`` with one arm, a Dex1-1 and a G1, the arm's agent, one devices agent)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from fleet.wire import keys
from fleet.wire import messages as m
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
    client = mixed.client()
    key = client.keys.device("gripper", "gl", keys.DIAG)
    diag = m.Diag(**{**_a_diag(mixed), "relayed": 4242})
    stop = threading.Event()

    def publish() -> None:  # the device agent's diag, until it publishes one (issue 21 part 1)
        while not stop.wait(0.2):
            client.session.put(key, m.encode(diag))

    thread = threading.Thread(target=publish, name="diag-publisher", daemon=True)
    thread.start()
    try:
        done = fleet_cli(mixed, "diag", "gl", "--json")
    finally:
        stop.set()
        thread.join(5.0)
    assert done.returncode == 0, done.stdout + done.stderr
    assert json.loads(done.stdout)["gripper/gl"]["relayed"] == 4242
    table = fleet_cli(mixed, "diag", "g1/h1")
    assert table.stdout.splitlines()[1].split()[0] == "g1/h1"


def _a_diag(h: FleetHarness) -> dict[str, object]:
    """An arm's real diag as fields (a device's diag has the same schema)."""
    done = subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", "diag", "a1", "--json"]
        + ["--inventory", str(h.inventory_path)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    fields: dict[str, object] = json.loads(done.stdout)["a1"]
    fields["stamp_ns"] = time.time_ns()
    return fields
