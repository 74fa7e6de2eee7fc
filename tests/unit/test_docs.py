"""The documentation keeps up with the code: the architecture map lists every package and module
of the product, and the CLI reference every command with every option its parser has.

Both read the tree and the parsers at run time, so a module that moves or a new option fails here
naming what the docs lack. No network, no processes.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from edge_agent.__main__ import build_parser as build_agent_parser
from fleet.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[2]
ARCHITECTURE = ROOT / "docs" / "design" / "architecture.md"
CLI = ROOT / "docs" / "guide" / "cli.md"
PRODUCT = ("fleet", "edge_agent", "viewer")
COMMON_HEADING = "Common options"


def _sections(text: str, level: str) -> dict[str, str]:
    """Heading line (without the hashes) -> the text under it, up to the next heading of ``level``
    or higher."""
    out: dict[str, str] = {}
    heading, lines = "", []
    depth = len(level)
    for line in text.splitlines():
        match = re.match(r"^(#+) (.*)$", line)
        if match and len(match.group(1)) <= depth:
            out[heading] = "\n".join(lines)
            heading, lines = match.group(2), []
        else:
            lines.append(line)
    out[heading] = "\n".join(lines)
    return out


def _packages() -> dict[str, list[str]]:
    """Every package of the product (``fleet/wire/``) -> its modules' file names."""
    found: dict[str, list[str]] = {}
    for top in PRODUCT:
        for init in sorted((ROOT / top).rglob("__init__.py")):
            package = init.parent
            if "__pycache__" in package.parts:
                continue
            name = package.relative_to(ROOT).as_posix() + "/"
            found[name] = sorted(p.name for p in package.glob("*.py"))
    return found


def test_the_architecture_map_lists_every_package_and_module() -> None:
    sections = _sections(ARCHITECTURE.read_text(encoding="utf-8"), "###")
    missing: list[str] = []
    for package, modules in _packages().items():
        heading = next((h for h in sections if f"`{package}`" in h), None)
        if heading is None:
            missing.append(f"{package} (no '### `{package}`: its job' heading)")
            continue
        body = sections[heading]
        missing += [f"{package}{m}" for m in modules if f"| `{m}` |" not in body]
    assert not missing, f"{ARCHITECTURE.relative_to(ROOT)} lacks: " + ", ".join(missing)


def test_the_architecture_map_lists_nothing_that_is_gone() -> None:
    """A module row in a package's section names a file that exists (after a move, the old row
    goes)."""
    sections = _sections(ARCHITECTURE.read_text(encoding="utf-8"), "###")
    stale: list[str] = []
    for package in _packages():
        heading = next((h for h in sections if f"`{package}`" in h), None)
        if heading is None:
            continue
        for module in re.findall(r"^\| `([\w.]+\.py)` \|", sections[heading], re.M):
            if not (ROOT / package / module).exists():
                stale.append(package + module)
    assert not stale, f"{ARCHITECTURE.relative_to(ROOT)} lists modules that are gone: {stale}"


def _commands(
    parser: argparse.ArgumentParser, prefix: str
) -> list[tuple[str, argparse.ArgumentParser]]:
    """``("fleet sim fault", parser)`` for every sub-command, nested ones included."""
    out: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append((f"{prefix} {name}", sub))
                out += _commands(sub, f"{prefix} {name}")
    return out


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {o for action in parser._actions for o in action.option_strings}


def _common_options() -> set[str]:
    """The options of `fleet status` that are documented once, under "Common options"."""
    parser = dict(_commands(build_parser(), "fleet"))["fleet status"]
    return _options(parser) - {"--json", "--watch"}


def test_every_fleet_command_and_option_is_in_the_cli_reference() -> None:
    text = CLI.read_text(encoding="utf-8")
    sections = _sections(text, "###")
    common = _common_options()
    assert COMMON_HEADING in sections, f"{CLI.name} has no '## {COMMON_HEADING}'"
    missing = [o for o in sorted(common) if f"`{o}" not in sections[COMMON_HEADING]]
    for command, parser in _commands(build_parser(), "fleet"):
        heading = f"`{command}`"
        if heading not in sections:
            missing.append(f"{command} (no '### {heading}' heading)")
            continue
        body = sections[heading]
        undocumented = sorted(o for o in _options(parser) - common if f"`{o}" not in body)
        missing += [f"{command} {o}" for o in undocumented]
        # the option column of its tables names only options its parser has
        for cell in re.findall(r"^\| (`-.*?) \|", body, re.M):
            missing += [
                f"{command} documents {o}, which its parser lacks"
                for o in re.findall(r"`(--?[\w-]+)", cell)
                if o not in _options(parser)
            ]
    assert not missing, f"{CLI.relative_to(ROOT)}: " + ", ".join(missing)


def test_edge_agent_options_are_in_the_cli_reference() -> None:
    sections = _sections(CLI.read_text(encoding="utf-8"), "###")
    body = sections["`edge-agent`"]
    common = _common_options()
    missing = [o for o in sorted(_options(build_agent_parser()) - common) if f"`{o}" not in body]
    assert not missing, f"{CLI.relative_to(ROOT)}, edge-agent lacks: {missing}"
