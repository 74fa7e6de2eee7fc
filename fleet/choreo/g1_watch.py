"""What the choreography player knows of the G1s whose arms it plays: the newest
``g1/<id>/state`` (FSM, stop latch, the rt/arm_sdk weight and phase) and ``g1/<id>/lowstate``
(the joints, rad) of each, and why one must not be commanded now.

As ``fleet.watch.ArmWatch`` for the D1 arms: the Zenoh callback only decodes (through the
channel table) and stores under a lock; no I/O, no Zenoh call.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import zenoh

from fleet.g1.loco import ARM_SDK_FSMS, fsm_name
from fleet.g1.messages import G1LowState, G1State
from fleet.watch import first_problem_left, report_problem
from fleet.wire import keys, payloads

SILENT_S = 1.0
"""A G1 whose agent put no state (or no lowstate) for this long has lost its link: both repeat
at its ``relay_hz`` (at least 1 Hz by the config check)."""


@dataclass(frozen=True)
class G1Latest:
    """The newest samples of one G1 (``*_at``: monotonic time received)."""

    state: G1State | None = None
    state_at: float = 0.0
    low: G1LowState | None = None
    low_at: float = 0.0


class G1Watch:
    """Latest state and lowstate of the G1s ``devices``."""

    def __init__(self, session: zenoh.Session, space: keys.KeySpace, devices: Iterable[str]):
        self.space = space
        self.devices = list(devices)
        self._lock = threading.Lock()  # guards self._latest
        self._latest = {d: G1Latest() for d in self.devices}
        self._subs = [
            session.declare_subscriber(space.device(keys.G1, "*", channel), self._on_sample)
            for channel in (keys.STATE, keys.LOWSTATE)
        ]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = self.space.parse_device_key(str(sample.key_expr), keys.G1)
        except keys.KeyError_:
            return
        if key.device not in self._latest:
            return
        try:
            payload = payloads.device_payloads(keys.G1)[key.channel].decode(
                sample.payload.to_bytes()
            )
        except (KeyError, payloads.PayloadError):
            return  # a foreign payload: the agent counts malformed data, not us
        now = time.monotonic()
        with self._lock:
            got = self._latest[key.device]
            if isinstance(payload, G1State):
                self._latest[key.device] = G1Latest(payload, now, got.low, got.low_at)
            elif isinstance(payload, G1LowState):
                self._latest[key.device] = G1Latest(got.state, got.state_at, payload, now)

    def latest(self, device: str) -> G1Latest:
        """The newest samples of ``device``."""
        with self._lock:
            return self._latest[device]

    def problem(self, device: str, now_s: float) -> str | None:
        """Why ``device``'s arms must not be commanded now, or None."""
        got = self.latest(device)
        state = got.state
        why = report_problem(f"g1 {device!r}", "state", state, got.state_at, now_s, SILENT_S)
        if why is not None or state is None:
            return why
        if state.fsm_id not in ARM_SDK_FSMS:
            return (
                f"g1 {device!r} is in fsm {state.fsm_id} {fsm_name(state.fsm_id)}: its arms "
                "(rt/arm_sdk) move only in lock standing (4) or the walking controller "
                f"(500, 501) (seed 004); start its walking controller first: "
                f"""`fleet cmd {device} '{{"op": "start"}}'`"""
            )
        if got.low is None or now_s - got.low_at > SILENT_S:
            return f"g1 {device!r}: no rt/lowstate for {SILENT_S:g} s (its arm joints are unknown)"
        return None

    def released(self, device: str) -> str | None:
        """Why ``device`` no longer takes our targets (its stream ramps down or is off), or
        None while it is engaging or on."""
        state = self.latest(device).state
        if state is None or state.arm_phase in ("engaging", "on"):
            return None
        if state.arm_phase == "holding":
            return f"g1 {device!r} holds its arms ({state.arm_held or 'held'})"
        why = state.arm_released or f"its arm stream is {state.arm_phase}"
        return f"g1 {device!r} released its arms ({why})"

    def wait_ready(self, timeout_s: float, stop: threading.Event | None = None) -> str | None:
        """Wait (bounded; ``stop`` ends it) until every G1 may be commanded; the first problem
        left, or None."""
        return first_problem_left(
            lambda now: [p for d in self.devices if (p := self.problem(d, now)) is not None],
            timeout_s,
            stop,
        )

    def close(self) -> None:
        """Undeclare the subscriptions (idempotent)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            sub.undeclare()
