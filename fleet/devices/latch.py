"""The stop latch of one device (pure): what stopped it, its acknowledgment, and its reset.

The same contract as the arm's (README, Protective stop): a stop latches at once and refuses
every motion (4002) until an operator's reset; its action is written and repeated every
``REPEAT_S`` until the device's own state confirms it; the ack is published when acted on and
again when confirmed. Repeats of one ``stop_id`` are ignored.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from fleet.wire import messages as m

REPEAT_S = 0.2
"""The stop's action is written again this often until confirmed (a DDS sample can be lost)."""


@dataclass
class StopLatch:
    """One device's latch. Owned by its relay; read and changed under the relay's lock."""

    device: str
    action: str
    request: m.StopRequest | None = None
    received_ns: int = 0
    written_ns: int | None = None
    confirmed_ns: int | None = None
    last_write_s: float = 0.0
    detail: str | None = None

    @property
    def latched(self) -> bool:
        """A stop holds: motion is refused."""
        return self.request is not None

    @property
    def reason(self) -> str | None:
        """``stop_reason`` for the state payload."""
        if self.request is None:
            return None
        why = f": {self.request.reason}" if self.request.reason else ""
        return f"stopped by {self.request.source}{why}"

    def latch(self, request: m.StopRequest) -> bool:
        """Latch ``request``; False when it is a repeat of the stop already latched."""
        if self.request is not None and self.request.stop_id == request.stop_id:
            return False
        if self.request is None or self.confirmed_ns is not None:
            self.written_ns, self.confirmed_ns = None, None
        self.request, self.received_ns = request, time.time_ns()
        self.last_write_s = 0.0
        return True

    def due(self, now_s: float) -> bool:
        """The action should be written (again) now: latched, unconfirmed, repeat elapsed."""
        return (
            self.request is not None
            and self.confirmed_ns is None
            and now_s - self.last_write_s >= REPEAT_S
        )

    def written(self, now_s: float) -> None:
        """The action was written to DDS."""
        self.last_write_s = now_s
        if self.written_ns is None:
            self.written_ns = time.time_ns()

    def confirm(self) -> bool:
        """The device's state confirms the action; True the first time."""
        if self.request is None or self.confirmed_ns is not None or self.written_ns is None:
            return False
        self.confirmed_ns = time.time_ns()
        return True

    def reset(self) -> bool:
        """An operator's reset; True when something was latched."""
        was = self.request is not None
        self.request, self.written_ns, self.confirmed_ns, self.detail = None, None, None, None
        return was

    def ack(self) -> m.StopAck | None:
        """The acknowledgment of the latched stop (``arm`` carries the device id)."""
        if self.request is None:
            return None
        return m.StopAck(
            arm=self.device,
            stop_id=self.request.stop_id,
            action=self.action,
            received_ns=self.received_ns,
            dds_written_ns=self.written_ns,
            still_ns=self.confirmed_ns,
            detail=self.detail,
            confirmed_ns=self.confirmed_ns,
        )
