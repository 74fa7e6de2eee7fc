"""The contract between the agent's device host (``edge_agent/devices.py``) and a kind's relay.

A relay owns one device's DDS readers and writers (created once, at start-up, on the host's
thread), its stop latch and its edge logic. The host calls it from three threads:
- ``relay``: ``on_data(index, now_s)`` when ``readers[index]`` has samples (then ``tick``), and
  ``tick(now_s)`` when the time it returned last comes (publishing at the relay rate, polling
  readers it does not want waited on, repeating stop actions, link watch);
- ``commands``: ``command(payload, principal)`` for each query (it may block on an RPC reply,
  bounded);
- ``safety``: ``stop(request)`` and ``reset()``.
It publishes through ``Put`` (channel, payload, reliable): the host owns the Zenoh session.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from fleet.devices.base import DeviceReply
from fleet.devices.latch import StopLatch
from fleet.wire import keys
from fleet.wire import messages as m

Put = Callable[[str, bytes, bool], None]
"""(device channel, JSON payload, reliable: BLOCK and REAL_TIME, else DROP)."""


class DeviceRelay(Protocol):
    """One device's edge logic (see the module docstring)."""

    device: str
    readers: list[Any]

    def on_data(self, index: int, now_s: float) -> None:
        """Take and handle every sample of ``readers[index]`` (the readers waited on)."""

    def tick(self, now_s: float) -> float:
        """Periodic work; returns when it wants the next tick (monotonic seconds; the host
        ticks at least every ``TICK_MAX_S`` anyway)."""

    def command(self, payload: bytes, principal: str) -> DeviceReply:
        """Check and execute one command; the reply."""

    def stop(self, request: m.StopRequest, repeat_ack: bool = True) -> None:
        """Latch ``request`` and act on it at once; a repeat of the latched stop is
        acknowledged again only with ``repeat_ack``."""

    def reset(self) -> None:
        """Release the latch (never moves the device)."""

    def counters(self) -> dict[str, int]:
        """Diagnostics since start."""


def error_reply(device: str, code: m.ErrorCode, message: str) -> DeviceReply:
    """A refusal with one of the arm's error codes."""
    return DeviceReply(ok=False, device=device, error=m.ErrorInfo(int(code), message))


class LatchedRelay:
    """What every kind's relay shares: its device id, its put, its two locks, the stop latch
    and the time its action was first written, the counters and the DDS sample rate; refusals,
    ``stop``, ``reset`` and ``counters``. A kind derives from it and writes its own stop action
    in ``_write_stop_action`` (a gripper's hold, a G1's ``stop_move`` or ``damp``).

    ``_lock`` guards the newest reading, the latch, the counters and the rate (copied under
    it, published after); ``_write`` serializes DDS writes with the latch decision, so nothing
    checked before a stop is written after the stop's own action (the arm's rule)."""

    def __init__(self, device: str, action: str, put: Put, counters: tuple[str, ...]) -> None:
        self.device = device
        self._put = put
        self._lock = threading.Lock()
        self._write = threading.Lock()
        self._latch = StopLatch(device, action)
        self._action_written_s: float | None = None
        """When the latched stop's action was first written (None: not yet, or no stop)."""
        self._counts = dict.fromkeys(("dds_samples", "bad_samples", "rejected", *counters), 0)
        self._rate_window = (time.monotonic(), 0)
        self._rate_hz = 0.0

    def _write_stop_action(self, now_s: float) -> None:
        raise NotImplementedError

    def _update_rate(self, now_s: float) -> None:
        """The DDS sample rate over the last second (caller holds ``_lock``)."""
        start, count = self._rate_window
        if now_s - start >= 1.0:
            samples = self._counts["dds_samples"]
            self._rate_hz = (samples - count) / (now_s - start)
            self._rate_window = (now_s, samples)

    def _put_ack(self, ack: m.StopAck | None) -> None:
        if ack is not None:
            self._put(keys.ESTOP_ACK, m.encode(ack), True)

    def _refuse(self, code: m.ErrorCode, message: str) -> DeviceReply:
        with self._lock:
            self._counts["rejected"] += 1
        return error_reply(self.device, code, message)

    def stop(self, request: m.StopRequest, repeat_ack: bool = True) -> None:
        """Latch and act at once (repeated by ``tick`` until the state confirms it)."""
        with self._lock:
            new = self._latch.latch(request)
            if new and self._latch.written_ns is None:
                self._action_written_s = None
        if new:
            self._write_stop_action(time.monotonic())
        elif repeat_ack:
            with self._lock:
                ack = self._latch.ack()
            self._put_ack(ack)

    def reset(self) -> None:
        """Release the latch (never moves the device: it stays as the stop left it)."""
        with self._lock:
            self._latch.reset()
            self._action_written_s = None

    def counters(self) -> dict[str, int]:
        """Counters since start."""
        with self._lock:
            return dict(self._counts)
