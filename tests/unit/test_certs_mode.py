"""Issue 28, finding 8: ``fleet certs`` (and ``--force``) leaves every key it writes mode 0600,
also a key that an earlier mistake left world-readable."""

from __future__ import annotations

import stat
from pathlib import Path

from fleet.inventory import load_inventory
from fleet.security.certs import make_certs
from testkit.harness import inventory_text


def _secrets(directory: Path) -> list[Path]:
    return sorted([*directory.glob("*.key"), directory / "passwords.txt"])


def test_forced_certificates_reset_every_key_to_0600(tmp_path: Path) -> None:
    path = tmp_path / "inventory.toml"
    path.write_text(inventory_text("lab", 7447, 0, 1, security="mtls"), encoding="utf-8")
    inventory = load_inventory(path)
    directory = tmp_path / "certs"
    make_certs(inventory, directory, days=2)
    keys = _secrets(directory)
    assert len(keys) > 3
    for key in keys:
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key
        key.chmod(0o644)  # someone made them readable
    make_certs(inventory, directory, days=2, force=True)
    modes = {key.name: oct(stat.S_IMODE(key.stat().st_mode)) for key in _secrets(directory)}
    assert set(modes.values()) == {"0o600"}, modes
