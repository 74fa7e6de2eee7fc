"""The devices' side of the agent (every kind of ``fleet/devices``: Dex1-1, G1): their slots, how a
stop acts on them, their commands, their stop confirmation and diag.

A device's own logic is its kind's *driver* (``fleet/devices/driver.py``): it writes its kind's stop
action (``write_stop``) under the device's write lock and tells when its state confirms it
(``stop_confirmed``, checked here on the relay thread after its data or tick); its state payload
carries the latch at its next put; a reset moves nothing. Its commands get the envelope checks every
kind gets (``fleet/devices/envelope.py``), then, under the device's write lock, the latch and the
driver's own checks and write (``DeviceDriver.execute``).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from edge_agent.link import DdsLink
from edge_agent.relay import ZenohRelay
from edge_agent.writelocks import WriteLocks
from fleet.devices import kind_of
from fleet.devices.base import DeviceReply, Release
from fleet.devices.driver import DeviceDriver, Refusal, error_reply
from fleet.devices.envelope import Principals, check_lease, check_order, release
from fleet.devices.ordering import CommandOrder
from fleet.devices.safety import ArmSafety, Lease, LeaseRefused
from fleet.devices.served import OnStill, OwnCounts
from fleet.devices.unit import IncomingQuery, Later, Outbox, owner_of
from fleet.inventory import Inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode
from fleet.wire.replies import answer

log = logging.getLogger("edge_agent.devices")


@dataclass
class DeviceSlot:
    """One device: its kind's key word, its driver, and the core's safety state for it."""

    kind: str
    driver: DeviceDriver
    safety: ArmSafety
    mount: str = ""
    order: CommandOrder = field(default_factory=CommandOrder)
    rejected: int = 0
    last_error: str | None = None

    @property
    def stop_action(self) -> str:
        """What a stop writes (the kind's action, or the inventory's choice)."""
        return self.driver.stop_action


class DeviceServer:
    """Every device of the agent, through its kind's driver."""

    def __init__(
        self,
        lock: threading.Lock,
        locks: WriteLocks,
        relay: ZenohRelay,
        principals: Principals,
        stopping: threading.Event,
        hooks: tuple[OnStill, OwnCounts],
        reply_latencies_s: collections.deque[float],
        lease_of: Callable[[str, float], Lease | None] = lambda _arm, _now: None,
    ) -> None:
        self._lock = lock
        self._locks = locks
        self._relay = relay
        self._principals = principals
        self._stopping = stopping
        self._on_still, self._own_counts = hooks
        self._latencies = reply_latencies_s
        self._lease_of = lease_of
        """Who holds an arm at a time (None: nobody): the arm a device is mounted on, whose
        lease covers the device."""
        self.slots: dict[str, DeviceSlot] = {}
        self.threads: list[threading.Thread] = []
        self._leaving = False

    def add(self, inventory: Inventory, device: str, link: DdsLink) -> DeviceSlot:
        """A device's slot: its kind's driver on the agent's participant, publishing through
        the agent's session, reading the latch the core holds for it (at start-up only)."""
        config = inventory.device(device)
        safety = ArmSafety(config.lease_s, config.watchdog_s)

        def latch() -> tuple[bool, str | None, str | None]:
            why = safety.stop_reason  # reference reads: no lock needed for a state payload
            return why is not None, why, safety.watched_by

        kind = kind_of(config)
        put = self._relay.device_put(device)
        driver = kind.load("agent")(config, link.participant, link.directory, put, latch)
        slot = DeviceSlot(kind.key, driver, safety, getattr(config, "mount", ""))
        self.slots[device] = slot
        return slot

    # ------------------------------------------------------------------ stops

    def latched(self, unit: str, now: float, out: Outbox) -> None:
        """Nothing in flight to end: a device's commands are written at once (a G1's RPC
        answer, if one comes, is only reported)."""

    def started(self, unit: str, now: float) -> None:
        self.slots[unit].driver.stop_started(now)

    def write(self, unit: str, stop_id: str | None, later: Later | None) -> bool:
        slot = self.slots[unit]
        with self._locks.of(unit):
            now = time.monotonic()
            with self._lock:
                stop = slot.safety.stop
                if stop is None or (stop_id is not None and stop.stop_id != stop_id):
                    return False  # reset meanwhile, or superseded
                stop.last_sent_s = now
            written, detail = slot.driver.write_stop(now)
            with self._lock:
                stop.detail = detail
                if written and stop.dds_written_ns is None:
                    stop.dds_written_ns = time.time_ns()
                    return True
        return False

    def status(self, unit: str, now: float, now_ns: int) -> tuple[zenoh.Publisher, bytes] | None:
        return None  # the device's state says it at its next put

    def released(self, unit: str, now: float, now_ns: int) -> None:
        """It stays as the stop left it."""
        self.slots[unit].driver.stop_cleared()

    def on_device(self, device: str, now: float) -> None:
        """After a driver took data or ticked (relay thread): confirm its stop when its state
        shows the action done, and end a finished watch."""
        slot = self.slots[device]
        driver = slot.driver
        with self._lock:
            stop = slot.safety.stop
            confirming = stop is not None and stop.dds_written_ns is not None and not stop.done
        still = driver.still()
        out = Outbox()
        if confirming and driver.stop_confirmed(now):
            with self._lock:
                if slot.safety.stop is stop and slot.safety.confirm(time.time_ns()):
                    self._on_still(device, out)
        if still is not None:
            with self._lock:
                slot.safety.on_still_report(still, now)
        for publisher, payload in out.puts:
            publisher.put(payload)

    # ------------------------------------------------------------------ commands

    def serve(self, item: IncomingQuery, now: float) -> None:
        """One device command: the envelope checked as for every kind, then, under the
        device's write lock, the latch and the driver's own checks and write."""
        slot = self.slots[item.arm]
        driver, label = slot.driver, f"{slot.kind} {item.arm!r}"
        try:
            command = driver.commands.decode(item.payload)
        except payloads.PayloadError as exc:
            op = payloads.unknown_op(item.payload, payloads.ops_of(driver.commands))
            code, why = (
                (ErrorCode.NOT_IMPLEMENTED, f"unknown op {op!r} for {label}")
                if op is not None
                else (ErrorCode.PARAMETER, str(exc))
            )
            self._refuse(item, slot, code, why, now)
            return
        try:
            with self._lock:
                principal = self._principals.check(item)
                owner = None if command.owner is None else owner_of(principal, command.owner)
                released = isinstance(command, Release)
                if released:
                    release(label, slot.safety, owner, now)
            if released:
                self._reply(item, DeviceReply(ok=True, device=item.arm), now)
                return
            with self._lock:
                check_order(label, slot.order, principal, owner, command)
                exempt = driver.allowed_while_latched(command) and slot.safety.latched
                if not exempt:
                    takeover = self._arm_owner_commands(slot, label, owner, command.takeover, now)
                    check_lease(label, slot.safety, owner, takeover or command.takeover, now)
                if (
                    driver.moves(command)
                    and owner is not None
                    and self._principals.watched(principal, owner)
                ):
                    slot.safety.watch(owner, now)
                slot.order.record(principal, owner, command.stamp_ns)
            with self._locks.of(item.arm):
                with self._lock:
                    latched = slot.safety.latched or self._stopping.is_set()
                    reason = slot.safety.last_reason
                if latched and not driver.allowed_while_latched(command):
                    raise Refusal(
                        ErrorCode.REJECTED,
                        f"{label} is stopped ({reason}); `fleet reset {item.arm}` releases it",
                    )
                reply = driver.execute(command, now, lambda r: self._reply(item, r, now))
        except Refusal as exc:
            self._refuse(item, slot, exc.code, str(exc), now)
            return
        if reply is not None:
            self._reply(item, reply, now)

    def _arm_owner_commands(
        self, slot: DeviceSlot, label: str, owner: str | None, takeover: bool, now: float
    ) -> bool:
        """An arm's lease covers the device mounted on it (caller holds the lock): while
        another owner holds the arm, the device refuses ``owner`` (3207) unless it takes over;
        True when ``owner`` holds the arm (it may command the device whoever holds the
        device's own lease). An arm served by another agent: by its newest status."""
        holder = self._lease_of(slot.mount, now) if slot.mount else None
        if holder is None:
            return False
        if holder.owner == owner:
            return True
        if not takeover:
            refused = LeaseRefused(holder.owner, holder.expires_s - now)
            raise Refusal(
                ErrorCode.LEASE_EXISTS, f"{label} is mounted on arm {slot.mount!r}, {refused}"
            )
        return False

    def busy(self, item: IncomingQuery, why: str) -> None:
        """Answer a query the inbox could not queue (called on the Zenoh thread)."""
        self._reply(item, error_reply(item.arm, ErrorCode.BUSY, why), time.monotonic())

    def _refuse(
        self, item: IncomingQuery, slot: DeviceSlot, code: ErrorCode, why: str, now: float
    ) -> None:
        with self._lock:
            slot.rejected += 1
            slot.last_error = why[:1000]
        self._reply(item, error_reply(item.arm, code, why), now)

    def _reply(self, item: IncomingQuery, reply: DeviceReply, started: float) -> None:
        """Answer a device command on the device's own key (any thread, no lock held)."""
        self._latencies.append(time.monotonic() - started)
        slot = self.slots[item.arm]
        if reply.error is not None:
            with self._lock:
                slot.last_error = reply.error.message
        answer(item.query, self._relay.keys.device(slot.kind, item.arm, keys.CMD), encode(reply))

    # ------------------------------------------------------------------ periodic, shutdown

    def tick(self, now: float, stamp_ns: int, periodic: bool, diag: bool, out: Outbox) -> None:
        """Each device's diag once a second (its state is its driver's to put)."""
        if not diag:
            return
        for device in self.slots:
            payload = encode(self.diag(device, now, stamp_ns))
            out.puts.append((self._relay.device_publishers[device][keys.DIAG], payload))

    def diag(self, device: str, now: float, stamp_ns: int) -> m.Diag:
        """A device's diag: its driver's link and counters, the core's refusals and the
        agent's own counters (the same fields as an arm's)."""
        slot = self.slots[device]
        health = slot.driver.health(now)
        with self._lock:
            rejected, last_error = slot.rejected, slot.last_error
        own = m.Diag(
            stamp_ns=stamp_ns,
            link=health.link,  # type: ignore[arg-type]
            relayed=health.relayed,
            malformed=health.bad_samples,
            unknown_messages=0,
            unknown_fields=0,
            rejected=rejected + health.rejected,
            commands=health.commands,
            ack_timeouts=health.timeouts,
            feedback_rate_hz=health.rate_hz,
            last_feedback_age_s=health.age_s,
            last_error=(last_error or health.last_error),
            foreign_feedback=health.foreign,
            implausible_feedback=health.implausible,
        )
        return self._own_counts(own)

    def hold_if_moving(self, unit: str) -> bool:
        """At shutdown a device is left as its driver leaves it (a G1 hands its arms back to
        the robot over ``arm_release_s``): the first call starts every device's leaving, so
        they ramp side by side, then each call waits (bounded) for its own. Nothing is held."""
        if not self._leaving:
            self._leaving = True
            now = time.monotonic()
            for slot in self.slots.values():
                slot.driver.leave(now)
        if not self.slots[unit].driver.wait_left():
            log.warning("%s %r: still leaving at the agent's exit", self.slots[unit].kind, unit)
        return False


__all__ = ["DeviceServer", "DeviceSlot"]
