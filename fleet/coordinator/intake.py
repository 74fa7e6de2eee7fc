"""What the coordinator's Zenoh callbacks hand to its ``events`` thread: decoded, bounded,
checked against the inventory, stops first.

- control (a bounded FIFO, served first, in arrival order): agent tokens, stops, resets. A stop
  that does not decode (or found the FIFO full) is passed on without a request: the agents
  stopped on it themselves; the coordinator counts and logs it;
- status: latest-wins per arm (the newest status is all the fleet state needs);
- reports (a bounded FIFO): stop acks and contact events; overflow is counted.
Samples on the keys of arms that are not in the inventory are counted and dropped: nothing an
unknown name sends is stored. The arm comes from the key, never from the payload.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import zenoh

from fleet.control import CONTROL_DEPTH, ControlFifo
from fleet.devices import DeviceKind
from fleet.wire import keys, payloads
from fleet.wire import messages as m

REPORT_DEPTH = 4096

ControlKind = Literal["token", "stop", "reset"]


@dataclass(frozen=True)
class Control:
    """An agent token change, a stop or a reset. ``arm`` None: the fleet-wide key. For a stop,
    ``stop`` None means undecodable (or dropped by a flood), ``why`` says which."""

    kind: ControlKind
    arm: str | None
    present: bool = False
    stop: m.StopRequest | None = None
    why: str = ""


@dataclass(frozen=True)
class Report:
    """A stop ack or a contact event of an inventory arm."""

    arm: str
    payload: m.StopAck | m.ContactEvent


@dataclass
class IntakeCounters:
    """Published in ``coordinator/diag``."""

    bad_events: int = 0
    unknown_arms: int = 0
    dropped_events: int = 0


class CoordinatorIntake:
    """Zenoh callbacks -> bounded queues for the events thread."""

    def __init__(self, space: keys.KeySpace, arms: frozenset[str]) -> None:
        self.counters = IntakeCounters()
        self.wake = threading.Event()
        self._space = space
        self._arms = arms
        self._lock = threading.Lock()
        # tokens, stops and resets: the fleet's one ordered intake (fleet.control); its
        # subscribers' callbacks run on the receiving Zenoh thread (service.py), in order
        self._control: ControlFifo[Control] = ControlFifo(
            lambda arm: Control("stop", arm, why="stop request dropped at a full queue (flood)"),
            CONTROL_DEPTH,
        )
        self._status: dict[str, m.ArmStatus] = {}
        self._reports: deque[Report] = deque()
        self._device_states: dict[str, tuple[DeviceKind, Any]] = {}

    def _arm(self, sample: zenoh.Sample) -> str | None:
        """The inventory arm whose key the sample came on; None (counted) otherwise."""
        try:
            arm = self._space.parse_arm_key(str(sample.key_expr)).arm
        except keys.KeyError_:
            arm = None
        if arm not in self._arms:
            with self._lock:
                self.counters.unknown_arms += 1
            return None
        return arm

    def _bad(self) -> None:
        with self._lock:
            self.counters.bad_events += 1

    # ------------------------------------------------------------------ callbacks

    def on_token(self, sample: zenoh.Sample) -> None:
        """An agent's liveliness token appeared or went away."""
        arm = self._arm(sample)
        if arm is not None:
            present = sample.kind == zenoh.SampleKind.PUT
            self._push_control(Control("token", arm, present=present))

    def on_stop(self, fleet_wide: bool):  # type: ignore[no-untyped-def]
        """The callback of the fleet's (``fleet_wide``) or the arms' stop key."""

        def handler(sample: zenoh.Sample) -> None:
            arm = None if fleet_wide else self._arm(sample)
            if not fleet_wide and arm is None:
                return
            try:
                event = Control("stop", arm, stop=payloads.STOP.decode(sample.payload.to_bytes()))
            except payloads.PayloadError as exc:
                self._bad()
                event = Control("stop", arm, why=f"undecodable stop request ({exc.why[:200]})")
            self._push_control(event)

        return handler

    def on_reset(self, fleet_wide: bool):  # type: ignore[no-untyped-def]
        """The callback of the fleet's or the arms' reset key; a bad reset releases nothing."""

        def handler(sample: zenoh.Sample) -> None:
            arm = None if fleet_wide else self._arm(sample)
            if not fleet_wide and arm is None:
                return
            try:
                payloads.RESET.decode(sample.payload.to_bytes())
            except payloads.PayloadError:
                self._bad()
                return
            self._push_control(Control("reset", arm))

        return handler

    def on_status(self, sample: zenoh.Sample) -> None:
        """An agent's status: latest wins."""
        arm = self._arm(sample)
        if arm is None:
            return
        try:
            status = payloads.STATUS.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            self._bad()
            return
        with self._lock:
            self._status[arm] = status
        self.wake.set()

    def on_report(self, sample: zenoh.Sample) -> None:
        """A stop ack or a contact event."""
        arm = self._arm(sample)
        if arm is None:
            return
        channel = self._space.parse_arm_key(str(sample.key_expr)).channel
        try:
            payload: m.StopAck | m.ContactEvent = payloads.decode(
                channel, sample.payload.to_bytes()
            )
        except payloads.PayloadError:
            self._bad()
            return
        self._push_report(Report(arm, payload))

    def _push_report(self, report: Report) -> None:
        with self._lock:
            if len(self._reports) >= REPORT_DEPTH:
                self.counters.dropped_events += 1
                return
            self._reports.append(report)
        self.wake.set()

    # ------------------------------------------------------------------ devices

    def on_device(self, kind: DeviceKind, devices: frozenset[str]):  # type: ignore[no-untyped-def]
        """The callbacks (token, state, ack) of one device kind's keys: tokens and acks go
        with the arms' (an ack's device id stands where an arm's would), states latest-wins."""
        prefix = f"{self._space.prefix}/{kind.key}/"
        decode = kind.payloads[keys.STATE].decode

        def device_of(sample: zenoh.Sample) -> str | None:
            device = str(sample.key_expr)[len(prefix) :].partition("/")[0]
            if device not in devices:
                with self._lock:
                    self.counters.unknown_arms += 1
                return None
            return device

        def on_token(sample: zenoh.Sample) -> None:
            device = device_of(sample)
            if device is not None:
                present = sample.kind == zenoh.SampleKind.PUT
                self._push_control(Control("token", device, present=present))

        def on_state(sample: zenoh.Sample) -> None:
            device = device_of(sample)
            if device is None:
                return
            try:
                state = decode(sample.payload.to_bytes())
            except payloads.PayloadError:
                self._bad()
                return
            with self._lock:
                self._device_states[device] = (kind, state)
            self.wake.set()

        def on_ack(sample: zenoh.Sample) -> None:
            device = device_of(sample)
            if device is None:
                return
            try:
                ack = payloads.decode(keys.ESTOP_ACK, sample.payload.to_bytes())
            except payloads.PayloadError:
                self._bad()
                return
            self._push_report(Report(device, ack))

        return on_token, on_state, on_ack

    def take_device_states(self) -> dict[str, tuple[DeviceKind, Any]]:
        """The newest state of each device heard since the last call."""
        with self._lock:
            states, self._device_states = self._device_states, {}
        return states

    def _push_control(self, event: Control) -> None:
        # a stop that finds the FIFO full marks its target (bounded: the inventory and None)
        is_stop = event.kind == "stop"
        if not self._control.push(event, event.arm, is_stop=is_stop) and not is_stop:
            with self._lock:
                self.counters.dropped_events += 1
        self.wake.set()

    # ------------------------------------------------------------------ events thread

    def take(self) -> tuple[list[Control], dict[str, m.ArmStatus], list[Report]]:
        """Everything pending, control first (stops that found the FIFO full at its end)."""
        control = self._control.take()
        with self._lock:
            status, self._status = self._status, {}
            reports = list(self._reports)
            self._reports.clear()
        return control, status, reports
