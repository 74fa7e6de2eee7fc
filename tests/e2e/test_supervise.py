"""``fleet demo``'s supervisor with real child processes and an injected clock."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

from fleet.cli.supervise import GIVE_UP_RESTARTS, Supervisor, how_it_ended


def _spawn(argv: list[str], **options: Any) -> subprocess.Popen[Any]:
    return subprocess.Popen([sys.executable, *argv], **options)


def test_a_child_that_keeps_dying_is_restarted_then_given_up_on() -> None:
    supervisor = Supervisor(_spawn)
    first = supervisor.start("agent of a1", ["-c", "import sys; sys.exit(3)"])
    first.wait(timeout=10)
    now, verdict, pids = 0.0, None, {first.pid}
    for _ in range(4 * GIVE_UP_RESTARTS):
        verdict = supervisor.check(now)
        if verdict is not None:
            break
        child = supervisor.children[0]
        if child.due_s is not None:
            now = child.due_s  # the back-off passes (the clock is ours)
        else:  # restarted: let it die again
            child.process.wait(timeout=10)
            pids.add(child.process.pid)
            now += 0.5
    assert verdict is not None and "agent of a1" in verdict and "exited with code 3" in verdict
    assert len(pids) == GIVE_UP_RESTARTS + 1, "restarted as many times as allowed, no more"


def test_a_healthy_child_is_left_alone_and_an_ending_is_named() -> None:
    supervisor = Supervisor(_spawn)
    sleeper = supervisor.start("router", ["-c", "import time; time.sleep(30)"])
    try:
        assert supervisor.check(0.0) is None and supervisor.check(100.0) is None
        assert supervisor.processes() == [sleeper]
    finally:
        sleeper.kill()
        sleeper.wait(timeout=10)
    assert how_it_ended(-9) == "killed by SIGKILL" and how_it_ended(1) == "exited with code 1"
