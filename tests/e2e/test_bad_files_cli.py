"""Malformed choreography and inventory files on the command line: exit code 2 with the
message, never a traceback (the parsers' own checks are in tests/unit/test_bad_files.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from testkit.file_tables import choreo_text, inventory_text

HUGE = "1" * 5000  # past Python's 4300-digit limit for int(str)


def _fleet(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_cli_exits_2_with_the_message_for_bad_files(tmp_path: Path) -> None:
    good = tmp_path / "inv.toml"
    good.write_text(inventory_text({}), encoding="utf-8")
    script = tmp_path / "dance.toml"
    script.write_text(choreo_text({"choreo.arms": "1"}), encoding="utf-8")
    played = _fleet("play", str(script), "--check", "--inventory", str(good))
    assert played.returncode == 2, played
    assert f"{script}: choreo.arms" in played.stderr and "Traceback" not in played.stderr

    script.write_bytes(b"[choreo]\nname = '\xff'\n")
    played = _fleet("play", str(script), "--check", "--inventory", str(good))
    assert played.returncode == 2 and str(script) in played.stderr, played
    assert "Traceback" not in played.stderr

    bad = tmp_path / "bad.toml"
    bad.write_text(inventory_text({"arms.a1.lease_s": HUGE}), encoding="utf-8")
    status = _fleet("status", "--inventory", str(bad))
    assert status.returncode == 2 and f"{bad}: not valid TOML" in status.stderr, status
    assert "Traceback" not in status.stderr
