"""A thread that dies takes its process down safely: the agent latches and stops every arm and
exits 1; the coordinator stops its heartbeat at once (the agents' watchdogs then hold what it
commanded) and exits 1. No zombie that looks healthy.

The agent and the coordinator run in this process, through their real ``main`` (real DDS, real
Zenoh, a real router and simulator in subprocesses); the failure is injected by patching one
method of one thread to raise, the only thing here that is not the product itself.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

import edge_agent.__main__ as agent_main
from edge_agent.device_server import DeviceServer
from edge_agent.inbox import SafetyInbox
from edge_agent.serving import CommandService
from edge_agent.stops import SafetyLoop
from fleet.cli import main as fleet_main
from fleet.client import FleetClient
from fleet.coordinator.service import Coordinator
from fleet.d1arm.tracker import ArmTracker
from fleet.dex1.messages import GripperHold
from fleet.dex1.relay import GripperDriver
from fleet.g1.relay import G1Driver
from fleet.guard import EXIT_THREAD_FAILED, ThreadGuard
from fleet.wire import keys
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until
from testkit.kinds import DEVICES

# ----------------------------------------------------------------------------- the guard


def test_the_guard_reports_once_and_never_reraises() -> None:
    failures: list[str] = []
    guard = ThreadGuard("test", failures.append)

    def boom() -> None:
        raise RecursionError("deep")

    thread = guard.thread(boom, "worker")
    thread.start()
    thread.join(timeout=5.0)
    assert guard.failed.wait(5.0)
    assert len(failures) == 1 and "worker" in failures[0] and "RecursionError" in failures[0]
    assert guard.wrap(boom, "callback")() is None  # a callback's failure is reported, not raised
    assert len(failures) == 1  # on_failure runs once


def test_a_failing_failure_handler_still_sets_failed() -> None:
    def handler(_what: str) -> None:
        raise OSError("cannot even hold")

    guard = ThreadGuard("test", handler)
    guard.fail("somewhere", ValueError("x"))
    assert guard.failed.wait(5.0)


# ----------------------------------------------------------------------------- processes


def _after(calls: int, method: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` that raises on its ``calls``-th call (the thread ran normally until then)."""
    count = [0]

    def patched(*args: Any, **kwargs: Any) -> Any:
        count[0] += 1
        if count[0] >= calls:
            raise RuntimeError("injected failure")
        return method(*args, **kwargs)

    return patched


