"""The edge agent: relays one network's robots into the key space and serves their commands.

One core for every kind: D1 arms and the devices of other kinds share one participant, one
Zenoh session, one safety inbox and loop, one latch store, one command thread and its envelope
checks, the write locks and the thread guard. The core speaks to each robot through one
per-unit contract (``fleet/devices/unit.py``: its safety state, and its kind's ``UnitServer``):
the server a served kind builds from what the core shares with it (``fleet/devices/served.py``;
the registry lists them: the D1 arms, ``fleet/d1arm``) and the devices' (``device_server.py``:
a kind's driver, ``fleet/devices/driver.py``). A stop of an arm stops the devices mounted on it.

Threads (all ours, all named, all under one ``ThreadGuard``):
- ``relay`` (DdsLink): takes every kind's samples from DDS, decodes them, updates the trackers,
  publishes joints/status and completes commands whose acks or targets arrived; between samples, the
  periodic jobs (link state, command deadlines, status at 4 Hz, diag at 1 Hz) every 50 ms;
- ``commands`` (CommandService, serving.py): hands each query to its unit's server, which
  checks it, assigns seqs and writes DDS;
- ``starts`` (StartScheduler): writes synchronized starts at their time;
- ``safety`` (SafetyLoop, stops.py): stops and resets first, then heartbeats, the watchdog;
- ``latches`` (LatchStore): writes latched stops to disk;
- a kind's own (the arms' ``files``: reads calibration files).
If any of them (or a Zenoh callback) fails, the guard latches and stops every arm, and the
process exits 1 (``__main__``): a supervisor restarts it; it never runs on half alive.

``lock`` guards the trackers, the safety state and the in-flight table; it is never held
across a DDS write, a Zenoh put or a reply: state is copied under the lock and the I/O happens
after. Every write to a robot happens under its write lock (``writelocks.py``): an arm's D1
commands through its kind's writer (``fleet/d1arm/writer.py``), a device's through its driver.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec

from edge_agent.device_server import DeviceServer
from edge_agent.inbox import CommandInbox, InboxCounters, SafetyInbox
from edge_agent.latches import LatchStore
from edge_agent.link import DdsLink
from edge_agent.mount_leases import MountLeases
from edge_agent.relay import ZenohRelay, principal_of
from edge_agent.scheduler import SchedulerFull, StartScheduler
from edge_agent.serving import CommandService
from edge_agent.stops import SafetyLoop
from edge_agent.writelocks import WriteLocks
from fleet.beat_limits import max_heartbeat_bytes
from fleet.devices import kind_of
from fleet.devices.envelope import Principals
from fleet.devices.registry import served_kinds
from fleet.devices.safety import Lease
from fleet.devices.served import CoreServices, KindSide
from fleet.devices.unit import Outbox, Unit, UnitServer
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.state_dir import default_state_dir
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from fleet.wire.replies import answer

TICK_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.25
"""Status is re-published 4 times a second: late joiners learn it, and it is the agent's
heartbeat (the coordinator calls an agent offline after 1 s of silence)."""
DIAG_PERIOD_S = 1.0
DIAG_SOON_S = 0.2
"""Bad input (an undecodable payload or stop, a busy refusal, a key naming no principal) is in
the next diag within this long, not at the next whole second: an operator who sends a bad
command sees it counted at once. It also bounds the diags a flood of bad input makes, to 5 a
second."""


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
        self.mount_leases = MountLeases(self.counters)
        self.safety_inbox = SafetyInbox(self.counters, max_heartbeat_bytes(units))
        self.command_inbox = CommandInbox(
            self.counters, lambda item: self.commands.busy(item), principal_of
        )
        # Before the relay declares the queryables: a flood of commands that fills the inbox
        # while the agent starts is answered from the first query (it once met no
        # CommandService yet, and the failed callback took the agent down). The servers join
        # ``self.servers`` as the kinds are built.
        self.servers: dict[str, UnitServer] = {}
        self.commands = CommandService(self.servers, self.command_inbox, self.stopping)
        # The latch directory before DDS and Zenoh: one it may not use (a symbolic link) is a
        # configuration error, and nothing is open yet to close.
        self.latches = LatchStore(
            state_dir or default_state_dir(),
            inventory.fleet,
            network.domain_id,
            self.guard,
            self._on_latch_written,
        )
        # DDS first: if the interface is wrong we fail before announcing anything on Zenoh.
        self._next_status = self._next_diag = 0.0
        self._diag_counts = self._bad_input_counts()
        try:
            self.link = DdsLink(network, self._tick, TICK_PERIOD_S, self.guard)
        except BaseException:
            self.latches.close()
            raise
        try:
            self.relay = ZenohRelay(
                inventory,
                arm_ids,
                (self.safety_inbox, self.command_inbox),
                self.guard,
                device_kinds,
                [arm for arm in mounted if arm not in arm_ids],
                self.mount_leases.on_status,
            )
        except BaseException:
            self.link.close()
            self.latches.close()
            raise
        try:
            self._build_kinds(inventory, [*arm_ids, *device_ids])
        except BaseException:
            self.link.close()
            self.relay.close()  # an open session can hang the process at exit
            self.latches.close()
            raise
        self.safety_loop = SafetyLoop(
            self.lock,
            self.units,
            self.servers,
            self.relay,
            self.safety_inbox,
            self.flush,
            self.stopping,
            self.guard,
            self.latches,
            mounted,
        )
        # The envelope's watchdog reads the safety loop's heartbeat table.
        self.principals.heartbeats = self.safety_loop.last_heartbeat_s
        # Stops latched before a restart, before any command can be served.
        for unit in self.units:
            request = self.latches.load(unit)
            if request is not None:
                self.safety_loop.restore(unit, request)
        self._threads = [
            self.safety_loop.thread,
            self.guard.thread(self.commands.run, "commands"),
            self.scheduler.thread,
            self.latches.thread,
            *(thread for server in self._kind_servers for thread in server.threads),
        ]

    def _build_kinds(self, inventory: Inventory, unit_ids: list[str]) -> None:
        """Every kind's side on the core's participant and session, then the tokens: the
        device kinds' drivers, and each served kind the same way, in the registry's order (its
        readers first in the relay's WaitSet, then the drivers')."""
        self.write_locks = WriteLocks(unit_ids)
        self.scheduler = StartScheduler(self.guard, self.stopping)
        self.principals = principals = Principals(inventory, {})
        self.devices = DeviceServer(
            self.lock,
            self.write_locks,
            self.relay,
            principals,
            self.stopping,
            (self._on_still, self._own_counts),
            self.reply_latencies_s,
            self._lease_of,
        )
        for device in self.device_ids:
            self.devices.add(inventory, device, self.link)
        core = CoreServices(
            lock=self.lock,
            guard=self.guard,
            stopping=self.stopping,
            write_lock=self.write_locks.of,
            dds=(self.link.participant, self.link.directory),
            zenoh=(self.relay.session, self.relay.keys),
            schedule=self._schedule,
            principals=principals,
            on_still=self._on_still,
            flush=self.flush,
            own_counts=self._own_counts,
        )
        self.sides: dict[str, KindSide] = {
            kind.name: kind.build(inventory, unit_ids, core) for kind in served_kinds()
        }
        for side in self.sides.values():
            self.link.add_part(side.link)
        self.link.add_drivers(
            {d: s.driver for d, s in self.devices.slots.items()}, self.devices.on_device
        )
        self.relay.announce([side.close for side in self.sides.values()])
        served = [(side.server, side.units) for side in self.sides.values()]
        self._kind_servers: list[UnitServer] = [*(s for s, _ in served), self.devices]
        self.units: dict[str, Unit] = {}
        for server, units in [*served, (self.devices, self.devices.slots)]:
            self.units |= units
            self.servers |= dict.fromkeys(units, server)

    def start(self) -> EdgeAgent:
        """Start relaying and serving commands."""
        self.link.start()
        for thread in self._threads:
            thread.start()
        return self

    def _schedule(self, due_s: float, run: Callable[[], None]) -> str | None:
        """Run ``run`` at ``due_s`` on the ``starts`` thread; why not, when it is full."""
        try:
            self.scheduler.schedule(due_s, run)
        except SchedulerFull as exc:
            return str(exc)
        return None

    def _on_still(self, unit: str, out: Outbox) -> None:
        """A stopped unit was seen still: its ack (caller holds the lock)."""
        self.safety_loop.on_still(unit, out)

    def _lease_of(self, arm: str, now: float) -> Lease | None:
        """Who holds ``arm`` (caller holds the lock): its safety state if this agent serves it,
        else its newest status."""
        served = self.units.get(arm)
        if served is None:
            return self.mount_leases.holder(arm, now)
        return served.safety.holder(now)

    def _on_latch_written(self, unit: str, why: str | None) -> None:
        """The latches thread wrote ``unit``'s latch, or could not (``why``): its status says
        whether its stop would survive a restart."""
        with self.lock:
            self.units[unit].safety.persist_error = why

    def _on_thread_failure(self, what: str) -> None:
        """The guard's failure path (on the failing thread): latch and stop every arm now;
        ``__main__`` then shuts down and exits 1."""
        self.safety_loop.latch_all(f"agent thread failed ({what}); restart the agent")

    # ------------------------------------------------------------------ the relay thread

    def _tick(self, now: float) -> None:
        """The periodic jobs, on the relay thread: every server's link state, command
        deadlines, status and diag."""
        stamp_ns = time.time_ns()
        periodic = now >= self._next_status
        if periodic:
            self._next_status = now + STATUS_PERIOD_S
        counts = self._bad_input_counts()
        diag = now >= self._next_diag or (
            counts != self._diag_counts and now >= self._next_diag - DIAG_PERIOD_S + DIAG_SOON_S
        )
        if diag:
            self._next_diag = now + DIAG_PERIOD_S
            self._diag_counts = counts
        out = Outbox()
        for server in self._kind_servers:
            server.tick(now, stamp_ns, periodic, diag, out)
        self.flush(out)

    def _bad_input_counts(self) -> tuple[int, ...]:
        counters = self.counters
        return (
            counters.bad_payloads,
            counters.undecodable_stops,
            counters.busy,
            counters.bad_stamps,
            counters.bad_keys,
            self.latches.failures,
        )

    def _own_counts(self, diag: m.Diag) -> m.Diag:
        """A unit's diag with the agent's own counters (the same in every unit's diag)."""
        counters = self.counters
        return msgspec.structs.replace(
            diag,
            bad_payloads=counters.bad_payloads,
            undecodable_stops=counters.undecodable_stops,
            busy=counters.busy,
            bad_stamps=counters.bad_stamps,
            bad_keys=counters.bad_keys,
            latch_failures=self.latches.failures,
            dropped_events=counters.dropped_events,
            write_failures=self.link.write_failures,
            stop_copies_reliable=counters.stop_copies[False],
            stop_copies_datagram=counters.stop_copies[True],
            beat_copies_reliable=counters.beat_copies[False],
            beat_copies_datagram=counters.beat_copies[True],
            datagram_replaced=self.relay.datagram.replaced,
        )

    def flush(self, out: Outbox) -> None:
        """Perform the puts and replies collected under the lock (call without it)."""
        for publisher, payload in out.puts:
            publisher.put(payload)
        for query, reply in out.replies:
            self.reply_latencies_s.append(reply.latency_ms / 1000.0)
            # On the arm's own key, not the query's: a wildcard query (arm/*/cmd/<principal>)
            # gets one reply per arm, which consolidation would merge on one wildcard key.
            answer(query, self.relay.keys.arm(reply.arm, keys.CMD), encode(reply))

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Shutdown order: stop taking commands (and drop pending synchronized starts) -> hold
        every robot still moving (nobody will command it any more; a G1's arms are handed back
        to the robot, over its release ramp, while the relay thread still streams) -> stop the
        loops and join
        -> stop DDS -> undeclare Zenoh (tokens first, so the fleet sees the agent leave) and
        close the session. Idempotent."""
        if self.stopping.is_set():
            return
        self.stopping.set()
        self.scheduler.cancel_all()
        self.scheduler.wake()
        for unit, server in self.servers.items():
            server.hold_if_moving(unit)
        for thread in self._threads:
            if thread is self.latches.thread:
                continue  # it runs until latches.close(), which writes the last stops
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self.latches.close()  # the latches of the last stops, written before the process ends
        self.link.close()
        self.relay.close()

    def __enter__(self) -> EdgeAgent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
