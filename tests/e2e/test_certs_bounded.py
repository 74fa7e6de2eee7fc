"""Issue 28 leftover: certificates and password files are read through ``fleet/files.py``'s
bounded read: a huge file in the CA key's place, or a FIFO in the passwords file's, is refused
in one line, never read whole or waited on."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from testkit.harness import inventory_text

ROOT = Path(__file__).resolve().parents[2]


def test_a_huge_ca_key_is_refused_in_one_line(tmp_path: Path) -> None:
    inventory = tmp_path / "inventory.toml"
    inventory.write_text(inventory_text("test", 7447, 1, 1, "", "mtls"), encoding="utf-8")
    certs = tmp_path / "certs"
    certs.mkdir()
    (certs / "ca.pem").write_text("not read before the key\n")
    (certs / "ca.key").write_bytes(b"-" * (1 << 20))
    run = subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", "certs", "--inventory", str(inventory)],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=ROOT,
    )
    assert run.returncode == 2, run.stdout + run.stderr
    key = certs / "ca.key"
    expected = f"fleet certs: {key}: the CA key is 1048576 bytes, more than 65536; refused"
    assert run.stderr.strip() == expected


def test_a_fifo_in_place_of_the_passwords_file_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from fleet.inventory import InventoryError, load_inventory
    from fleet.security.session import _password_of

    inventory_path = tmp_path / "inventory.toml"
    text = inventory_text("test", 7447, 1, 1, "", "password")
    inventory_path.write_text(text, encoding="utf-8")
    inventory = load_inventory(inventory_path)
    Path(inventory.security.passwords).parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(inventory.security.passwords)
    monkeypatch.delenv("D1_FLEET_PASSWORD", raising=False)
    try:
        _password_of(inventory, "operator")
    except InventoryError as exc:
        assert "not a regular file" in str(exc)
    else:
        raise AssertionError("a FIFO passwords file was read")
