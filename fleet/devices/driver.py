"""The contract between the agent core (``edge_agent/``) and a device kind's driver.

The core owns everything a stop promises, for every kind: the ordered intake, the latch (one set
of rules, persisted), leases, the watchdog, ordering, one write lock per device, replies,
``diag``, metrics and ``info/``. A driver brings only what is its device's own: its DDS readers
and writers (created once, on the core's start-up thread, on the core's one participant), how
to decode its state, how to check and write a command, what its stop action is, and when its
state shows that action done.

The core calls a driver from three threads:
- ``relay``: ``on_data(index, now_s)`` when ``readers[index]`` has samples, ``tick(now_s)`` when
  the time it returned last comes (then ``stop_confirmed``, ``still``);
- ``commands``: ``execute(command, now_s, done)`` under the device's write lock, after the core
  checked the envelope (principal, order, lifetime, lease) and the latch;
- ``safety``: ``stop_started`` and ``write_stop`` under the device's write lock, ``stop_cleared``
  on a reset.
It publishes its state and events through ``Put`` (the core owns the Zenoh session) and reads
the latch only through ``LatchView`` (the core's, for its state payload). A driver never
imports the core.

Trust: any participant on a device's DDS network can write its state topics. A driver takes a
state sample only from the device's own writer (``fleet/origin/trust.py``, the rule an arm's
feedback follows: the device's host, and on it the first writer of each state topic; the
``WriterDirectory`` the core shares names a writer's host); other samples are counted
(``foreign``) and never reach the relay, grip detection, a hold's target or a stop's
confirmation.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from fleet.devices.base import DeviceReply
from fleet.origin.trust import OriginFilter
from fleet.wire import messages as m
from fleet.wire.payloads import PayloadKind

if TYPE_CHECKING:  # a type only: the CLI and the coordinator never load DDS through it
    from fleet.origin.directory import WriterDirectory

Put = Callable[[str, bytes, bool], None]
"""(device channel, JSON payload, reliable: BLOCK and REAL_TIME, else DROP)."""
LatchView = Callable[[], "tuple[bool, str | None, str | None]"]
"""(latched, why, watched_by) of the device's stop latch and watchdog, as the core holds them
(for the state payload)."""
Done = Callable[[DeviceReply], None]
"""Answers a command the driver completes later (an RPC answered on the relay thread)."""


class Refusal(Exception):
    """A command refused, by the core's envelope checks or by a kind (its driver, its plan):
    ``code`` (``fleet.wire.messages.ErrorCode``) and why."""

    def __init__(self, code: m.ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class DriverHealth:
    """What a driver knows about its link, for the core's ``diag`` and metrics."""

    link: str
    samples: int
    bad_samples: int
    relayed: int
    rate_hz: float
    age_s: float | None
    commands: int
    rejected: int
    timeouts: int
    last_error: str | None
    foreign: int = 0
    """State samples from a writer that is not the device's own (dropped)."""
    implausible: int = 0
    """Readings that moved faster than the device can (dropped)."""


class DeviceDriver(Protocol):
    """One device's own logic (see the module docstring)."""

    device: str
    readers: list[Any]
    stop_action: str
    commands: PayloadKind[Any]

    def on_data(self, index: int, now_s: float) -> None:
        """Take and handle every sample of ``readers[index]``."""

    def tick(self, now_s: float) -> float:
        """Periodic work (publishing at the relay rate, polling, link watch); returns when it
        wants the next tick (monotonic seconds)."""

    def execute(self, command: Any, now_s: float, done: Done) -> DeviceReply | None:
        """Check and write one decoded command; the reply, or None when ``done`` will be
        called later (bounded: the driver times it out). Raises ``Refusal``."""

    def moves(self, command: Any) -> bool:
        """``command`` sets the device moving (the watchdog watches its owner)."""

    def allowed_while_latched(self, command: Any) -> bool:
        """``command`` may run under a latched stop (it is a way to a safe state)."""

    def stop_started(self, now_s: float) -> None:
        """A new stop latched: its confirmation starts over."""

    def write_stop(self, now_s: float) -> tuple[bool, str | None]:
        """Write the stop action now: (written, detail for the ack: why it was not written or
        cannot be confirmed yet)."""

    def stop_confirmed(self, now_s: float) -> bool:
        """The device's own state shows the stop action done, after its first write."""

    def stop_cleared(self) -> None:
        """The latch was reset (the device stays as the stop left it)."""

    def still(self) -> bool | None:
        """The device does not move (None: unknown); the watchdog's owner check."""

    def leave(self, now_s: float) -> None:
        """The agent exits: start what the device needs before nobody commands it (a G1 hands
        its arms back to the robot); the relay thread still runs."""

    def wait_left(self) -> bool:
        """Wait (bounded, by the driver) until what ``leave`` started is done; True if it is."""

    def health(self, now_s: float) -> DriverHealth:
        """Link and counters since start."""


