"""The viewer's picture of the fleet: the newest sample per arm, fed by Zenoh subscribers (live)
or by a recording (``fleet viewer --replay``, viewer/replay.py), through one ``ingest`` path.

Zenoh callbacks run on Zenoh threads. They only decode and store the newest payload per arm
(latest wins, nothing queues up) and return; the viewer's own thread takes ``snapshot()`` copies
at its render rate. ``_lock`` guards the arrays and dicts below it, never any I/O. Transitions
(a stop latched or released, a contact, a refusal, an agent gone or back) and the stop and reset
requests seen on the key space, for the fleet, its arms and its devices, also go to the bounded
event log (viewer/events.py); the choreography players' states to ``DanceTracker``
(viewer/dance.py).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import zenoh

from fleet.control import direct
from fleet.d1.limits import JOINT_COUNT
from fleet.devices import DeviceKind
from fleet.guard import ThreadGuard
from fleet.watch import UnitReport
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from viewer.dance import DanceTracker, DanceView
from viewer.events import (
    CONTACT,
    OFFLINE,
    ONLINE,
    REFUSED,
    RELEASED,
    RESET,
    STOP,
    EventLog,
    stop_timing_text,
)

log = logging.getLogger("viewer.state")

STALE_S = 1.0
"""No joints for this long (at the viewer) and the arm is drawn stale (grey)."""
REPLAY_ONLINE_S = 2.0
"""In a replay (no liveliness tokens were recorded), an arm is online while its agent's status
(4 Hz) is at most this old at the replay's position."""


@dataclass(frozen=True)
class DeviceView:
    """One device beside the arms as the viewer last heard it."""

    device: str
    kind: str
    mount: str  # the arm it is mounted on, "" standing alone
    state: Any  # the kind's state payload (GripperState, G1State), None before the first
    age_s: float  # seconds since that state arrived (inf: never)
    summary: str  # the kind's one line (``fleet status``'s)
    low: Any = None  # the kind's lowstate payload (a G1's G1LowState), None before the first
    low_age_s: float = math.inf  # seconds since that lowstate arrived


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of the fleet's latest state, arms in inventory order."""

    arms: tuple[str, ...]
    angles_deg: npt.NDArray[np.float64]  # (N, 7), the newest joints (zeros before the first)
    joints_age_s: npt.NDArray[np.float64]  # (N,), seconds since the viewer got joints (inf: never)
    status: tuple[m.ArmStatus | None, ...]
    online: npt.NDArray[np.bool_]  # (N,), the agent's liveliness token is present
    contact: npt.NDArray[np.bool_] | None = None  # (N, 7), joint in confirmed contact
    diag: tuple[m.Diag | None, ...] = ()  # the agents' newest counters (empty: none yet)
    devices: tuple[DeviceView, ...] = ()  # grippers, G1s: their newest state, in inventory order
    dances: tuple[DanceView, ...] = ()  # the choreography players heard of, newest first

    def diag_of(self, i: int) -> m.Diag | None:
        """Arm ``i``'s newest diag, None before the first."""
        return self.diag[i] if i < len(self.diag) else None

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


DEVICE_SHOWN = (keys.STATE, keys.LOWSTATE)
"""A device's channels the viewer shows: its state, and a G1's joints (``lowstate``)."""
CONTROL = (keys.ESTOP, keys.RESET)
"""Stop and reset requests: logged for the fleet, every arm and every device."""
INGESTED = frozenset((keys.JOINTS, keys.STATUS, keys.CONTACT, keys.DIAG, keys.ESTOP, keys.RESET))
"""The channels the viewer shows (per arm; ``estop`` and ``reset`` also fleet-wide)."""


