"""``fleet demo``'s children, kept running: a child that exits is reported (which one, its code
or signal) and restarted with back-off; the demo gives up, and exits non-zero, when one keeps
dying. Meanwhile the fleet shows its arm offline, as for any agent that is gone."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

BACKOFF_S = (1.0, 2.0, 4.0, 8.0, 16.0)
"""Wait before the 1st, 2nd, ... restart of one child."""
GIVE_UP_RESTARTS = 5
"""More restarts than this within GIVE_UP_WINDOW_S and the demo gives up."""
GIVE_UP_WINDOW_S = 120.0

Spawn = Callable[..., "subprocess.Popen[Any]"]


def how_it_ended(returncode: int) -> str:
    """``exited with code 1`` or ``killed by SIGKILL``."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exited with code {returncode}"


@dataclass
class Child:
    """One supervised process."""

    name: str
    argv: list[str]
    process: subprocess.Popen[Any]
    restarts: list[float] = field(default_factory=list)
    due_s: float | None = None


class Supervisor:
    """Restarts the demo's children; ``check`` once a second from the demo's loop."""

    def __init__(self, spawn: Spawn, say: Callable[[str], None] | None = None) -> None:
        self._spawn = spawn
        self._say = say
        self.children: list[Child] = []

    def start(self, name: str, argv: list[str], **options: Any) -> subprocess.Popen[Any]:
        """Start and supervise ``argv`` (``options`` apply to the first start only)."""
        process = self._spawn(argv, **options)
        self.children.append(Child(name, argv, process))
        return process

    def check(self, now: float) -> str | None:
        """Report and restart children that ended; why it gave up, or None."""
        for child in self.children:
            if child.due_s is not None:
                if now >= child.due_s:
                    child.due_s = None
                    child.restarts.append(now)
                    child.process = self._spawn(child.argv)
                    self._report(f"fleet demo: {child.name} restarted (PID {child.process.pid})")
                continue
            code = child.process.poll()
            if code is None:
                continue
            recent = [t for t in child.restarts if now - t <= GIVE_UP_WINDOW_S]
            ended = how_it_ended(code)
            if len(recent) >= GIVE_UP_RESTARTS:
                return (
                    f"{child.name} (PID {child.process.pid}) {ended} again after "
                    f"{len(recent)} restarts in {GIVE_UP_WINDOW_S:g} s; giving up"
                )
            wait_s = BACKOFF_S[min(len(recent), len(BACKOFF_S) - 1)]
            child.due_s = now + wait_s
            self._report(
                f"fleet demo: {child.name} (PID {child.process.pid}) {ended}; "
                f"restarting it in {wait_s:g} s"
            )
        return None

    def _report(self, text: str) -> None:
        """To the demo's screen (above its status block), else stderr."""
        if self._say is not None:
            self._say(text)
        else:
            print(text, file=sys.stderr, flush=True)

    def processes(self) -> list[subprocess.Popen[Any]]:
        """Every child's current process, in start order."""
        return [child.process for child in self.children]

    def current(self) -> dict[str, subprocess.Popen[Any]]:
        """Each child's current process (a restart replaces it) by name."""
        return {child.name: child.process for child in self.children}


def stop_children(stages: list[list[subprocess.Popen[Any]]], patience_s: float) -> None:
    """Stop the children by PID, stage after stage: SIGTERM a stage's children at once and wait
    for them before the next stage (the commanders first, so they hold what they moved while
    the agents still listen, and the router last, which everyone's shutdown talks through: a
    player whose agents were gone waited 5 s for them). One deadline, ``patience_s`` from now,
    for all: a child still running then (one still starting, its shutdown handler not yet
    reached) is SIGKILLed."""
    deadline = time.monotonic() + patience_s
    for stage in stages:
        _terminate(stage, deadline)


def _terminate(children: list[subprocess.Popen[Any]], deadline: float) -> None:
    """SIGTERM ``children``, wait for them until ``deadline``, SIGKILL the rest and reap them."""
    for child in children:
        if child.poll() is None:
            child.terminate()
    for child in children:
        try:
            child.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
    for child in children:
        try:
            child.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            print(
                f"fleet demo: could not stop PID {child.pid} ({' '.join(child.args[1:4])}); "
                "stop it by hand",
                file=sys.stderr,
            )
