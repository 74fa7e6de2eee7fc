"""With no router, a command fails fast with one clean line (it waited 10 s, and showed Zenoh's
Rust source paths)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from fleet.cli.main import EXIT_UNREACHABLE, main
from testkit.harness import FleetHarness


@pytest.mark.parametrize("command", [["estop"], ["status"], ["reset", "a1"]])
def test_no_router_fails_within_the_connect_timeout_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str]
) -> None:
    with FleetHarness(tmp_path, arms=1) as h:  # nothing started: no router on its port
        started = time.monotonic()
        code = main([*command, "--inventory", str(h.inventory_path)])
        took = time.monotonic() - started
    err = capsys.readouterr().err.strip()
    assert code == EXIT_UNREACHABLE
    assert took < 5.0, f"took {took:.1f} s"
    assert err.count("\n") == 0 and "no Zenoh router answered" in err, err
    assert ".rs" not in err and "--connect-timeout" in err, err