@contextmanager
def _main_thread_signals(give_up_s: float) -> Iterator[None]:
    """Run a process's main() here: restore the signal handlers after, and SIGTERM ourselves
    if it has not returned in ``give_up_s`` (so a missed failure fails the test, never hangs)."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    timer = threading.Timer(give_up_s, lambda: os.kill(os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        for sig, handler in saved.items():
            signal.signal(sig, handler)


class _Seen:
    """Statuses and stop acks of the fleet, as a client sees them."""

    def __init__(self, client: FleetClient) -> None:
        self.statuses: list[m.ArmStatus] = []
        self.acks: list[m.StopAck] = []
        self.beats: list[float] = []
        decode = __import__("msgspec").json.decode
        session = client.session
        self._subs = [
            session.declare_subscriber(
                client.keys.all_arms(keys.STATUS),
                lambda s: self.statuses.append(decode(s.payload.to_bytes(), type=m.ArmStatus)),
            ),
            session.declare_subscriber(
                client.keys.all_arms(keys.ESTOP_ACK),
                lambda s: self.acks.append(decode(s.payload.to_bytes(), type=m.StopAck)),
            ),
            session.declare_subscriber(
                client.keys.heartbeat, lambda _s: self.beats.append(time.monotonic())
            ),
        ]

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


INJECTIONS: dict[str, tuple[type, str, int]] = {
    "relay": (ArmTracker, "on_feedback", 40),
    "safety": (SafetyLoop, "_tick", 40),
    "relay-periodic-jobs": (ArmTracker, "diag", 3),
    "commands": (CommandService, "_handle", 1),
    "zenoh-callback": (SafetyInbox, "on_heartbeat", 1),
}


@pytest.mark.parametrize("thread", sorted(INJECTIONS))
def test_a_failed_agent_thread_latches_every_arm_and_exits_1(
    fleet_harness: FleetHarness, monkeypatch: pytest.MonkeyPatch, thread: str
) -> None:
    h = fleet_harness
    h.start_router()
    h.start_sim()
    client = h.client()
    seen = _Seen(client)
    owner, name, calls = INJECTIONS[thread]
    monkeypatch.setattr(owner, name, _after(calls, getattr(owner, name)))
    monkeypatch.setenv("D1_FLEET_STATE_DIR", str(h.tmp_path / "state"))

    def trigger() -> None:  # what makes the patched method run, for the event-driven ones
        wait_until(lambda: any(s.link == "ok" for s in seen.statuses), 20.0)
        if thread == "commands":
            client.command("a1", m.Hold())
        if thread == "zenoh-callback":
            beat = m.Heartbeat(time.time_ns(), "test", 1, 0.1)
            client.session.put(client.keys.heartbeat_of(client.principal), m.encode(beat))

    threading.Thread(target=trigger, daemon=True).start()
    with _main_thread_signals(give_up_s=40.0):
        code = agent_main.main(["--inventory", str(h.inventory_path), "--arm", "a1"])
    seen.close()
    assert code == EXIT_THREAD_FAILED
    failure_acks = [a for a in seen.acks if a.stop_id.startswith("agent-failure")]
    assert failure_acks, f"no stop was acknowledged before the agent exited: {seen.acks}"
    assert any(s.estopped and "agent thread failed" in (s.stop_reason or "") for s in seen.statuses)


def test_a_failed_coordinator_thread_stops_the_heartbeat_and_exits_1(
    fleet_harness: FleetHarness, monkeypatch: pytest.MonkeyPatch
) -> None:
    h = fleet_harness
    h.start_router()
    client = h.client()
    seen = _Seen(client)
    monkeypatch.setattr(Coordinator, "_apply_control", _after(1, Coordinator._apply_control))

    stopped_at: list[float] = []

    def trigger() -> None:
        wait_until(lambda: len(seen.beats) >= 5, 20.0)
        stopped_at.append(time.monotonic())
        client.put_stop(client.stop_request(source="test"))

    threading.Thread(target=trigger, daemon=True).start()
    argv = ["coordinator", "--inventory", str(h.inventory_path)]
    with _main_thread_signals(give_up_s=40.0):
        code = fleet_main.main(argv)
    seen.close()
    assert code == EXIT_THREAD_FAILED
    assert len(seen.beats) >= 5
    # The events thread died on the stop: not one heartbeat after its failure (before the
    # fix, the heartbeat went on and kept every agent's watchdog satisfied).
    late = [t for t in seen.beats if t > stopped_at[0] + 0.2]
    assert not late, f"{len(late)} heartbeats after the coordinator's thread failed"


DEVICE_INJECTIONS: dict[str, tuple[type, str, int]] = {
    "gripper-driver": (GripperDriver, "tick", 40),
    "g1-driver": (G1Driver, "on_data", 40),
    "device-commands": (DeviceServer, "serve", 1),
}


@pytest.mark.parametrize("thread", sorted(DEVICE_INJECTIONS))
def test_a_failed_thread_latches_every_arm_and_device_of_the_agent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, thread: str
) -> None:
    """One agent serving an arm, its gripper and a G1: a failure in a device's path (its
    driver on the relay thread, its command) latches all three, and the agent exits 1."""
    with FleetHarness(tmp_path, arms=1, extra=DEVICES) as h:
        h.start_router()
        h.start_sim()
        client = h.client()
        acks: dict[str, list[m.StopAck]] = {}
        decode = __import__("msgspec").json.decode

        def on_ack(sample: Any) -> None:
            unit = str(sample.key_expr).split("/")[-3]
            acks.setdefault(unit, []).append(decode(sample.payload.to_bytes(), type=m.StopAck))

        sub = client.session.declare_subscriber(f"{client.keys.prefix}/*/*/estop/ack", on_ack)
        owner, name, calls = DEVICE_INJECTIONS[thread]
        monkeypatch.setattr(owner, name, _after(calls, getattr(owner, name)))
        monkeypatch.setenv("D1_FLEET_STATE_DIR", str(h.tmp_path / "state"))

        def trigger() -> None:  # the command thread fails on the first device command
            if thread == "device-commands":
                token = client.keys.device("gripper", "gl", keys.AGENT)
                liveliness = client.session.liveliness()
                wait_until(lambda: any(r.ok for r in liveliness.get(token, timeout=1.0)), 20.0)
                client.device_command("gl", GripperHold(), timeout_s=1.0)  # never answered

        threading.Thread(target=trigger, daemon=True).start()
        argv = ["--inventory", str(h.inventory_path), "--interface", "lo"]
        with _main_thread_signals(give_up_s=40.0):
            code = agent_main.main(argv)
        sub.undeclare()
    assert code == EXIT_THREAD_FAILED
    failed = {
        unit
        for unit, seen in acks.items()
        if any(a.stop_id.startswith("agent-failure") for a in seen)
    }
    assert failed == {"a1", "gl", "h1"}, acks
