"""Imports point one way (README "Architecture"): the keeper of the rule, reading the sources."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
OURS = ("fleet", "edge_agent", "viewer")


def _imports(folder: str) -> dict[str, set[str]]:
    """Per source file below ``folder``, the modules of ours it imports."""
    found: dict[str, set[str]] = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module)
            elif isinstance(node, ast.Import):
                names.update(alias.name for alias in node.names)
        found[str(path.relative_to(ROOT))] = {n for n in names if n.split(".")[0] in OURS}
    return found


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(f"{package}.")


def _offenders(folder: str, allowed: tuple[str, ...]) -> list[str]:
    return [
        f"{path} imports {name}"
        for path, names in _imports(folder).items()
        for name in sorted(names)
        if not any(_within(name, a) for a in allowed)
    ]


@pytest.mark.parametrize("folder", ["edge_agent", "viewer"])
def test_the_edge_and_the_viewer_never_import_the_coordinator(folder: str) -> None:
    offenders = [
        f"{path} imports {name}"
        for path, names in _imports(folder).items()
        for name in names
        if _within(name, "fleet.coordinator")
    ]
    assert offenders == []


def test_the_codec_and_the_key_space_import_nothing_above_them() -> None:
    assert _offenders("fleet/d1", ("fleet.d1",)) == []
    assert _offenders("fleet/wire", ("fleet.wire", "fleet.d1")) == []


def test_the_client_side_library_never_imports_its_users() -> None:
    """``fleet.watch`` and ``fleet.heartbeat`` serve the API, player, mirror and coordinator."""
    users = ("fleet.api", "fleet.choreo", "fleet.teleop", "fleet.coordinator", "fleet.cli")
    imported = _imports("fleet")
    for module in ("fleet/watch.py", "fleet/heartbeat.py"):
        assert [n for n in imported[module] if any(_within(n, u) for u in users)] == []
