"""Scheduling priority of a test worker: the tests that measure time run ahead of the rest.

``make test`` runs more pytest workers than the machine has cores, because most end-to-end
tests spend their time waiting for a simulated arm to move. A test that measures a latency, a
rate or a skew (the network lab, the browser, tests marked ``timing``) would then measure the
scheduler instead. So each worker moves itself per test into the foreground or the background;
the processes a test starts inherit it. Two mechanisms, the first where it exists:

- **A background CPU group** (cgroup v1 ``cpu``, made by the controller for the run): every
  thread of a background test and of the processes it starts is in one group with
  ``BACKGROUND_SHARES``, so the background as a whole, however many threads it runs, gets
  about a fifth of a contended core against the foreground. Measured: with nice values alone
  (a per-thread weight) two background fleets of ~60 threads outweighed one timing test's
  processes, and a synchronized start's skew reached 147 ms (goal 25) with three workers.
- **Nice values** (``FOREGROUND`` / ``BACKGROUND``): on Linux they belong to each thread, so
  every thread of the worker is set (a zenoh runtime thread made during a background test must
  not stay behind).

Both need root (CAP_SYS_NICE, the cgroup files): without it nothing is changed at all, so no
timing test ever runs in the background.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

FOREGROUND = 0
BACKGROUND = 5
"""CFS weight 335 against 1024 for each background thread (used where no CPU group can be
made, and inside the group)."""
FOREGROUND_GROUPS = ("netlab", "browser")

CPU_CGROUPS = Path("/sys/fs/cgroup/cpu")
"""cgroup v1's ``cpu`` controller (cgroup v2 moves threads only in threaded groups: not used)."""
BACKGROUND_SHARES = 256
"""Against 1024 for the foreground: 20 % of a core both want. Enough for a background fleet's
heartbeats (a 0.5 s watchdog) when a browser test's Chromium takes a whole core, far less
than ~60 threads at nice 5 take from a timing test."""
GROUP_ENV = "D1_FLEET_TEST_CPU_GROUP"
"""Where the controller tells its workers the background group's directory."""


def can_reprioritize() -> bool:
    """True where a worker may lower its nice value again (root on Linux)."""
    return hasattr(os, "setpriority") and os.path.isdir("/proc/self/task") and os.geteuid() == 0


def _own_cpu_group() -> Path | None:
    """This process's cgroup v1 ``cpu`` directory, or None (no such hierarchy)."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if "cpu" in controllers.split(","):
            group = CPU_CGROUPS / path.lstrip("/")
            return group if (group / "tasks").is_file() else None
    return None


def make_background_group(run: str) -> Path | None:
    """The controller's: a background group beside its own for this run, or None (no root, no
    cgroup v1 ``cpu``); its path is put in the environment the workers inherit."""
    own = _own_cpu_group() if can_reprioritize() else None
    if own is None:
        return None
    group = own / f"d1-fleet-tests-{run}"
    try:
        group.mkdir(exist_ok=True)
        (group / "cpu.shares").write_text(str(BACKGROUND_SHARES))
    except OSError:
        return None
    os.environ[GROUP_ENV] = str(group)
    return group


def remove_background_group(group: Path) -> None:
    """The controller's, at the end: whatever is still in the group back to its parent, then
    the group removed (a process a test leaked is stopped by the test that started it)."""
    parent = group.parent / "tasks"
    with contextlib.suppress(OSError):
        for task in (group / "tasks").read_text().split():
            with contextlib.suppress(OSError):
                parent.write_text(task)
        group.rmdir()


def _move_threads(tasks: Path) -> None:
    for task in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):
            tasks.write_text(task)


def set_worker_priority(foreground: bool) -> None:
    """Every thread of this worker in the foreground or the background (threads that end
    meanwhile are skipped)."""
    group = os.environ.get(GROUP_ENV)
    if group:
        _move_threads(Path(group).parent / "tasks" if foreground else Path(group) / "tasks")
    set_worker_nice(FOREGROUND if foreground else BACKGROUND)


def set_worker_nice(nice: int) -> None:
    """Every thread of this process at ``nice`` (threads that end meanwhile are skipped)."""
    for task in os.listdir("/proc/self/task"):
        try:
            os.setpriority(os.PRIO_PROCESS, int(task), nice)
        except (ProcessLookupError, PermissionError):
            continue


def in_foreground(group: str | None, timing: bool) -> bool:
    """Whether a test runs in the foreground: its xdist group's or its ``timing`` mark's."""
    return timing or group in FOREGROUND_GROUPS
