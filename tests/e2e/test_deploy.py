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
from testkit.harness import inventory_text


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
    assert f'ExecStart="{bin_dir}/edge-agent" "--interface" "lo" "--inventory" "{path}"' in agent
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


def systemd_words(line: str) -> list[str]:
    """The argv systemd makes of an ``ExecStart=`` value (quotes, C escapes, ``%%``, ``$$``);
    an unescaped specifier or variable is an error here (systemd would expand it)."""
    words, i = [], 0
    escapes = {"\\": "\\", '"': '"', "n": "\n", "t": "\t", "r": "\r"}
    while i < len(line):
        if line[i] == " ":
            i += 1
            continue
        assert line[i] == '"', f"unquoted word at {line[i:]!r}"
        i += 1
        word = []
        while line[i] != '"':
            char = line[i]
            if char == "\\":
                nxt = line[i + 1]
                if nxt == "x":
                    word.append(chr(int(line[i + 2 : i + 4], 16)))
                    i += 4
                    continue
                word.append(escapes[nxt])
                i += 2
                continue
            if char in "%$":
                assert line[i + 1] == char, f"unescaped {char} in {line!r}"
                i += 1
            word.append(char)
            i += 1
        words.append("".join(word))
        i += 1
    return words


def test_hostile_inventory_values_stay_single_literal_arguments(tmp_path: Path) -> None:
    folder = tmp_path / 'my %h $HOME "dir"'
    folder.mkdir()
    path = folder / "inventory.toml"
    extra = '[arms.b1]\ninterface = "eth0 --principal root"\nsuffix = "_9"\nsimulated = false\n'
    path.write_text(inventory_text("lab", 7447, 0, 1, extra), encoding="utf-8")
    inventory = load_inventory(path)
    bin_dir = tmp_path / "bin %i $PATH"
    rendered = units(inventory, bin_dir, user="d1%u")
    for name, text in rendered.items():
        lines = text.splitlines()
        (exec_start,) = [x for x in lines if x.startswith("ExecStart=")]
        argv = systemd_words(exec_start.removeprefix("ExecStart="))
        assert argv[0].startswith(str(bin_dir)), (name, argv)
        assert argv[argv.index("--inventory") + 1] == str(path.resolve()), argv
        assert "User=d1%%u" in lines
        for line in lines:
            assert "%" not in line.replace("%%", ""), line
    agent = [t for n, t in rendered.items() if "eth0" in n][0]
    (exec_start,) = [x for x in agent.splitlines() if x.startswith("ExecStart=")]
    argv = systemd_words(exec_start.removeprefix("ExecStart="))
    assert argv[1:3] == ["--interface", "eth0 --principal root"]
    assert "--principal" not in argv
