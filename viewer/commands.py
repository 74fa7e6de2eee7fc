"""What the viewer sends: STOP ALL, reset, and jog (``move_joint``) commands.

Jogs go through ``FleetClient.command`` on the viewer's own ``viewer-jog`` thread: a slider
callback only records the newest target per (arm, joint) and returns (latest wins: dragging a
slider never queues up a backlog of moves). Stops are put at once, from the caller's thread (a
viser callback thread, never a Zenoh one), with congestion control BLOCK and priority
REAL_TIME, and repeated twice with the same ``stop_id`` by the ``viewer-stop`` thread: Zenoh's
reliability is hop by hop, and agents ignore a stop id they have seen.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable

import zenoh

from fleet.client import JSON, FleetClient
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.inventory import Inventory
from fleet.wire import keys
from fleet.wire import messages as m

log = logging.getLogger("viewer.commands")

STOP_REPEAT_S = (0.1, 0.3)
"""Delays (after the first put) of the repeats of a stop."""

Notify = Callable[[str, str, bool], None]
"""``notify(title, body, is_error)``: show a notification in every connected browser."""


def clamp_to_limits(joint: int, angle_deg: float) -> float:
    """``angle_deg`` clamped to wire joint ``joint``'s documented range."""
    low, high = JOINT_RANGE_DEG[joint]
    return min(max(angle_deg, low), high)


class Commander:
    """The viewer's outgoing side on the key space. A context manager; ``close()`` idempotent."""

    def __init__(self, inventory: Inventory, session: zenoh.Session, notify: Notify) -> None:
        self.keys = keys.KeySpace(inventory.fleet)
        self.client = FleetClient(inventory, session=session)
        self._notify = notify
        self._estop = session.declare_publisher(
            self.keys.estop,
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.REAL_TIME,
        )
        self._reset = session.declare_publisher(
            self.keys.reset,
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.DATA_HIGH,
        )
        self._lock = threading.Lock()  # guards _pending only
        self._pending: dict[tuple[str, int], float] = {}
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._repeats: queue.SimpleQueue[tuple[float, bytes] | None] = queue.SimpleQueue()
        self.stops_sent = 0
        self._threads = [
            threading.Thread(target=self._jog_loop, name="viewer-jog", daemon=True),
            threading.Thread(target=self._stop_loop, name="viewer-stop", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    # ------------------------------------------------------------------ stop and reset

    def stop_all(self, reason: str = "STOP ALL pressed in the viewer") -> m.StopRequest:
        """Put a fleet-wide StopRequest now, and queue its repeats. Drops pending jogs."""
        with self._lock:
            self._pending.clear()
        request = m.StopRequest(
            stamp_ns=time.time_ns(), source="viewer", stop_id=uuid.uuid4().hex, reason=reason
        )
        payload = m.encode(request)
        self._estop.put(payload)
        self.stops_sent += 1
        now = time.monotonic()
        for delay in STOP_REPEAT_S:
            self._repeats.put((now + delay, payload))
        log.warning("STOP ALL sent (stop_id %s)", request.stop_id)
        return request

    def reset_all(self) -> m.ResetRequest:
        """Put a fleet-wide ResetRequest (the operator confirmed it)."""
        request = m.ResetRequest(stamp_ns=time.time_ns(), source="viewer")
        self._reset.put(m.encode(request))
        log.warning("reset sent to the whole fleet")
        return request

    def _stop_loop(self) -> None:
        try:
            while True:
                item = self._repeats.get()
                if item is None:
                    return
                due, payload = item
                if self._closing.wait(max(0.0, due - time.monotonic())):
                    return
                self._estop.put(payload)
        except Exception:
            log.exception("the viewer-stop thread failed")
            raise

    # ------------------------------------------------------------------ jog

    def jog(self, arm: str, joint: int, angle_deg: float) -> None:
        """Ask for ``arm``'s ``joint`` at ``angle_deg`` (clamped); returns at once."""
        with self._lock:
            self._pending[(arm, joint)] = clamp_to_limits(joint, angle_deg)
        self._wake.set()

    def _jog_loop(self) -> None:
        try:
            while not self._closing.is_set():
                if not self._wake.wait(0.2):
                    continue
                self._wake.clear()
                with self._lock:
                    batch, self._pending = self._pending, {}
                for (arm, joint), angle in batch.items():
                    if self._closing.is_set():
                        return
                    self._send_jog(arm, joint, angle)
        except Exception:
            log.exception("the viewer-jog thread failed")
            raise

    def _send_jog(self, arm: str, joint: int, angle_deg: float) -> None:
        reply = self.client.command(arm, m.MoveJoint(joint=joint, angle_deg=angle_deg))
        if reply.ok:
            return
        why = reply.error.message if reply.error else "refused"
        log.warning("jog of %s joint %d to %.1f deg failed: %s", arm, joint, angle_deg, why)
        self._notify(f"{arm}: move_joint {joint} failed", why, True)

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Stop the threads (join with a timeout), then undeclare the publishers."""
        if self._closing.is_set():
            return
        self._closing.set()
        self._wake.set()
        self._repeats.put(None)
        for thread in self._threads:
            thread.join(timeout=5.0)
        self._estop.undeclare()
        self._reset.undeclare()

    def __enter__(self) -> Commander:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
