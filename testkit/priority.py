"""Scheduling priority of a test worker: the tests that measure time run ahead of the rest.

``make test`` runs more pytest workers than the machine has cores, because most end-to-end
tests spend their time waiting for a simulated arm to move. A test that measures a latency, a
rate or a skew (the network lab, the browser, tests marked ``timing``) would then measure the
scheduler instead. So each worker sets its own niceness per test: ``FOREGROUND`` (0) for those,
``BACKGROUND`` for the rest; the processes a test starts inherit it. On Linux the nice value
belongs to each thread, so every thread of the worker is set (a zenoh runtime thread made
during a background test must not stay behind). Lowering a nice value needs root
(CAP_SYS_NICE): without it nothing is changed at all, so no timing test ever runs in the
background.
"""

from __future__ import annotations

import os

FOREGROUND = 0
BACKGROUND = 5
"""CFS weight 335 against 1024: a background worker keeps about a quarter of a contended core
(its waits for a moving arm stay well inside their timeouts) and a timing test the rest."""
FOREGROUND_GROUPS = ("netlab", "browser")


def can_reprioritize() -> bool:
    """True where a worker may lower its nice value again (root on Linux)."""
    return hasattr(os, "setpriority") and os.path.isdir("/proc/self/task") and os.geteuid() == 0


def set_worker_nice(nice: int) -> None:
    """Every thread of this process at ``nice`` (threads that end meanwhile are skipped)."""
    for task in os.listdir("/proc/self/task"):
        try:
            os.setpriority(os.PRIO_PROCESS, int(task), nice)
        except (ProcessLookupError, PermissionError):
            continue


def nice_for(group: str | None, timing: bool) -> int:
    """The nice value a test runs at: its xdist group's or its ``timing`` mark's."""
    return FOREGROUND if timing or group in FOREGROUND_GROUPS else BACKGROUND
