"""The viewer's picture of the fleet: the newest sample per arm, fed by Zenoh subscribers.

Zenoh callbacks run on Zenoh threads. They only decode and store the newest payload per arm
(latest wins, nothing queues up) and return; the viewer's own thread takes ``snapshot()`` copies
at its render rate. ``_lock`` guards the arrays and dicts below it, never any I/O.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import zenoh

from fleet.d1.limits import JOINT_COUNT
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m

log = logging.getLogger("viewer.state")

STALE_S = 1.0
"""No joints for this long (at the viewer) and the arm is drawn stale (grey)."""


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of the fleet's latest state, arms in inventory order."""

    arms: tuple[str, ...]
    angles_deg: npt.NDArray[np.float64]  # (N, 7), the newest joints (zeros before the first)
    joints_age_s: npt.NDArray[np.float64]  # (N,), seconds since the viewer got joints (inf: never)
    status: tuple[m.ArmStatus | None, ...]
    online: npt.NDArray[np.bool_]  # (N,), the agent's liveliness token is present
    contact: npt.NDArray[np.bool_] | None = None  # (N, 7), joint in confirmed contact

    def contact_rows(self) -> npt.NDArray[np.bool_]:
        """(N, 7) joints in confirmed contact (all False before any contact event)."""
        if self.contact is None:
            return np.zeros((len(self.arms), JOINT_COUNT), dtype=bool)
        return self.contact

    @property
    def stale(self) -> npt.NDArray[np.bool_]:
        """(N,) no fresh joints, or the agent reports the arm's link not ok."""
        link_bad = np.array([s is not None and s.link != "ok" for s in self.status], dtype=bool)
        return (self.joints_age_s > STALE_S) | link_bad

    @property
    def estopped(self) -> npt.NDArray[np.bool_]:
        """(N,) the agent reports the arm stopped (latched)."""
        return np.array([s is not None and s.estopped for s in self.status], dtype=bool)

    @property
    def error(self) -> npt.NDArray[np.bool_]:
        """(N,) the arm reports an error."""
        return np.array([s is not None and bool(s.error) for s in self.status], dtype=bool)


class ViewerFleet:
    """Latest joints, status and agent liveliness of every inventory arm. A context manager."""

    def __init__(
        self,
        inventory: Inventory,
        session: zenoh.Session,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.keys = keys.KeySpace(inventory.fleet)
        self.arms = tuple(inventory.arms)
        self._index = {arm: i for i, arm in enumerate(self.arms)}
        self._clock = clock
        self._session = session
        n = len(self.arms)
        self._lock = threading.Lock()
        # Guarded by _lock:
        self._angles = np.zeros((n, JOINT_COUNT))
        self._joints_at = np.full(n, -math.inf)
        self._status: list[m.ArmStatus | None] = [None] * n
        self._online = np.zeros(n, dtype=bool)
        self._contact = np.zeros((n, JOINT_COUNT), dtype=bool)
        self.malformed = 0  # payloads we could not decode (counted, dropped)
        self._last_warning = -math.inf
        self._handles: list[zenoh.Subscriber[None]] = []

    def start(self, guard: ThreadGuard | None = None) -> None:
        """Declare the subscribers (liveliness with history: tokens already present count);
        with ``guard``, a callback's unexpected failure fails the viewer instead of vanishing."""

        def wrap(callback: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], object]:
            return callback if guard is None else guard.wrap(callback, "viewer-state")

        on_sample = wrap(self._on_sample)
        self._handles = [
            self._session.declare_subscriber(self.keys.all_arms(channel), on_sample)
            for channel in (keys.JOINTS, keys.STATUS, keys.CONTACT)
        ]
        self._handles.append(
            self._session.liveliness().declare_subscriber(
                self.keys.all_arms(keys.AGENT), wrap(self._on_token), history=True
            )
        )

    # ------------------------------------------------------------------ zenoh callbacks

    def _arm_index(self, sample: zenoh.Sample) -> int | None:
        try:
            return self._index.get(self.keys.parse_arm_key(str(sample.key_expr)).arm)
        except keys.KeyError_:
            return None

    def _bad(self, what: str, exc: Exception) -> None:
        with self._lock:
            self.malformed += 1
            now = self._clock()
            if now - self._last_warning < 10.0:
                return
            self._last_warning = now
        log.warning("dropped a malformed %s payload (%s); %d so far", what, exc, self.malformed)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Joints, status or contact of an inventory arm, decoded through the channel table."""
        try:
            key = self.keys.parse_arm_key(str(sample.key_expr))
        except keys.KeyError_:
            return
        i = self._index.get(key.arm)
        if i is None:
            return
        try:
            payload = payloads.decode(key.channel, sample.payload.to_bytes())
        except payloads.PayloadError as exc:
            self._bad(key.channel, exc)
            return
        if isinstance(payload, m.Joints):
            self._on_joints(i, payload)
        elif isinstance(payload, m.ArmStatus):
            with self._lock:
                self._status[i] = payload
        elif isinstance(payload, m.ContactEvent):
            self._on_contact(i, payload)

    def _on_joints(self, i: int, joints: m.Joints) -> None:
        row = np.asarray(joints.angles_deg, dtype=float)
        if row.shape != (JOINT_COUNT,) or not np.all(np.isfinite(row)):
            self._bad("joints", ValueError(f"{len(joints.angles_deg)} angles or non-finite"))
            return
        now = self._clock()
        with self._lock:
            self._angles[i] = row
            self._joints_at[i] = now

    def _on_contact(self, i: int, event: m.ContactEvent) -> None:
        if not 0 <= event.joint < JOINT_COUNT:
            self._bad("contact", ValueError(f"joint {event.joint}"))
            return
        with self._lock:
            self._contact[i, event.joint] = event.state == "confirmed"

    def _on_token(self, sample: zenoh.Sample) -> None:
        i = self._arm_index(sample)
        if i is None:
            return
        with self._lock:
            self._online[i] = sample.kind == zenoh.SampleKind.PUT

    # ------------------------------------------------------------------ readers

    def snapshot(self) -> Snapshot:
        """Copy the newest state (cheap: a few small arrays and a tuple of references)."""
        now = self._clock()
        with self._lock:
            angles = self._angles.copy()
            joints_at = self._joints_at.copy()
            status = tuple(self._status)
            online = self._online.copy()
            contact = self._contact.copy()
        return Snapshot(
            arms=self.arms,
            angles_deg=angles,
            joints_age_s=now - joints_at,
            status=status,
            online=online,
            contact=contact,
        )

    def close(self) -> None:
        """Undeclare the subscribers (idempotent); the session belongs to the caller."""
        handles, self._handles = self._handles, []
        for handle in handles:
            handle.undeclare()

    def __enter__(self) -> ViewerFleet:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
