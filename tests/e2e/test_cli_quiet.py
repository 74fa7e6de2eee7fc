"""Lines a user should not see: Ctrl-C on ``fleet hz`` / ``echo`` / ``status --watch`` printed
an INFO line ("received SIGINT, shutting down"), and the coordinator logged a stop without a
reason as "stop ... on all: " (a colon and nothing)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from testkit.harness import FleetHarness, wait_until


@pytest.mark.parametrize(
    "argv",
    [["hz", "arm/*/joints"], ["echo", "arm/*/joints"], ["status", "--watch"]],
    ids=["hz", "echo", "status-watch"],
)
def test_ctrl_c_ends_a_watching_command_without_a_log_line(
    fleet_harness: FleetHarness, argv: list[str]
) -> None:
    fleet_harness.start_router()
    process = subprocess.Popen(
        [sys.executable, "-m", "fleet.cli.main", *argv]
        + ["--inventory", str(fleet_harness.inventory_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # Connected once its session is up: the router counts it among its sessions.
        wait_until(lambda: _connected(fleet_harness) or process.poll() is not None, 20.0)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGINT)
        _out, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=5)
    assert "INFO" not in err and "shutting down" not in err, err


def _connected(harness: FleetHarness) -> bool:
    """True once a TCP connection to the router's port is established (the command's: the
    test opens none), read from /proc/net/tcp (state 01)."""
    port = f"{harness.port:04X}"
    lines = Path("/proc/net/tcp").read_text().splitlines()[1:]
    return any(ln.split()[2].endswith(f":{port}") and ln.split()[3] == "01" for ln in lines)


def test_the_coordinator_logs_a_stop_without_reason_without_a_dangling_colon(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    h.start_router()
    h.start_coordinator()
    client = h.client()
    request = client.stop_request("", source="test")

    def logged() -> str | None:
        client.put_stop(request)  # repeated until the coordinator (maybe still starting) saw it
        line = next((ln for ln in h.log("coordinator").splitlines() if "stop " in ln), None)
        return line

    line = wait_until(logged, 20.0, interval_s=0.5)
    assert not line.rstrip().endswith(":"), line
    assert "(no reason given)" in line, line