class ViewerFleet:
    """Latest joints, status, contact, diag and agent liveliness of every inventory arm, and the
    event log. A context manager (live: subscribes on ``start``)."""

    def __init__(
        self,
        arms: tuple[str, ...],
        fleet: str,
        session: zenoh.Session | None = None,
        clock: Callable[[], float] = time.monotonic,
        online_from_status: bool = False,
        devices: Mapping[str, tuple[DeviceKind, str]] | None = None,
    ) -> None:
        """``session`` None: fed through ``ingest`` only (a replay); ``online_from_status``:
        an arm is online while its status is fresh (a recording holds no liveliness);
        ``devices``: device id -> (its kind, the arm it is mounted on or "")."""
        self.keys = keys.KeySpace(fleet)
        self.arms = arms
        self._index = {arm: i for i, arm in enumerate(self.arms)}
        self._clock = clock
        self._session = session
        self._online_from_status = online_from_status
        self._devices = dict(devices or {})
        self._device_index = {device: i for i, device in enumerate(self._devices)}
        self._device_kinds = {kind.key: kind for kind, _mount in self._devices.values()}
        self.events = EventLog()
        self.dances = DanceTracker(self.events)
        self._lock = threading.Lock()
        self._handles: list[zenoh.Subscriber[None]] = []
        self.malformed = 0  # payloads we could not decode (counted, dropped)
        self._last_warning = -math.inf
        self.clear()

    def clear(self) -> None:
        """Forget every arm's and device's state, the event log and the malformed count (a
        replay scrubbed backwards counts them again as it re-feeds the file)."""
        n = len(self.arms)
        self.events.clear()
        self.dances.clear()
        with self._lock:
            self.malformed = 0
            self._last_warning = -math.inf
            self._angles = np.zeros((n, JOINT_COUNT))
            self._joints_at = np.full(n, -math.inf)
            self._status: list[m.ArmStatus | None] = [None] * n
            self._status_at = np.full(n, -math.inf)
            self._diag: list[m.Diag | None] = [None] * n
            self._online = np.zeros(n, dtype=bool)
            self._contact = np.zeros((n, JOINT_COUNT), dtype=bool)
            self._device_state: list[Any] = [None] * len(self._devices)
            self._device_at = np.full(len(self._devices), -math.inf)
            self._device_low: list[Any] = [None] * len(self._devices)
            self._device_low_at = np.full(len(self._devices), -math.inf)

    def start(self, guard: ThreadGuard | None = None) -> None:
        """Declare the subscribers (liveliness with history: tokens already present count);
        with ``guard``, a callback's unexpected failure fails the viewer instead of vanishing."""
        assert self._session is not None, "a replay is fed through ingest()"

        def wrap(callback: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], object]:
            return callback if guard is None else guard.wrap(callback, "viewer-state")

        on_sample = wrap(self._on_sample)
        # Stops and resets on the receiving Zenoh thread, so the event log shows them in
        # arrival order (fleet.control); ingest only decodes and appends under a short lock.
        ordered = direct(on_sample)
        self._handles = [
            self._session.declare_subscriber(
                self.keys.all_arms(channel), ordered if channel in CONTROL else on_sample
            )
            for channel in sorted(INGESTED)
        ]
        self._handles += [
            self._session.declare_subscriber(key, ordered)
            for key in (self.keys.estop, self.keys.reset)
        ]
        self._handles.append(self._session.declare_subscriber(self.keys.stop_report, on_sample))
        self._handles.append(self._session.declare_subscriber(self.keys.choreo, on_sample))
        self._handles += [
            self._session.declare_subscriber(
                self.keys.device(kind, "*", channel), ordered if channel in CONTROL else on_sample
            )
            for kind, device_kind in self._device_kinds.items()
            for channel in (*DEVICE_SHOWN, *CONTROL)
            if channel in device_kind.payloads
        ]
        self._handles.append(
            self._session.liveliness().declare_subscriber(
                self.keys.all_arms(keys.AGENT), wrap(self._on_token), history=True
            )
        )

    # ------------------------------------------------------------------ zenoh callbacks

    def _bad(self, what: str, exc: Exception) -> None:
        with self._lock:
            self.malformed += 1
            now = self._clock()
            if now - self._last_warning < 10.0:
                return
            self._last_warning = now
        log.warning("dropped a malformed %s payload (%s); %d so far", what, exc, self.malformed)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.ingest(str(sample.key_expr), sample.payload.to_bytes())

    def ingest(
        self, key: str, data: bytes, at_s: float | None = None, wall_ns: int | None = None
    ) -> None:
        """One sample of the key space, decoded through the channel table: the state of an
        inventory arm, or a stop or reset request (fleet-wide or one arm's). Anything else is
        ignored; a bad payload is counted. ``at_s``/``wall_ns``: when it arrived (a replay
        passes the recorded times; default now)."""
        if key == self.keys.stop_report:
            self._on_stop_report(data, wall_ns)
            return
        if key.startswith(f"{self.keys.prefix}/{keys.CHOREO}/"):
            self._on_choreo(key, data, at_s, wall_ns)
            return
        if key in (self.keys.estop, self.keys.reset):
            arm, channel = None, key.rpartition("/")[2]
        else:
            try:
                parsed = self.keys.parse_arm_key(key)
            except keys.KeyError_:
                self._ingest_device(key, data, at_s, wall_ns)
                return
            arm, channel = parsed.arm, parsed.channel
        i = None if arm is None else self._index.get(arm)
        if (arm is not None and i is None) or channel not in INGESTED:
            return  # not ours, or a recorded channel the viewer does not show (raw, acks)
        try:
            payload = payloads.decode(channel, data)
        except payloads.PayloadError as exc:
            self._bad(channel, exc)
            return
        now = self._clock() if at_s is None else at_s
        if isinstance(payload, (m.StopRequest, m.ResetRequest)):
            self._on_control(arm, payload, wall_ns)
        elif i is None:
            return
        elif isinstance(payload, m.Joints):
            self._on_joints(i, payload, now)
        elif isinstance(payload, m.ArmStatus):
            self._on_status(i, payload, now, wall_ns)
        elif isinstance(payload, m.ContactEvent):
            self._on_contact(i, payload, wall_ns)
        elif isinstance(payload, m.Diag):
            self._on_diag(i, payload, wall_ns)

    def _ingest_device(
        self, key: str, data: bytes, at_s: float | None, wall_ns: int | None
    ) -> None:
        """A device's state or lowstate, or a stop or reset request to it (anything else of a
        device is not shown)."""
        kind_key = key[len(self.keys.prefix) + 1 :].partition("/")[0]
        kind = self._device_kinds.get(kind_key)
        if kind is None:
            return
        try:
            parsed = self.keys.parse_device_key(key, kind.key)
        except keys.KeyError_:
            return
        i = self._device_index.get(parsed.device)
        channel = parsed.channel
        shown = (*DEVICE_SHOWN, *CONTROL)
        if i is None or channel not in shown or channel not in kind.payloads:
            return
        try:
            state = kind.payloads[channel].decode(data)
        except payloads.PayloadError as exc:
            self._bad(f"{kind.key} {channel}", exc)
            return
        if channel in CONTROL:
            self._on_control(parsed.device, state, wall_ns)
            return
        now = self._clock() if at_s is None else at_s
        with self._lock:
            if channel == keys.STATE:
                before = self._device_state[i]
                self._device_state[i] = state
                self._device_at[i] = now
            else:
                self._device_low[i] = state
                self._device_low_at[i] = now
        if channel == keys.STATE:
            self._log_latch(parsed.device, before, state, wall_ns)

    def _on_joints(self, i: int, joints: m.Joints, now: float) -> None:
        row = np.asarray(joints.angles_deg, dtype=float)
        if row.shape != (JOINT_COUNT,) or not np.all(np.isfinite(row)):
            self._bad("joints", ValueError(f"{len(joints.angles_deg)} angles or non-finite"))
            return
        with self._lock:
            self._angles[i] = row
            self._joints_at[i] = now

    def _on_status(self, i: int, status: m.ArmStatus, now: float, wall_ns: int | None) -> None:
        with self._lock:
            before = self._status[i]
            self._status[i] = status
            self._status_at[i] = now
        self._log_latch(self.arms[i], before, status, wall_ns)

    def _log_latch(
        self, unit: str, before: UnitReport | None, now: UnitReport, wall_ns: int | None
    ) -> None:
        """An arm's status or a device's state latched or released its stop: one event per
        transition, never one per repeated report."""
        was = before is not None and before.estopped
        if now.estopped and not was:
            why = now.stop_reason or "no reason given"
            self.events.add(STOP, unit, f"STOPPED (latched): {why}", wall_ns)
        elif was and not now.estopped:
            self.events.add(RELEASED, unit, "stop released by a reset", wall_ns)

    def _on_contact(self, i: int, event: m.ContactEvent, wall_ns: int | None) -> None:
        if not 0 <= event.joint < JOINT_COUNT:
            self._bad("contact", ValueError(f"joint {event.joint}"))
            return
        confirmed = event.state == "confirmed"
        with self._lock:
            was = bool(self._contact[i, event.joint])
            self._contact[i, event.joint] = confirmed
        if confirmed and not was:
            what = "grip" if event.grip else "contact"
            text = f"j{event.joint} {what} ({event.method}, error {event.error_deg:.1f}°)"
            self.events.add(CONTACT, self.arms[i], text, wall_ns)
        elif was and not confirmed:
            self.events.add(CONTACT, self.arms[i], f"j{event.joint} contact released", wall_ns)

    def _on_diag(self, i: int, diag: m.Diag, wall_ns: int | None) -> None:
        with self._lock:
            before = self._diag[i]
            self._diag[i] = diag
        # The agent answers a refusal to its caller only; its counter is how others learn of it.
        if before is not None and diag.rejected > before.rejected:
            count = diag.rejected - before.rejected
            why = diag.last_error or "no reason kept"
            text = f"refused {count} command{'s' if count > 1 else ''}: {why}"
            self.events.add(REFUSED, self.arms[i], text, wall_ns)

    def _on_control(
        self, unit: str | None, request: m.StopRequest | m.ResetRequest, wall_ns: int | None
    ) -> None:
        """A stop or reset request to the fleet (``unit`` None), an arm or a device: logged,
        never acted on (the agents decide)."""
        if isinstance(request, m.ResetRequest):
            self.events.add(RESET, unit, f"reset requested by {request.source}", wall_ns)
        elif self.events.first_sight(request.stop_id):  # stops are repeated until acknowledged
            why = request.reason or "no reason given"
            self.events.add(STOP, unit, f"stop requested by {request.source}: {why}", wall_ns)

    def _on_stop_report(self, data: bytes, wall_ns: int | None) -> None:
        """The coordinator's fan-out report of one stop (on every ack): logged once, when every
        arm in it was seen still."""
        try:
            report = payloads.STOP_REPORT.decode(data)
        except payloads.PayloadError as exc:
            self._bad(keys.STOP_REPORT, exc)
            return
        text = stop_timing_text(report)
        if text is not None and self.events.first_sight(f"still:{report.stop_id}"):
            self.events.add(STOP, None, text, wall_ns)

    def _on_choreo(self, key: str, data: bytes, at_s: float | None, wall_ns: int | None) -> None:
        """A choreography player's state (``choreo/<principal>``)."""
        try:
            principal = self.keys.principal_of(key)
            status = payloads.decode(keys.CHOREO, data)
        except keys.KeyError_:
            return
        except payloads.PayloadError as exc:
            self._bad(keys.CHOREO, exc)
            return
        self.dances.on_status(principal, status, self._clock() if at_s is None else at_s, wall_ns)

    def _on_token(self, sample: zenoh.Sample) -> None:
        try:
            i = self._index.get(self.keys.parse_arm_key(str(sample.key_expr)).arm)
        except keys.KeyError_:
            return
        if i is None:
            return
        online = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            changed = bool(self._online[i]) != online
            self._online[i] = online
        if changed:
            kind, text = (ONLINE, "agent online") if online else (OFFLINE, "agent gone (offline)")
            self.events.add(kind, self.arms[i], text)

    # ------------------------------------------------------------------ readers

    def snapshot(self) -> Snapshot:
        """Copy the newest state (cheap: a few small arrays and a tuple of references)."""
        now = self._clock()
        with self._lock:
            angles = self._angles.copy()
            joints_at = self._joints_at.copy()
            status = tuple(self._status)
            diag = tuple(self._diag)
            online = self._online.copy()
            if self._online_from_status:
                online = (now - self._status_at) <= REPLAY_ONLINE_S
            contact = self._contact.copy()
            device_state = list(self._device_state)
            device_age = now - self._device_at
            device_low = list(self._device_low)
            low_age = now - self._device_low_at
        views = []
        for k, (device, (kind, mount)) in enumerate(self._devices.items()):
            state = device_state[k]
            summary = "no state yet" if state is None else kind.summary(state)
            views.append(
                DeviceView(
                    device,
                    kind.key,
                    mount,
                    state,
                    float(device_age[k]),
                    summary,
                    device_low[k],
                    float(low_age[k]),
                )
            )
        return Snapshot(
            arms=self.arms,
            angles_deg=angles,
            joints_age_s=now - joints_at,
            status=status,
            online=online,
            contact=contact,
            diag=diag,
            devices=tuple(views),
            dances=self.dances.views(now),
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
