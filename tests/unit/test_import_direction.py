"""Imports point one way (shared/STYLE.md): a walk over every import of the product's packages.

- the codec imports only itself, the key space only itself and the codec;
- ``edge_agent/`` and ``viewer/`` never import the coordinator, nor each other;
- ``fleet/`` never imports the agent or the viewer, but for its CLI: the ``fleet`` command is
  the top of the stack and runs the viewer;
- nothing imports ``edge_agent.agent`` but the agent's ``__main__`` (no module reaches back
  into the agent), and no package has an import circle, at module level or in disguise
  (an import inside a function counts too).
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("fleet", "edge_agent", "viewer")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def _modules() -> dict[str, Path]:
    return {
        _module_name(path): path
        for package in PACKAGES
        for path in sorted((REPO / package).rglob("*.py"))
    }


def _resolve(name: str) -> str | None:
    """The product module ``name`` refers to (a module or a name in one), or None."""
    modules = _modules()
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


@cache
def imports_of(module: str) -> frozenset[str]:
    """Every product module ``module`` imports, anywhere in its body."""
    path = _modules()[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            names = [f"{base}.{alias.name}" for alias in node.names] + [base]
        for name in names:
            target = _resolve(name)
            if target is not None and target != module:
                found.add(target)
    return frozenset(found)


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _violations(importer: str, forbidden: tuple[str, ...]) -> list[str]:
    return sorted(
        f"{module} imports {target}"
        for module in _modules()
        if _within(module, importer) and not _within(module, "fleet.cli")
        for target in imports_of(module)
        if any(_within(target, f) for f in forbidden)
    )


def test_the_walk_sees_the_product() -> None:
    assert "edge_agent.link" in _modules()
    assert "fleet.d1.protocol" in imports_of("fleet.d1arm.tracker")
    assert "fleet.wire.keys" in imports_of("edge_agent.relay")


def _outside(importer: str, allowed: tuple[str, ...]) -> list[str]:
    return sorted(
        f"{module} imports {target}"
        for module in _modules()
        if _within(module, importer)
        for target in imports_of(module)
        if not any(_within(target, a) for a in allowed)
    )


def test_the_codec_and_the_key_space_import_nothing_above_them() -> None:
    assert _outside("fleet.d1", ("fleet.d1",)) == []
    # The channel table lists every kind's payloads: the kinds' Struct modules are as low as
    # the key space (they import only its messages), the rest of a kind's package is above it.
    kind_schemas = ("fleet.dex1.messages", "fleet.g1.messages")
    assert _outside("fleet.wire", ("fleet.wire", "fleet.d1", *kind_schemas)) == []
    for module in kind_schemas:
        assert imports_of(module) <= {"fleet.wire.messages"}, module


def test_the_client_side_library_never_imports_its_users() -> None:
    """``fleet.watch`` and ``fleet.heartbeat`` serve the API, player, mirror and coordinator."""
    users = ("fleet.api", "fleet.choreo", "fleet.teleop", "fleet.coordinator", "fleet.cli")
    for module in ("fleet.watch", "fleet.heartbeat"):
        assert [t for t in imports_of(module) if any(_within(t, u) for u in users)] == []


def test_the_inventory_is_below_the_security_runtime() -> None:
    """The security schema sits beside the inventory (``fleet.security_config``, importing no
    product module); access control, certificates and sessions (``fleet.security``) read an
    inventory, so neither the inventory nor the schema imports them."""
    assert imports_of("fleet.security_config") == frozenset()
    assert _violations("fleet.inventory", ("fleet.security",)) == []
    assert "fleet.inventory" in imports_of("fleet.security.acl")


@pytest.mark.parametrize(
    ("importer", "forbidden"),
    [
        ("fleet.d1", ("fleet.wire", "fleet.coordinator", "fleet.cli", "edge_agent", "viewer")),
        ("fleet.wire", ("fleet.coordinator", "fleet.cli", "fleet.client", "edge_agent", "viewer")),
        ("edge_agent", ("fleet.coordinator", "fleet.cli", "fleet.client", "fleet.api", "viewer")),
        ("viewer", ("fleet.coordinator", "edge_agent")),
        ("fleet", ("edge_agent", "viewer")),
    ],
)
def test_imports_point_one_way(importer: str, forbidden: tuple[str, ...]) -> None:
    assert _violations(importer, forbidden) == []


def test_nothing_reaches_back_into_the_agent() -> None:
    importers = sorted(m for m in _modules() if "edge_agent.agent" in imports_of(m))
    assert importers == ["edge_agent.__main__"]


def _circle_from(start: str) -> list[str] | None:
    """An import path from ``start`` back to itself, if there is one."""
    stack = [(start, [start])]
    seen: set[str] = set()
    while stack:
        module, path = stack.pop()
        for target in sorted(imports_of(module)):
            if target == start:
                return [*path, start]
            if target not in seen:
                seen.add(target)
                stack.append((target, [*path, target]))
    return None


def test_no_module_imports_itself_through_others() -> None:
    circles = []
    for module in _modules():
        if module.endswith("__main__"):
            continue
        circle = _circle_from(module)
        if circle is not None and not _through_a_package_init(circle):
            circles.append(" -> ".join(circle))
    assert circles == []


def _through_a_package_init(circle: list[str]) -> bool:
    """``fleet`` re-exports ``fleet.api`` in its ``__init__``: a package and its own modules
    naming each other is how Python packages work, not a circle of responsibilities."""
    return any(_modules()[m].name == "__init__.py" for m in circle)


KIND_PACKAGES = ("fleet.d1arm", "fleet.dex1", "fleet.g1")


@cache
def _loaded_by_name() -> dict[str, frozenset[str]]:
    """What is imported by name at run time (importlib): the registry loads every kind's
    ``kind.py`` (device kinds and served kinds), and each ``DeviceKind`` names its driver and
    simulator modules."""
    import importlib

    from fleet.devices.registry import KIND_MODULES, SERVED_MODULES

    edges = {"fleet.devices.registry": frozenset((*KIND_MODULES, *SERVED_MODULES))}
    for name in KIND_MODULES:
        kind = importlib.import_module(name).KIND
        edges[name] = frozenset(entry.partition(":")[0] for entry in (kind.agent, kind.sim))
    return edges


def test_the_kinds_loaded_by_name_exist_and_close_no_circle() -> None:
    """A kind is loaded by name; counting those loads as imports, nothing loops back (a kind
    imports ``fleet.devices.kind``, never the registry that loads it)."""
    loaded = _loaded_by_name()
    modules = _modules()
    assert all(target in modules for targets in loaded.values() for target in targets), loaded

    def targets(module: str) -> frozenset[str]:
        return imports_of(module) | loaded.get(module, frozenset())

    circles = []
    for start in modules:
        stack, seen = [(start, [start])], set()
        while stack:
            module, path = stack.pop()
            for target in sorted(targets(module)):
                if target == start and not _through_a_package_init([*path, start]):
                    circles.append(" -> ".join([*path, start]))
                elif target not in seen:
                    seen.add(target)
                    stack.append((target, [*path, target]))
    assert circles == []


@pytest.mark.parametrize("kind", KIND_PACKAGES)
def test_a_kind_never_imports_the_core_its_siblings_or_the_registry(kind: str) -> None:
    """Kinds are siblings below the agent core (``edge_agent``): the core serves them through
    the per-unit contract, they never reach up into it, into each other, or into the registry
    that loads their ``kind.py`` (the D1 arm's lists it as a served kind)."""
    siblings = tuple(k for k in KIND_PACKAGES if k != kind)
    forbidden = ("edge_agent", "viewer", "fleet.coordinator", "fleet.devices.registry", *siblings)
    assert _violations(kind, forbidden) == []
    if f"{kind}.kind" in _modules():
        assert "fleet.devices.registry" not in imports_of(f"{kind}.kind")


def test_every_kind_package_is_in_the_registry() -> None:
    """Every kind package below the core is loaded through the registry, which the walk and
    the import rules above then cover."""
    from fleet.devices.registry import KIND_MODULES, SERVED_MODULES

    listed = {name.rpartition(".")[0] for name in (*KIND_MODULES, *SERVED_MODULES)}
    assert listed == set(KIND_PACKAGES)


def test_the_core_names_no_kind() -> None:
    """``edge_agent/`` builds every kind from the registry: it imports no kind's package (a
    fourth kind is one package and one registry line, no line in the core)."""
    assert _violations("edge_agent", KIND_PACKAGES) == []


@pytest.mark.parametrize("folder", ["bench", "fuzz", "testkit"])
def test_tools_share_helpers_through_testkit_never_through_tests(folder: str) -> None:
    """``bench/``, ``fuzz/`` and the testing package import ``testkit``, never ``tests/``."""
    found = []
    for path in sorted((REPO / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            found += [f"{path.relative_to(REPO)}: {n}" for n in names if n.split(".")[0] == "tests"]
    assert found == []
