"""The harness's fork server starts processes as Popen would: argv, environment, working
directory, output, standard input, exit codes and signals (``testkit.forkserver``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from testkit.forkserver import PRELOAD, ForkServer
from testkit.harness import wait_until
from testkit.priority import can_reprioritize


@pytest.fixture
def server() -> ForkServer:
    server = ForkServer()
    yield server
    server.close()


def _said(log: Path) -> dict[str, object]:
    return json.loads(log.read_text().splitlines()[0])


def test_the_imports_start_no_thread_so_forking_is_safe() -> None:
    code = (
        "import os, threading\n"
        f"for name in {PRELOAD!r}: __import__(name)\n"
        "print(threading.active_count(), len(os.listdir('/proc/self/task')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"], out


def test_a_child_runs_the_module_with_its_argv_env_cwd_and_log(
    server: ForkServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "child.log"
    log.write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    env = {**os.environ, "FORKSERVER_MARKER": "m-1"}
    nice = os.getpriority(os.PRIO_PROCESS, 0)
    bump = 3 if can_reprioritize() else 0  # putting it back needs root
    os.setpriority(os.PRIO_PROCESS, 0, nice + bump)  # a nice value the server never had
    try:
        process = server.start(["-m", "tests.e2e.forkserver_child", "exit", "3"], str(log), env)
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    assert process.wait(timeout=30.0) == 3
    said = _said(log)
    assert said == {
        "argv": ["exit", "3"],
        "cwd": str(tmp_path),
        "marker": "m-1",
        "stdin": "",
        "threads": 1,
        "main": "__main__",
        "nice": nice + bump,
    }
    assert "to stderr" in log.read_text()
    assert process.poll() == 3


def test_a_signal_and_a_kill_are_seen_as_popen_reports_them(
    server: ForkServer, tmp_path: Path
) -> None:
    logs = [tmp_path / "a.log", tmp_path / "b.log"]
    for log in logs:
        log.write_bytes(b"")
    handled = server.start(["-m", "tests.e2e.forkserver_child", "wait", "0"], str(logs[0]), {})
    killed = server.start(["-m", "tests.e2e.forkserver_child", "wait", "0"], str(logs[1]), {})
    assert handled.pid != killed.pid
    wait_until(lambda: all(log.read_text() for log in logs), 30.0)
    assert handled.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        handled.wait(timeout=0.1)
    handled.send_signal(signal.SIGTERM)
    killed.kill()
    assert handled.wait(timeout=30.0) == 7
    assert killed.wait(timeout=30.0) == -signal.SIGKILL
    killed.kill()  # a process that ended is never signalled again


def _state(pid: int) -> str | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return None


def test_an_ended_childs_pid_stays_held_until_its_code_is_collected(
    server: ForkServer, tmp_path: Path
) -> None:
    """A harness's SIGTERM-then-SIGCONT raced a child's exit: the server had reaped it before
    the client heard of it, so the SIGCONT found no process (and a reused PID could have been
    another one). As with Popen, the PID is freed only when the client has the code."""
    log = tmp_path / "c.log"
    log.write_bytes(b"")
    process = server.start(["-m", "tests.e2e.forkserver_child", "exit", "0"], str(log), {})
    assert wait_until(lambda: server.exit_code(process.pid, 0.0) is not None, 30.0)
    assert _state(process.pid) == "Z"  # reported, not reaped
    os.kill(process.pid, signal.SIGCONT)  # what send_signal does when its poll lost the race
    assert process.poll() == 0
    assert wait_until(lambda: _state(process.pid) is None, 30.0)
    process.send_signal(signal.SIGCONT)  # collected: never signalled again
