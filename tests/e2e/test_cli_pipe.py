"""``fleet schema | head -1``: a reader that leaves early gives no traceback (a real child
process writing into a pipe smaller than its output)."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
F_SETPIPE_SZ = 1031


def test_a_closed_pipe_is_no_traceback() -> None:
    """``fleet schema | head -1``: the reader leaves after one line."""
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)  # smaller than the output: the writer blocks
    child = subprocess.Popen(
        [sys.executable, "-m", "fleet.cli.main", "schema"],
        stdout=write_end,
        stderr=subprocess.PIPE,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    os.close(write_end)
    with os.fdopen(read_end, "rb") as reader:
        assert reader.readline()
    _out, err = child.communicate(timeout=30)
    assert b"Traceback" not in err and b"BrokenPipeError" not in err, err.decode()
    assert child.returncode == 0
