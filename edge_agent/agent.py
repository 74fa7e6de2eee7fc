"""The edge agent: relays one network's robots into the key space and serves their commands.

One core for every kind: D1 arms (``ArmSlot``: tracker, seqs, acks) and the devices of other
kinds (``DeviceSlot``: a kind's driver, ``fleet/devices/driver.py``) share one participant, one
Zenoh session, one safety inbox and loop, one latch store, one command thread and its envelope
checks, the write locks and the thread guard. A stop of an arm stops the devices mounted on it.

Threads (all ours, all named, all under one ``ThreadGuard``):
- ``relay`` (DdsLink): takes feedback from DDS, decodes it, updates the trackers, publishes
  joints/status and completes commands whose acks or targets arrived; between samples, the
  periodic jobs (link state, command deadlines, status at 4 Hz, diag at 1 Hz) every 50 ms;
- ``commands`` (CommandService, serving.py): checks queries, assigns seqs, writes DDS;
- ``starts`` (StartScheduler): writes synchronized starts at their time;
- ``safety`` (SafetyLoop, stops.py): stops and resets first, then heartbeats, the watchdog;
- ``latches`` (LatchStore): writes latched stops to disk.
If any of them (or a Zenoh callback) fails, the guard latches and stops every arm, and the
process exits 1 (``__main__``): a supervisor restarts it; it never runs on half alive.

``lock`` guards the trackers, the safety state and the in-flight table; it is never held
across a DDS write, a Zenoh put or a reply: state is copied under the lock and the I/O happens
after. Every D1 command goes through ``writer`` (writer.py), one arm at a time.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from pathlib import Path

import msgspec
import zenoh

from edge_agent.commands import InFlight
from edge_agent.contact_edge import ContactEdge
from edge_agent.holds import hold_command
from edge_agent.inbox import CommandInbox, InboxCounters, IncomingQuery, SafetyInbox
from edge_agent.latches import LatchStore, default_state_dir
from edge_agent.link import DdsLink
from edge_agent.relay import JSON, ZenohRelay, principal_of
from edge_agent.safety import ArmSafety
from edge_agent.scheduler import StartScheduler
from edge_agent.serving import CommandService
from edge_agent.slots import ArmSlot, DeviceSlot, Outbox, Unit
from edge_agent.stops import SafetyLoop
from edge_agent.tracker import ArmTracker
from edge_agent.unit_stops import ArmStops, DeviceStops, UnitStops
from edge_agent.writer import ArmWriter, transient_seq
from fleet.beat_limits import max_heartbeat_bytes
from fleet.d1 import protocol as p
from fleet.devices import kind_of
from fleet.devices.base import DeviceReply
from fleet.files import FILE_TIMEOUT_S, FileWatcher
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.origin.trust import SampleWriter
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode

log = logging.getLogger("edge_agent")

TICK_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.25
"""Status is re-published 4 times a second: late joiners learn it, and it is the agent's
heartbeat (the coordinator calls an agent offline after 1 s of silence)."""
DIAG_PERIOD_S = 1.0
CALIBRATION_POLL_S = 1.0
"""How often the ``files`` thread looks for a new calibration file (``fleet calibrate``)."""


class EdgeAgent:
    """Serves the arms ``arm_ids`` and devices ``device_ids`` of ``inventory``. A context
    manager."""

    def __init__(
        self,
        inventory: Inventory,
        arm_ids: list[str],
        state_dir: Path | None = None,
        device_ids: list[str] | None = None,
    ) -> None:
        device_ids = list(device_ids or [])
        network = inventory.network_of(arm_ids, device_ids)
        self.inventory = inventory
        self.lock = threading.Lock()
        self.arm_ids = list(arm_ids)
        self.device_ids = device_ids
        self.slots = {a: self._slot(inventory, a) for a in arm_ids}
        self.devices: dict[str, DeviceSlot] = {}
        device_kinds = {d: kind_of(inventory.device(d)).key for d in device_ids}
        mounted: dict[str, list[str]] = {}
        for device in device_ids:
            mount = getattr(inventory.device(device), "mount", "")
            if mount:
                mounted.setdefault(mount, []).append(device)
        self.stopping = threading.Event()
        self.guard = ThreadGuard("edge-agent", self._on_thread_failure)
        self.failed = self.guard.failed
        self.counters = InboxCounters()
        # Seconds from each served command's arrival to its reply, for metrics (scraped and
        # drained by edge_agent/metrics.py; bounded, one append per reply).
        self.reply_latencies_s: collections.deque[float] = collections.deque(maxlen=10_000)
        units = len(inventory.arms) + len(inventory.devices)
        self.safety_inbox = SafetyInbox(self.counters, max_heartbeat_bytes(units))
        self.command_inbox = CommandInbox(
            self.counters, lambda item: self.commands.busy(item), principal_of
        )
        suffixes = {a: inventory.arm(a).suffix for a in arm_ids}
        # DDS first: if the interface is wrong we fail before announcing anything on Zenoh.
        self._next_status = self._next_diag = 0.0
        self.link = DdsLink(
            network,
            suffixes,
            (self._on_feedback, self._on_bad_sample, self._tick),
            TICK_PERIOD_S,
            self.guard,
        )
        try:
            self.relay = ZenohRelay(
                inventory,
                arm_ids,
                (self.safety_inbox, self.command_inbox),
                self.guard,
                device_kinds,
                [arm for arm in mounted if arm not in self.slots],
            )
        except BaseException:
            self.link.close()
            raise
        for device in device_ids:
            self.devices[device] = self._device_slot(inventory, device, device_kinds[device])
        self.link.add_drivers({d: s.driver for d, s in self.devices.items()}, self._on_device)
        self.units: dict[str, Unit] = {**self.slots, **self.devices}
        self.writer = ArmWriter(self.lock, self.slots, self.link, self.relay.mirror_command)
        self.writer.add_units(device_ids)
        self.latches = LatchStore(state_dir or default_state_dir(), inventory.fleet, self.guard)
        arm_stops = ArmStops(
            self.lock, self.slots, self.writer, self.relay, (self.cancel_in_flight, self.flush)
        )
        device_stops = DeviceStops(self.lock, self.writer, self.units)
        stops: dict[str, UnitStops] = dict.fromkeys(self.slots, arm_stops)
        stops |= dict.fromkeys(self.devices, device_stops)
        self.safety_loop = SafetyLoop(
            self.lock,
            self.units,
            stops,
            self.relay,
            self.safety_inbox,
            self.flush,
            self.stopping,
            self.guard,
            self.latches,
            mounted,
        )
        # Stops latched before a restart, before any command can be served.
        for arm in self.units:
            request = self.latches.load(arm)
            if request is not None:
                self.safety_loop.restore(arm, request)
        configs = {a: inventory.arm(a) for a in arm_ids}
        paths = {a: inventory.calibration_path(a) for a in arm_ids}
        self.contact = ContactEdge(configs, self.relay, self.lock, self.writer, paths)
        self.writer.observers.append(self._on_written)
        # Files are read on a thread of their own (fleet.files): never on the relay's.
        self.calibrations = FileWatcher(
            self.contact.read_calibrations, CALIBRATION_POLL_S, self.stopping
        )
        self.scheduler = StartScheduler(self.guard, self.stopping)
        self.commands = CommandService(
            self.lock,
            self.slots,
            self.devices,
            self._reply_device,
            self.writer,
            self.command_inbox,
            self.scheduler,
            (self.collect_finished, self.flush),
            self.safety_loop.last_heartbeat_s,
            self.stopping,
            inventory,
        )
        self._threads = [
            self.safety_loop.thread,
            self.guard.thread(self.commands.run, "commands"),
            self.scheduler.thread,
            self.latches.thread,
            self.guard.thread(self.calibrations.run, "files"),
        ]

    def start(self) -> EdgeAgent:
        """Start relaying and serving commands."""
        self.link.start()
        for thread in self._threads:
            thread.start()
        return self

    @staticmethod
    def _slot(inventory: Inventory, arm: str) -> ArmSlot:
        config = inventory.arm(arm)
        return ArmSlot(ArmTracker(config))

    def _device_slot(self, inventory: Inventory, device: str, kind: str) -> DeviceSlot:
        """A device's slot: its kind's driver on this agent's participant, publishing through
        this agent's session, reading the latch the core holds for it."""
        config = inventory.device(device)
        safety = ArmSafety(config.lease_s, config.watchdog_s)

        def latch() -> tuple[bool, str | None]:
            stop = safety.stop  # one reference read: no lock needed for a state payload
            return stop is not None, safety.last_reason if stop is not None else None

        factory = kind_of(config).load("agent")
        put = self.relay.device_put(device)
        driver = factory(config, self.link.participant, self.link.directory, put, latch)
        return DeviceSlot(kind, driver, safety, getattr(config, "mount", ""))

    def _on_device(self, device: str, now: float) -> None:
        """After a driver took data or ticked (relay thread): confirm its stop when its state
        shows the action done, and end a finished watch."""
        slot = self.devices[device]
        driver = slot.driver
        with self.lock:
            stop = slot.safety.stop
            confirming = stop is not None and stop.dds_written_ns is not None and not stop.done
        still = driver.still()
        out = Outbox()
        if confirming and driver.stop_confirmed(now):
            with self.lock:
                if slot.safety.stop is stop and slot.safety.confirm(time.time_ns()):
                    self.safety_loop.on_still(device, slot, out)
        if still is not None:
            with self.lock:
                slot.safety.on_still_report(still, now)
        self.flush(out)

    def _reply_device(self, item: IncomingQuery, reply: DeviceReply, started: float) -> None:
        """Answer a device command on the device's own key (any thread, no lock held)."""
        self.reply_latencies_s.append(time.monotonic() - started)
        slot = self.devices[item.arm]
        principal = item.principal or "unknown"
        key = f"{self.relay.keys.device(slot.kind, item.arm, keys.CMD)}/{principal}"
        if reply.error is not None:
            with self.lock:
                slot.last_error = reply.error.message
        item.query.reply(key, encode(reply), encoding=JSON)
        item.query.drop()

    def _on_thread_failure(self, what: str) -> None:
        """The guard's failure path (on the failing thread): latch and stop every arm now;
        ``__main__`` then shuts down and exits 1."""
        self.safety_loop.latch_all(f"agent thread failed ({what}); restart the agent")

    # ------------------------------------------------------------------ the relay thread

    def _on_feedback(
        self, arm: str, text: bytes, now: float, writer: SampleWriter | None = None
    ) -> None:
        stamp_ns = time.time_ns()
        pubs = self.relay.publishers[arm]
        out = Outbox()
        with self.lock:
            slot = self.slots[arm]
            tracker = slot.tracker
            error_status = tracker.error_status
            decoded = tracker.on_feedback(text, now, writer)
            status_changed = tracker.update_link(now)
            if decoded is not None:
                message = decoded.message
                if isinstance(message, p.JointAngles):
                    slot.joints_seq += 1
                    joints = m.Joints(stamp_ns, list(message.angles_deg), slot.joints_seq)
                    out.puts.append((pubs.joints, encode(joints)))  # before the raw string
                    for flight, _query in slot.in_flight.values():
                        flight.on_angles(message.angles_deg)
                    if slot.safety.on_angles(message.angles_deg, stamp_ns, now):
                        self.safety_loop.on_still(arm, slot, out)
                elif isinstance(message, p.D1Status):
                    status_changed = True
                    if message.error_status != error_status:  # logged on change only
                        _log_error_status(arm, message.error_status)
                    if slot.safety.on_status(message.enabled, message.powered, stamp_ns):
                        self.safety_loop.on_still(arm, slot, out)  # acknowledged as confirmed
                elif isinstance(message, (p.ReceiveAck, p.ExecuteAck)):
                    _on_ack(slot, message, now)
                else:
                    status_changed = True
            if pubs.raw_feedback_matched and len(text) <= p.MAX_MESSAGE_BYTES:
                out.puts.append((pubs.raw_feedback, text))  # for debugging, not for floods
            if status_changed:
                out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
            if decoded is not None:
                self.contact.on_message(arm, slot, decoded.message, now, stamp_ns, out)
            self.collect_finished(slot, now, out)
        self.flush(out)
        self.contact.flush()  # force-limit writes, after the lock

    def _on_written(self, arm: str, command: p.Command, now: float) -> None:
        """Watch the pose after an enable of all joints; a motion ends the watch (called
        without the lock, after the write)."""
        with self.lock:
            tracker = self.slots[arm].tracker
            if isinstance(command, p.SetAllTorque) and command.mode > 0:
                setting = f"funcode 5 mode {command.mode}, enable_mode {tracker.config.enable_mode}"
                tracker.sag.armed(tracker.angles_deg, now, setting)
            elif isinstance(command, (p.SetJointAngle, p.ReturnToZero)) or (
                isinstance(command, p.SetAllAngles) and command.angles_deg != tracker.angles_deg
            ):
                tracker.sag.cancel()

    def cancel_in_flight(self, slot: ArmSlot, now: float, why: str, out: Outbox) -> None:
        """Fail every command in flight on ``slot`` (caller holds the lock)."""
        for flight, _query in slot.in_flight.values():
            flight.fail(ErrorCode.REJECTED, why)
        self.collect_finished(slot, now, out)

    def _on_bad_sample(self, arm: str, why: str) -> None:
        """A sample on the arm's feedback topic that is not an ArmString_: counted."""
        with self.lock:
            tracker = self.slots[arm].tracker
            tracker.malformed += 1
            tracker.last_error = f"malformed feedback: {why}"

    def _tick(self, now: float) -> None:
        """The periodic jobs, on the relay thread: link state, command deadlines, status and
        diag."""
        stamp_ns = time.time_ns()
        periodic = now >= self._next_status
        if periodic:
            self._next_status = now + STATUS_PERIOD_S
        diag = now >= self._next_diag
        if diag:
            self._next_diag = now + DIAG_PERIOD_S
            self.contact.apply_calibrations(self.calibrations.take(), self.slots)
            stuck_s = self.calibrations.stuck_s(now)
            if stuck_s > FILE_TIMEOUT_S:  # a hung read: latch every arm and exit (the guard)
                why = f"reading a calibration file has taken {stuck_s:.0f} s"
                self.guard.fail("files", TimeoutError(why))
        out = Outbox()
        with self.lock:
            for arm, slot in self.slots.items():
                tracker = slot.tracker
                pubs = self.relay.publishers[arm]
                if tracker.update_link(now) or periodic:
                    out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
                if diag:
                    out.puts.append((pubs.diag, encode(self._diag(tracker, now, stamp_ns))))
                for flight, _query in list(slot.in_flight.values()):
                    flight.on_time(now, tracker.angles_deg)
                self.collect_finished(slot, now, out)
        if diag:
            for device in self.devices:
                payload = encode(self.device_diag(device, now, stamp_ns))
                out.puts.append((self.relay.device_publishers[device][keys.DIAG], payload))
        self.flush(out)

    def _diag(self, tracker: ArmTracker, now: float, stamp_ns: int) -> m.Diag:
        """One arm's counters and the agent's own (caller holds the lock)."""
        counters = self.counters
        return msgspec.structs.replace(
            tracker.diag(now, stamp_ns),
            bad_payloads=counters.bad_payloads,
            undecodable_stops=counters.undecodable_stops,
            busy=counters.busy,
            dropped_events=counters.dropped_events,
            write_failures=self.link.write_failures,
        )

    def device_diag(self, device: str, now: float, stamp_ns: int) -> m.Diag:
        """A device's diag: its driver's link and counters, the core's refusals and the
        agent's own counters (the same fields as an arm's)."""
        slot = self.devices[device]
        health = slot.driver.health(now)
        counters = self.counters
        with self.lock:
            rejected, last_error = slot.rejected, slot.last_error
        return m.Diag(
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
            bad_payloads=counters.bad_payloads,
            undecodable_stops=counters.undecodable_stops,
            busy=counters.busy,
            dropped_events=counters.dropped_events,
            write_failures=self.link.write_failures,
        )

    def collect_finished(self, slot: ArmSlot, now: float, out: Outbox) -> None:
        """Move finished commands from the in-flight table to ``out`` (caller holds the lock)."""
        finished: dict[int, tuple[InFlight, zenoh.Query]] = {}
        for seq, (flight, query) in list(slot.in_flight.items()):
            if flight.done:
                del slot.in_flight[seq]
                slot.seqs.release(seq)
                finished[id(flight)] = (flight, query)
        for flight, query in finished.values():
            reply = flight.reply(now)
            if reply.error is not None:
                slot.tracker.last_error = reply.error.message
                if reply.error.code == ErrorCode.TIMEOUT:  # an ack, not a target, is late
                    slot.tracker.ack_timeouts += 1
            out.replies.append((query, reply))

    def flush(self, out: Outbox) -> None:
        """Perform the puts and replies collected under the lock (call without it)."""
        for publisher, payload in out.puts:
            publisher.put(payload)
        for query, reply in out.replies:
            self.reply_latencies_s.append(reply.latency_ms / 1000.0)
            # On the arm's own key, not the query's: a wildcard query (arm/*/cmd/<principal>)
            # gets one reply per arm, which consolidation would merge on one wildcard key.
            principal = principal_of(query.key_expr) or "unknown"
            key = self.relay.keys.command(reply.arm, principal)
            query.reply(key, encode(reply), encoding=JSON)
            query.drop()

    # ------------------------------------------------------------------ state access

    def tracker(self, arm: str) -> ArmTracker:
        """The tracker of ``arm`` (read it under no assumption of consistency)."""
        return self.slots[arm].tracker

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Shutdown order: stop taking commands (and drop pending synchronized starts) -> hold
        every arm still moving (nobody will command it any more) -> stop the loops and join ->
        stop DDS -> undeclare Zenoh (tokens first, so the fleet sees the agent leave) and close
        the session. Idempotent."""
        if self.stopping.is_set():
            return
        self.stopping.set()
        self.scheduler.cancel_all()
        self.scheduler.wake()
        self._hold_moving_arms()
        for thread in self._threads:
            if thread is self.latches.thread:
                continue  # it runs until latches.close(), which writes the last stops
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self.latches.close()  # the latches of the last stops, written before the process ends
        self.link.close()
        self.relay.close()

    def _hold_moving_arms(self) -> None:
        def hold_if_moving(slot: ArmSlot, now: float) -> tuple[p.Command, int] | None:
            tracker = slot.tracker
            if slot.safety.standstill.still or slot.safety.latched or tracker.powered is False:
                return None  # still, or already held by its stop
            command = hold_command(tracker, now)  # None without a fresh pose
            return None if command is None else (command, transient_seq(slot))

        for arm in self.arm_ids:
            if self.writer.write(arm, hold_if_moving) is not None:
                log.info("arm %s was moving: held it before shutting down", arm)

    def __enter__(self) -> EdgeAgent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _log_error_status(arm: str, error_status: int) -> None:
    """The arm's ``error_status`` changed: the raw value, which may be a bitfield of faults."""
    if error_status == p.ERROR_STATUS_NORMAL:
        log.info("arm %s: error_status %d (normal)", arm, error_status)
    else:
        log.warning(
            "arm %s: error_status %d (abnormal; 0x%x as a bitfield)",
            arm,
            error_status,
            error_status & (2**64 - 1),
        )


