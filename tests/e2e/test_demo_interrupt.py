"""Ctrl-C in ``fleet demo``'s first seconds, as a terminal sends it: SIGINT to the demo's whole
process group, at four moments of its start-up. Every child must be gone within 3 s (within
the demo's patience once it runs: its dance, which may be engaging the G1's arms, gives them
back with their weight ramp first), with no traceback and exit code 0. Before: the children
got the SIGINT too (tracebacks from the middle of their imports), the demo went on starting
the rest, then waited 10 s for a router that the SIGINT had killed: 23-25 s, and 5 s once
running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleet.cli.processes import PATIENCE_S
from testkit.harness import free_port, wait_until
from tests.e2e.test_demo import REPO, _alive, _children_of, stop_demo

STARTING_STOPPED_WITHIN_S = 3.0
CHILDREN = 9
"""The demo's children with the repository's inventory: router, simulator, four agents (a1 with
its gripper, a2, a3, the G1), coordinator, dance, viewer."""


def _processes_naming(text: str) -> list[int]:
    """The live processes whose command line holds ``text`` (the demo's unique endpoint: every
    child gets it, even one started after the Ctrl-C)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if text in cmdline and _alive(int(entry.name)):
            found.append(int(entry.name))
    return found


@pytest.mark.timing
@pytest.mark.parametrize("moment", ["router", "half", "all started", "running"])
def test_ctrl_c_at_any_moment_of_start_up_stops_every_child_promptly(
    tmp_path: Path, dds_domain: int, moment: str
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "demo.out"
    with open(out, "wb") as sink:
        demo = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli.main", "demo", "--port", str(free_port())]
            + ["--for-s", "120", "--domain", str(dds_domain), "--endpoint", endpoint]
            + ["--inventory", str(REPO / "inventory.toml")],
            stdout=sink,
            stderr=subprocess.STDOUT,
            cwd=REPO,
            start_new_session=True,  # its own process group, as a shell's foreground job
        )
    try:
        if moment == "running":  # its intro printed: the viewer serves, the dance starts
            wait_until(lambda: "Ctrl-C stops the demo" in out.read_text(errors="replace"), 60.0)
        else:
            wanted = {"router": 1, "half": 4, "all started": CHILDREN}[moment]
            wait_until(lambda: len(_children_of(demo.pid)) >= wanted, 30.0, interval_s=0.01)
        started = time.monotonic()
        os.killpg(demo.pid, signal.SIGINT)  # what Ctrl-C in its terminal does
        code = demo.wait(timeout=30)
        wait_until(lambda: not _processes_naming(endpoint), 30.0, interval_s=0.02)
        took_s = time.monotonic() - started
        text = out.read_text(errors="replace")
        print(f"Ctrl-C at {moment}: demo and every child gone in {took_s:.2f} s")
        assert "Traceback" not in text, text[-3000:]
        assert code == 0, text[-3000:]
        bound_s = PATIENCE_S if moment == "running" else STARTING_STOPPED_WITHIN_S
        assert took_s < bound_s, text[-3000:]
    finally:
        stop_demo(demo)
        for pid in _processes_naming(endpoint):
            os.kill(pid, signal.SIGKILL)
