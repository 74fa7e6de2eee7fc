"""``--log-file`` and ``--log-format`` (issue 16): real processes append JSON lines to one file,
a bad path is one line and exit 2, logrotate's move is followed (WatchedFileHandler)."""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
from collections.abc import Iterator
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from edge_agent.__main__ import parse_args
from fleet.cli.main import build_parser
from fleet.cli.processes import _common_argv
from fleet.inventory import load_inventory
from fleet.runtime import setup_logging
from testkit.harness import FleetHarness, wait_until

FIELDS = {"time", "level", "logger", "thread", "message", "role", "pid"}


def _records(path: Path) -> list[dict[str, object]]:
    """Every line of ``path`` as a JSON object with the documented fields (else the test fails
    naming the line)."""
    records = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        record = json.loads(line)
        assert set(record) >= FIELDS, f"line {number} lacks {FIELDS - set(record)}: {line}"
        stamp = datetime.fromisoformat(str(record["time"]))
        assert stamp.utcoffset() == timedelta(0), f"line {number} is not UTC: {line}"
        records.append(record)
    return records


def test_router_and_agent_append_json_lines_to_one_file(tmp_path: Path) -> None:
    log_file = tmp_path / "fleet.log"
    options = ["--log-file", str(log_file), "--log-format", "json"]
    with FleetHarness(tmp_path) as fleet:
        fleet.start_router(*options)
        fleet.start("agent", ["-m", "edge_agent", "--arm", "a1", *options])

        def agent_serving() -> bool:
            return log_file.exists() and '"serving arms a1' in log_file.read_text("utf-8")

        wait_until(agent_serving, timeout_s=20.0)
        assert fleet.stop("agent") == 0, fleet.log("agent")
        assert fleet.stop("router") == 0, fleet.log("router")
        # The log went to the file, not to stderr (the harness's capture of the output).
        assert "serving arms" not in fleet.log("agent")
        assert "listening on" not in fleet.log("router")
    records = _records(log_file)
    roles = {r["role"] for r in records}
    assert roles == {"router", "agent"}, records
    pids = {r["role"]: r["pid"] for r in records}
    assert pids["router"] == fleet.processes["router"].pid
    assert pids["agent"] == fleet.processes["agent"].pid
    stopped = [r for r in records if r["role"] == "agent" and r["message"] == "stopped"]
    assert stopped and stopped[0]["level"] == "INFO" and stopped[0]["thread"] == "MainThread"
    assert any(r["logger"] == "edge_agent" for r in records)


@pytest.mark.parametrize(
    ("argv", "bad"),
    [
        (["-m", "fleet.cli.main", "router"], "missing/dir/router.log"),
        (["-m", "edge_agent", "--arm", "a1"], "."),  # a directory
    ],
)
def test_bad_log_file_is_one_line_and_exit_2(tmp_path: Path, argv: list[str], bad: str) -> None:
    inventory = Path(__file__).resolve().parents[2] / "inventory.toml"
    path = tmp_path / bad
    done = subprocess.run(
        [sys.executable, *argv, "--inventory", str(inventory), "--log-file", str(path)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "cannot open" in lines[0], done.stderr


@pytest.fixture
def root_logging() -> Iterator[None]:
    """setup_logging changes the root logger: put it back as pytest had it."""
    root = logging.getLogger()
    handlers, level, hook = list(root.handlers), root.level, sys.excepthook
    yield
    for handler in root.handlers:
        if handler not in handlers:
            handler.close()
    root.handlers[:] = handlers
    root.setLevel(level)
    sys.excepthook = hook


def test_json_lines_escape_newlines_carry_tracebacks_and_follow_logrotate(
    tmp_path: Path, root_logging: None
) -> None:
    path = tmp_path / "x.log"
    setup_logging("INFO", str(path), "json", role="viewer")
    log = logging.getLogger("fleet.test")
    log.info("two\nlines")
    try:
        raise ValueError("boom")
    except ValueError:
        log.exception("failed")
    path.rename(tmp_path / "x.log.1")  # what logrotate does (without copytruncate)
    log.warning("after the rotation")
    setup_logging("INFO", str(path), "json", role="viewer")  # again: our handler is replaced
    log.info("once")
    first, moved = _records(tmp_path / "x.log.1"), _records(path)
    assert [r["message"] for r in first] == ["two\nlines", "failed"]
    assert "ValueError: boom" in str(first[1]["exc"]) and first[1]["level"] == "ERROR"
    assert [r["message"] for r in moved] == ["after the rotation", "once"]
    assert {r["role"] for r in first + moved} == {"viewer"}


def test_demo_passes_its_log_options_to_its_children() -> None:
    inventory = load_inventory(Path(__file__).resolve().parents[2] / "inventory.toml")
    args = argparse.Namespace(inventory="inventory.toml", log_file="demo.log", log_format="json")
    argv = _common_argv(args, inventory)
    assert argv[argv.index("--log-file") + 1] == "demo.log"
    assert argv[argv.index("--log-format") + 1] == "json"
    args = argparse.Namespace(inventory="inventory.toml", log_file=None, log_format="text")
    assert "--log-file" not in _common_argv(args, inventory)


@pytest.mark.parametrize(
    "command", ["router", "sim", "coordinator", "viewer", "foxglove", "record", "demo", "play"]
)
def test_every_long_running_command_takes_the_log_options(command: str) -> None:
    args = build_parser().parse_args([command, "--log-file", "f.log", "--log-format", "json"])
    assert (args.log_file, args.log_format) == ("f.log", "json")


def test_edge_agent_takes_the_log_options() -> None:
    args = parse_args(["--arm", "a1", "--log-file", "f.log", "--log-format", "json"])
    assert (args.log_file, args.log_format) == ("f.log", "json")
