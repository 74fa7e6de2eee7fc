"""``fleet demo``'s first screen as a terminal shows it: the demo runs in a pseudo-terminal of
80x24 and of 160x40, its output is rendered by pyte (a VT100 emulator), and after a stop (whose
WARNING lines the children print) the screen holds the status block once, no line of it wider
than the terminal, and every log line intact above it. Before: the 129-column block wrapped on
80 columns and was printed again and again, and the redraw overwrote the WARNING lines.

Also: the dance's player, which a stop ends, is reaped (no ``<defunct>`` child of the demo).
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import signal
import struct
import subprocess
import sys
import termios
import threading
from collections.abc import Iterator
from pathlib import Path

import pyte
import pytest

from fleet.client import FleetClient
from fleet.inventory import load_inventory
from testkit.harness import free_port, wait_until
from tests.e2e.test_demo import REPO, _alive, _children_of, _cmdline, stop_demo

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")
HEADER = "arm      agent"


class Terminal:
    """A pty of ``cols`` x ``rows`` running ``argv``; its output rendered by pyte."""

    def __init__(self, argv: list[str], cols: int, rows: int) -> None:
        self.cols, self.rows = cols, rows
        self.screen = pyte.Screen(cols, rows)
        self.stream = pyte.ByteStream(self.screen)
        self.raw = bytearray()
        self._lock = threading.Lock()
        master, slave = pty.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
        env = {**os.environ, "TERM": "xterm", "COLUMNS": str(cols), "LINES": str(rows)}
        self.process = subprocess.Popen(
            argv, stdin=slave, stdout=slave, stderr=slave, cwd=REPO, env=env, close_fds=True
        )
        os.close(slave)
        self._master = master
        self._reader = threading.Thread(target=self._read, name="pty-reader", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self._master, 65536)
            except OSError:
                return  # the child closed the pty
            if not data:
                return
            with self._lock:
                self.raw += data
                self.stream.feed(data)

    def lines(self) -> list[str]:
        """The screen's rows as shown (trailing spaces cut)."""
        with self._lock:
            return [row.rstrip() for row in self.screen.display]

    def output_lines(self) -> list[str]:
        """Every line the program wrote, escape sequences removed."""
        with self._lock:
            text = self.raw.decode(errors="replace")
        return [ANSI.sub("", line).rstrip("\r") for line in text.split("\n")]

    def close(self) -> None:
        stop_demo(self.process)
        os.close(self._master)


@pytest.fixture(params=[(80, 24), (160, 40)], ids=["80x24", "160x40"])
def terminal(
    request: pytest.FixtureRequest, dds_domain: int
) -> Iterator[tuple[Terminal, FleetClient]]:
    cols, rows = request.param
    port, domain = free_port(), dds_domain
    endpoint = f"tcp/127.0.0.1:{port}"
    inventory_path = REPO / "inventory.toml"
    argv = [sys.executable, "-m", "fleet.cli.main", "demo", "--no-viewer", "--for-s", "120"]
    argv += ["--domain", str(domain), "--endpoint", endpoint, "--inventory", str(inventory_path)]
    term = Terminal(argv, cols, rows)
    children: list[int] = []
    try:
        wait_until(lambda: _children_of(term.process.pid), 10.0)
        children = _children_of(term.process.pid)
        inventory = load_inventory(inventory_path).with_endpoints([endpoint])
        with FleetClient(inventory, connect_timeout_s=20.0) as client:
            yield term, client
    finally:
        term.close()
        for pid in children:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


def block_rows(lines: list[str]) -> list[str]:
    """The rows of the status block: from its header to the end."""
    start = next(i for i, line in enumerate(lines) if line.startswith(HEADER))
    return lines[start:]


def test_the_demos_screen_keeps_its_block_once_and_its_log_lines_whole(
    terminal: tuple[Terminal, FleetClient],
) -> None:
    term, client = terminal

    def all_up() -> bool:
        lines = term.lines()
        rows = [ln for ln in lines if ln[:3] in ("a1 ", "a2 ", "a3 ")]
        return len(rows) == 3 and all(" up " in r and " ok " in r for r in rows)

    wait_until(all_up, 90.0)
    player = wait_until(
        lambda: next((p for p in _children_of(term.process.pid) if " play " in _cmdline(p)), None),
        30.0,
    )
    acks = client.estop(reason="screen test", timeout_s=5.0)
    assert all(acks.values()), acks

    def stopped_everywhere() -> bool:
        rows = [ln for ln in term.lines() if ln[:3] in ("a1 ", "a2 ", "a3 ")]
        return len(rows) == 3 and all(" YES " in r for r in rows)

    wait_until(stopped_everywhere, 15.0)
    warnings = [ln for ln in term.output_lines() if " WARNING " in ln]
    assert warnings, "the stop printed no WARNING line (the test would prove nothing)"
    # Two more redraws after the warnings arrived.
    drawn = term.output_lines().count(next(ln for ln in term.output_lines() if HEADER in ln))
    wait_until(lambda: sum(HEADER in ln for ln in term.output_lines()) >= drawn + 2, 10.0)

    lines = term.lines()
    assert sum(ln.startswith(HEADER) for ln in lines) == 1, "\n".join(lines)
    for arm in ("a1", "a2", "a3"):
        assert sum(ln.startswith(f"{arm} ") for ln in lines) == 1, "\n".join(lines)
    for row in block_rows(lines):
        assert len(row) < term.cols, f"a block line fills the width (it wraps): {row!r}"
    assert any("screen test" in row for row in block_rows(lines)), "\n".join(lines)
    # Every log line on the screen is a whole line the demo printed (or one of its wrapped
    # parts): no redraw wrote over it.
    printed = term.output_lines()
    parts = {
        line[k : k + term.cols].rstrip()
        for line in printed
        for k in range(0, max(1, len(line)), term.cols)
    }
    above = lines[: lines.index(block_rows(lines)[0])]
    for row in above:
        assert row == "" or row in parts, f"a log line was overwritten: {row!r}\n" + "\n".join(
            lines
        )
    assert any("WARNING" in row for row in above), "\n".join(lines)

    # The stop ended the dance's player: the demo reaped it (no zombie). Its ending waits for
    # the agents up to ENDING_S (5 s) plus the G1 arms' weight ramp, and the demo reaps every
    # 1-3 s: over 15 s on a loaded host (seen once in a fresh-clone run at load 5-8).
    wait_until(lambda: not Path(f"/proc/{player}").exists(), 30.0)
