"""Every process stops cleanly on SIGTERM, also when its router stops at the same moment (a
host shutting down, a supervisor stopping a whole site): exit code 0 within seconds.

Zenoh's close waits up to 10 s for a link whose router is gone: every secure process (its QUIC
datagram session) hung 10 s at each stop and was killed by the test harness (exit -9), and a
supervisor would have waited as long. Real processes: router, simulator, an arms' agent, a
devices' agent (a gripper on the arm, a G1) and the coordinator, plain and with mutual TLS.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from testkit.harness import HUNG_AT_SHUTDOWN, FleetHarness, wait_until

DEVICES = '[grippers.gl]\nmount = "a1"\nagent = "agent-lo"\n\n[g1.h1]\nagent = "agent-lo"\n'
STOPPED_WITHIN_S = 6.0
"""A session's close may take 2 s (``fleet.wire.session.CLOSE_WAIT_S``), a datagram session's
1 s, and the rest of a shutdown well under a second on a quiet host: 6 s leaves room for a
loaded one, and is far from the 10 s Zenoh would wait."""


@pytest.mark.parametrize("security", ["none", "mtls"])
def test_every_process_exits_0_within_seconds_when_its_router_stops_with_it(
    tmp_path: Path, security: str
) -> None:
    with FleetHarness(tmp_path, extra=DEVICES, security=security) as h:
        h.start_router()
        h.start_sim()
        h.start_agent()
        h.start(
            "devices",
            ["-m", "edge_agent", "--principal", "agent-lo", "--device", "gl", "--device", "h1"],
        )
        h.start_coordinator()
        client = h.client()
        up = lambda: all(s is not None for s in client.device_snapshot(wait_s=1.0).values())  # noqa: E731
        try:
            wait_until(up, 40.0)
            wait_until(lambda: h.all_links_ok(client), 30.0)
            wait_until(lambda: client.fleet_state(wait_s=1.0) is not None, 20.0)
        except AssertionError:
            raise AssertionError(h.diagnose(client) + h.log("devices")[-3000:]) from None
        client.close()
        started = time.monotonic()
        processes = dict(h.processes)
        for process in processes.values():  # the router first: it is the first one started
            process.send_signal(signal.SIGTERM)
        exits: dict[str, tuple[int | None, float]] = {}
        deadline = started + STOPPED_WITHIN_S
        while len(exits) < len(processes) and time.monotonic() < deadline:
            for name, process in processes.items():
                if name not in exits and process.poll() is not None:
                    exits[name] = (process.returncode, round(time.monotonic() - started, 2))
            time.sleep(0.02)
        hung = sorted(set(processes) - set(exits))
        logs = {name: h.log(name)[-1500:] for name in hung}
        assert not hung, f"still running {STOPPED_WITHIN_S:g} s after SIGTERM: {hung}\n{logs}"
        failed = {name: e for name, e in exits.items() if e[0] != 0}
        assert not failed, f"exit codes: {exits}\n" + "\n".join(h.log(n)[-1500:] for n in failed)


STUCK_AT_SHUTDOWN = """
import sys, threading, time
from fleet.runtime import shutdown_event
stop = shutdown_event(bound_s=float(sys.argv[1]))
print("ready", flush=True)
stop.wait(30)

def stuck_close():  # a close that never returns, as a library call could
    threading.Event().wait(60)

stuck_close()
"""


def test_a_process_stuck_at_shutdown_prints_where_and_exits_within_its_bound() -> None:
    """The bound every process has from its first SIGTERM (``fleet.runtime.SHUTDOWN_BOUND_S``;
    here 0.5 s): a shutdown stuck in a call exits with code 1 and every thread's stack on
    stderr, naming the call, instead of waiting for a supervisor's SIGKILL."""
    with subprocess.Popen(
        [sys.executable, "-c", STUCK_AT_SHUTDOWN, "0.5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as process:
        try:
            assert process.stdout is not None and process.stdout.readline() == "ready\n"
            started = time.monotonic()
            process.send_signal(signal.SIGTERM)
            _out, stderr = process.communicate(timeout=10.0)
            took_s = time.monotonic() - started
            code = process.returncode
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate()
    print(f"stuck at shutdown: exit {code} after {took_s:.2f} s")
    assert code == 1, stderr
    assert 0.5 <= took_s < 5.0, took_s
    assert HUNG_AT_SHUTDOWN.search(stderr), stderr
    assert "stuck_close" in stderr, stderr


SIGNAL_WHILE_WAITING = """
import os, signal, sys
from fleet.runtime import shutdown_event
stop = shutdown_event(bound_s=None)
# The moment the suite once hit: the main thread inside stop.wait(), holding the lock that
# Event.set() takes, when the signal handler runs. Held here on purpose (CPython's Event keeps
# it in _cond), the signal sent, and the handler run, all while it is held.
stop._cond.acquire()
os.kill(os.getpid(), signal.SIGTERM)
for _ in range(1000):  # bytecodes: the handler runs at one of them
    pass
stop._cond.release()
print("set" if stop.wait(5.0) else "not set", flush=True)
"""


def test_a_signal_while_the_main_thread_holds_the_events_lock_still_stops_it() -> None:
    """A signal handler runs in the main thread between two bytecodes, which may be inside
    ``Event.wait`` with the Event's lock held: a handler that set the Event itself deadlocked
    there (a simulator in a suite run, stopped only by its shutdown bound). The Event is set by
    the signal relay's thread instead (``fleet.runtime._SignalRelay``): the handler returns at
    once, and the Event is set once the lock is free."""
    result = subprocess.run(
        [sys.executable, "-c", SIGNAL_WHILE_WAITING],
        capture_output=True,
        text=True,
        timeout=20.0,
    )
    assert result.returncode == 0 and result.stdout == "set\n" and not result.stderr, result
