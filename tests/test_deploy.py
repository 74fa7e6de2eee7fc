"""``fleet deploy systemd`` (issue 16): units rendered from an inventory, checked by
``systemd-analyze verify`` where it exists."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.cli.deploy_cmd import units
from fleet.inventory import load_inventory
from tests.harness import inventory_text


def test_units_from_inventory_verify(tmp_path: Path) -> None:
    path = tmp_path / "inventory.toml"
    extra = '[arms.b1]\ninterface = "eth0"\nsuffix = "_9"\nsimulated = false\n'
    # The devices of a card are served by its agent: a gripper on a1, a G1 on eth0.
    extra += '[grippers.gl]\nmount = "a1"\n[g1.h1]\ninterface = "eth0"\n'
    path.write_text(inventory_text("lab", 7447, 0, 2, extra), encoding="utf-8")
    inventory = load_inventory(path)
    bin_dir = Path(sys.executable).parent
    rendered = units(inventory, bin_dir)
    assert set(rendered) == {
        "d1-fleet-router.service",
        "d1-fleet-coordinator.service",
        "d1-fleet-viewer.service",
        "d1-fleet-agent-lo.service",
        "d1-fleet-agent-eth0.service",
    }
    agent = rendered["d1-fleet-agent-lo.service"]
    assert f"ExecStart={bin_dir}/edge-agent --interface lo --inventory {path}" in agent
    assert "Description=d1-fleet edge agent of a1, a2, gl (lo)" in agent, agent
    assert "edge agent of b1, h1 (eth0)" in rendered["d1-fleet-agent-eth0.service"]
    assert "Restart=on-failure" in agent and "StandardOutput=journal" in agent
    assert "After=network-online.target d1-fleet-router.service" in agent
    out = tmp_path / "units"
    done = subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", "deploy", "systemd", "--out", str(out)]
        + ["--inventory", str(path)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(rendered)
    if shutil.which("systemd-analyze") is None:
        pytest.skip("no systemd-analyze on this host")
    files = [str(p) for p in sorted(out.iterdir())]
    verify = subprocess.run(
        ["systemd-analyze", "verify", *files], capture_output=True, text=True, timeout=60
    )
    problems = [
        line
        for line in (verify.stdout + verify.stderr).splitlines()
        if "d1-fleet" in line and "network-online" not in line
    ]
    assert verify.returncode == 0 or not problems, verify.stdout + verify.stderr
    assert not problems, problems
