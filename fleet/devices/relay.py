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

from collections.abc import Callable
from typing import Any, Protocol

from fleet.devices.base import DeviceReply
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
