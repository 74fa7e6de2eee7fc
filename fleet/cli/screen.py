"""``fleet demo``'s terminal: log lines above, the status block redrawn below, never interleaved.

On a terminal, the block is redrawn in place once a second: the cursor goes back to the block's
first line (``ESC[nF``), everything below is cleared (``ESC[J``), the log lines that arrived
since (the children's output, the demo's own logging) are printed, then the block. Every line
of the block is cut to the terminal's width, so the number of lines printed is the number of
lines on the screen and the cursor goes back exactly over the block (a 129-column line wrapped
on an 80-column terminal and the block was printed again and again). Not a terminal: log lines
and blocks are printed as they come, nothing is redrawn.

The block's own layout for a width (fewer columns, angles folded) is ``fleet.cli.status``'s.
"""

from __future__ import annotations

import io
import shutil
import subprocess
import threading
from collections.abc import Callable
from typing import Any, TextIO


def clip(line: str, width: int) -> str:
    """``line`` cut to ``width - 1`` characters (the last column left free: a line that fills
    the width makes some terminals wrap), ``…`` marking the cut."""
    room = max(1, width - 1)
    return line if len(line) <= room else line[: room - 1] + "…"


class Screen:
    """The demo's output. ``log(line)`` from any thread; ``draw(block)`` from the demo's loop."""

    def __init__(
        self, out: TextIO, width: Callable[[], int] | None = None, tty: bool | None = None
    ) -> None:
        self.out = out
        self.tty = out.isatty() if tty is None else tty
        self._width = width or (lambda: shutil.get_terminal_size((100, 24)).columns)
        self._lock = threading.Lock()  # guards _pending and _printed, and orders the writes
        self._pending: list[str] = []
        self._printed = 0

    def width(self) -> int:
        """The terminal's width now (it may change between two draws)."""
        return max(20, self._width())

    def log(self, line: str) -> None:
        """A log line: printed at once when not a terminal, else above the next block."""
        line = line.rstrip("\r\n")
        with self._lock:
            if not self.tty or not self._printed:
                self.out.write(line + "\n")
                self.out.flush()
            else:
                self._pending.append(line)

    def draw(self, block: list[str]) -> None:
        """Print ``block`` (lines already laid out for ``width()``) below the log lines."""
        width = self.width()
        with self._lock:
            parts = []
            if self.tty and self._printed:
                parts.append(f"\033[{self._printed}F\033[J")  # back over the old block, clear
            # A log line may wrap: it scrolls with the rest, and the block comes after it.
            parts += [line + "\n" for line in self._pending]
            self._pending.clear()
            lines = [clip(line, width) for line in block] if self.tty else block
            parts += [line + "\n" for line in lines]
            self.out.write("".join(parts))
            self.out.flush()
            self._printed = len(lines)

    def follow(self, process: subprocess.Popen[Any], on_line: Callable[[str], None]) -> None:
        """Read ``process``'s piped output on a thread of its own: each line to ``on_line``
        first (the demo looks for the viewer's URL), then to ``log``."""
        stream = process.stdout
        assert stream is not None

        def read() -> None:
            for line in stream:
                text = line if isinstance(line, str) else line.decode(errors="replace")
                on_line(text)
                self.log(text)

        threading.Thread(target=read, name=f"output-{process.pid}", daemon=True).start()


class LogStream(io.TextIOBase):
    """A text stream whose complete lines go to ``screen.log`` (the demo's own logging, which
    writes to whatever ``sys.stderr`` is, while the status block is on the screen)."""

    def __init__(self, screen: Screen) -> None:
        super().__init__()
        self._screen = screen
        self._partial = ""

    def write(self, text: str) -> int:
        """Buffer ``text``; hand each complete line to the screen."""
        lines = (self._partial + text).split("\n")
        self._partial = lines.pop()
        for line in lines:
            self._screen.log(line)
        return len(text)

    def isatty(self) -> bool:
        return False