class DriverBase:
    """What every driver shares: its device id, put, latch view, the lock over its readings and
    counters, the DDS sample rate and which state writers are the device's own."""

    def __init__(
        self,
        device: str,
        put: Put,
        latch: LatchView,
        counters: tuple[str, ...],
        stale_s: float,
        directory: WriterDirectory,
    ) -> None:
        self.device = device
        self._stale_s = stale_s
        self._directory = directory
        self._origins = OriginFilter(f"device {device!r}", stale_s)
        """The device's own state writers (relay thread only)."""
        self._latest: tuple[Any, float] | None = None
        """The newest reading and when it arrived (monotonic s); the kind fills it in."""
        self._put = put
        self._latch = latch
        self._lock = threading.Lock()
        self._counts = dict.fromkeys(
            (
                "dds_samples",
                "bad_samples",
                "relayed",
                "commands",
                "rejected",
                "timeouts",
                "foreign",
                "implausible",
                *counters,
            ),
            0,
        )
        self._rate_window = (time.monotonic(), 0)
        self._rate_hz = 0.0
        self._last_error: str | None = None
        self._stop_written_s: float | None = None
        """When the current stop's action was first written (None: not yet, or no stop)."""

    def _from_the_device(self, reader: Any, handle: int, topic: str, now_s: float) -> bool:
        """Whether the writer ``handle`` of a sample on ``reader`` (its ``topic``, a periodic
        state) is the device's own; a foreign sample is counted, its reason kept as the last
        error (relay thread)."""
        writer = self._directory.identify(reader, handle)
        why = self._origins.refusal(writer, topic, True, now_s)
        if why is None:
            return True
        with self._lock:
            self._counts["foreign"] += 1
            self._last_error = why
        return False

    def _update_rate(self, now_s: float) -> None:
        """The DDS sample rate over the last second (caller holds ``_lock``)."""
        start, count = self._rate_window
        if now_s - start >= 1.0:
            samples = self._counts["dds_samples"]
            self._rate_hz = (samples - count) / (now_s - start)
            self._rate_window = (now_s, samples)

    def _refuse(self, code: m.ErrorCode, message: str) -> Refusal:
        with self._lock:
            self._last_error = message[:1000]
        return Refusal(code, message)

    def stop_started(self, now_s: float) -> None:
        """A new stop: its action's first write starts the confirmation."""
        with self._lock:
            self._stop_written_s = None

    def stop_cleared(self) -> None:
        """A reset: nothing to confirm any more."""
        with self._lock:
            self._stop_written_s = None

    def leave(self, now_s: float) -> None:
        """Nothing to do at the agent's exit (a kind that has something overrides it)."""

    def wait_left(self) -> bool:
        """Nothing to wait for."""
        return True

    def health(self, now_s: float) -> DriverHealth:
        """Link (from the newest reading's age: ``_latest`` is (reading, received_s)) and
        counters."""
        with self._lock:
            latest = self._latest
        age_s = None if latest is None else now_s - latest[1]
        stale = age_s is not None and age_s > self._stale_s
        link = "lost" if age_s is None else ("stale" if stale else "ok")
        with self._lock:
            c = self._counts
            return DriverHealth(
                link=link,
                samples=c["dds_samples"],
                bad_samples=c["bad_samples"],
                relayed=c["relayed"],
                rate_hz=round(self._rate_hz, 1),
                age_s=None if age_s is None else round(age_s, 3),
                commands=c["commands"],
                rejected=c["rejected"],
                timeouts=c["timeouts"],
                last_error=self._last_error,
                foreign=c["foreign"],
                implausible=c["implausible"],
            )

    def counters(self) -> dict[str, int]:
        """Counters since start."""
        with self._lock:
            return dict(self._counts)


def error_reply(device: str, code: m.ErrorCode, message: str) -> DeviceReply:
    """A refusal with one of the arm's error codes."""
    return DeviceReply(ok=False, device=device, error=m.ErrorInfo(int(code), message[:1000]))