def _on_ack(slot: ArmSlot, ack: p.ReceiveAck | p.ExecuteAck, now: float) -> None:
    """Credit ``ack`` to the written command it answers (caller holds the lock): by its seq, or,
    when it carries seq 10 (an arm answering as the spec's examples do), to the oldest command
    awaiting this kind of ack (``acks.py``), counted as unmatched; any other seq is counted as
    foreign and credited to nothing."""
    tracker = slot.tracker
    seq, how = slot.acks.answered(ack, now)
    if how == "foreign":
        tracker.acks_foreign += 1
        tracker.last_error = (
            f"{type(ack).__name__} with seq {ack.seq} ignored: neither a command of ours nor "
            f"the arm's seq {p.ARM_REPORT_SEQ} (another client commanding the arm?)"
        )
        return
    if seq is None:
        tracker.acks_ignored += 1
        why = "a late or repeated ack" if how == "late" else "no command written awaits one"
        tracker.last_error = f"{type(ack).__name__} with seq {ack.seq} ignored: {why}"
        return
    if how == "oldest":
        tracker.acks_unmatched += 1
        ack = msgspec.structs.replace(ack, seq=seq)
    entry = slot.in_flight.get(seq)
    if entry is not None:  # else a stop, hold or force limit: nobody awaits its acks
        entry[0].on_ack(ack)
