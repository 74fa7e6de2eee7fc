"""A thin client over the public key space: what the CLI uses, and what any Zenoh client can do.

Nothing here is private to d1-fleet: every call is a query or a subscription on documented keys.
"""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

import msgspec
import zenoh

from fleet.devices import kind_of
from fleet.devices.base import DeviceReply
from fleet.devices.driver import error_reply
from fleet.inventory import Inventory
from fleet.security.session import datagram_session, open_session
from fleet.wire import keys, payloads, stoppath
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo, encode
from fleet.wire.session import close_bounded

JSON = zenoh.Encoding.APPLICATION_JSON
DEVICE_REPLY = payloads.DEVICE_REPLY
REPLY_MARGIN_S = 2.0
"""A command's query waits this much longer than the command's own timeout."""
AS_THEY_COME = zenoh.ConsolidationMode.NONE
"""How a command's query takes its replies: each one the moment it arrives. Zenoh's default
(latest per key) holds every reply until the query is final, and a query is final only when
every queryable the routers sent it to has answered: one that never does (a stale route after a
session reconnected under loss, a frozen or hostile process declaring the key) held every
command's reply until its timeout (measured in the network lab after 30 % loss: a synchronized
move's reply 5.0 s after the arms had moved). The agents reply on each arm's own key, so there
is nothing to merge."""
COMMAND_LIFETIME_S = 5.0
"""A command that reaches its agent later than this after it was sent is refused (4005): a
replay, or a network that held it, never executes it late. Hosts' clocks must agree to well
within this (NTP); a streamed target sets its own, shorter lifetime."""


def start_at_ns(lead_s: float) -> int:
    """A synchronized start ``lead_s`` from now (``start_at_ns`` of every arm's command). The
    time base is this host's wall clock, compared by each agent with its own: keep hosts
    NTP/PTP-synchronized."""
    return time.time_ns() + int(lead_s * 1e9)


def _no_reply(arm: str, why: str) -> m.CommandReply:
    return m.CommandReply(
        ok=False,
        arm=arm,
        seq=None,
        received=False,
        executed=None,
        reached=None,
        latency_ms=0.0,
        error=ErrorInfo(int(ErrorCode.NO_AGENT), why),
    )


STOP_QOS = stoppath.RELIABLE_QOS
"""Stops and resets: never dropped under congestion, and sent ahead of everything else (a
stop also goes the datagram path: ``fleet/wire/stoppath.py``)."""


def default_source() -> str:
    """``user@host`` for stops and commands a person triggers."""
    return f"{os.environ.get('USER', 'user')}@{socket.gethostname()}"


S = TypeVar("S", bound=msgspec.Struct)
"""A command Struct with the envelope (``stamp_ns``, ``lifetime_s``)."""


class FleetClient:
    """A Zenoh session on the fleet's key space. A context manager."""

    def __init__(
        self,
        inventory: Inventory,
        session: zenoh.Session | None = None,
        connect_timeout_s: float = 10.0,
        datagram: stoppath.DatagramSession | None = None,
    ) -> None:
        self.inventory = inventory
        self.keys = keys.KeySpace(inventory.fleet)
        self._own_session = session is None
        self.principal = inventory.principal
        self._stamp_lock = threading.Lock()
        self._last_stamp_ns = 0
        self._stop_pubs: dict[str, stoppath.TwoPathPublisher] = {}  # guarded by _stop_lock
        self._stop_lock = threading.Lock()
        self._ack_subscribers: list[zenoh.Subscriber[None]] = []  # guarded by _stop_lock
        self._datagram_acks: stoppath.DatagramSubscription | None = None
        self._ack_waiters: dict[str, Callable[[str, m.StopAck, bool], None]] = {}  # by stop_id
        if session is None:
            session = open_session(inventory, connect_timeout_s=connect_timeout_s)
        self.session = session
        self._own_datagram = datagram is None
        if datagram is None:  # the stops' datagram path (issue 24), opened beside
            datagram = datagram_session(inventory, beside=session)
            datagram.start()
        self.datagram = datagram

    # ------------------------------------------------------------------ commands

    def stamp(self, command: S) -> S:
        """``command`` with a ``stamp_ns`` (the agent serves each stamp once and, per owner, in
        order) and a lifetime if it has none. A caller's own stamp is kept (a streamed target
        is stamped when it was computed); otherwise this client's clock, strictly increasing."""
        with self._stamp_lock:
            if command.stamp_ns is not None:
                stamp = command.stamp_ns
                self._last_stamp_ns = max(self._last_stamp_ns, stamp)
            else:
                self._last_stamp_ns = max(time.time_ns(), self._last_stamp_ns + 1)
                stamp = self._last_stamp_ns
        lifetime = command.lifetime_s if command.lifetime_s is not None else COMMAND_LIFETIME_S
        return msgspec.structs.replace(command, stamp_ns=stamp, lifetime_s=lifetime)

    def command(self, arm: str, command: m.ArmCommand) -> m.CommandReply:
        """Send ``command`` to ``arm``'s agent (stamped, see ``stamp``) and wait for its reply."""
        self.inventory.arm(arm)  # unknown arm: InventoryError with the known ones
        command = self.stamp(command)
        timeout = (command.timeout_s if command.wait_reached else 3.0) + REPLY_MARGIN_S
        for reply in self.ask(self.command_key(arm), encode(command), timeout):
            if reply.ok is None:
                continue
            try:
                return payloads.REPLY.decode(reply.ok.payload.to_bytes())
            except payloads.PayloadError as exc:
                return _no_reply(arm, f"arm {arm!r}: unreadable reply from its agent: {exc}")
        why = (
            f"arm {arm!r}: no reply from its agent within {timeout:g} s "
            f"(no token on {self.keys.arm(arm, keys.AGENT)}?); is its edge-agent running?"
        )
        if self.inventory.security.enabled:
            role = self.inventory.role_of(self.principal)
            why += (
                f" Or the router's access control refused the command: principal "
                f"{self.principal!r} (role {role}) may command arms only as an operator, "
                "maintainer or coordinator"
            )
        return _no_reply(arm, why)

    def device_command(
        self, device: str, command: msgspec.Struct | bytes, timeout_s: float = 3.0
    ) -> DeviceReply:
        """Send ``command`` (a kind's command Struct, or its JSON) to a device's agent
        (``<kind>/<device>/cmd/<principal>``) and wait for its reply."""
        kind = kind_of(self.inventory.device(device)).key
        key = self.keys.device_command(kind, device, self.principal)
        data = command if isinstance(command, bytes) else encode(self.stamp(command))
        for reply in self.ask(key, data, timeout_s):
            if reply.ok is None:
                continue
            try:
                return DEVICE_REPLY.decode(reply.ok.payload.to_bytes())
            except payloads.PayloadError as exc:
                why = f"{kind} {device!r}: unreadable reply from its agent: {exc}"
                return error_reply(device, ErrorCode.UNKNOWN, why)
        why = (
            f"{kind} {device!r}: no reply from its agent within {timeout_s:g} s (no token on "
            f"{self.keys.device(kind, device, keys.AGENT)}?); is the edge-agent of its card "
            f"(`edge-agent --interface {self.inventory.device(device).interface}`) running?"
        )
        return error_reply(device, ErrorCode.NO_AGENT, why)

    def multi(
        self,
        target: str,
        command: m.ArmCommand,
        sync: bool = True,
        lead_s: float | None = None,
        partial: bool = False,
    ) -> m.MultiArmReply:
        """Send ``command`` to an arm, a group or ``all`` through the coordinator (one owner,
        synchronized start: all or nothing unless ``partial``). Fails with 4001 when no
        coordinator answers."""
        self.inventory.resolve(target)
        request = m.MultiArmRequest(
            target=target, command=command, sync=sync, lead_s=lead_s, partial=partial
        )
        timeout = (command.timeout_s if command.wait_reached else 3.0) + 2 * REPLY_MARGIN_S
        key = self.keys.coordinator_command(self.principal)
        for reply in self.ask(key, encode(request), timeout):
            if reply.ok is not None:
                try:
                    return payloads.MULTI_REPLY.decode(reply.ok.payload.to_bytes())
                except payloads.PayloadError as exc:
                    why = f"unreadable reply from the coordinator: {exc}"
                    return m.MultiArmReply(False, {}, None, ErrorInfo(int(ErrorCode.UNKNOWN), why))
        why = f"no coordinator answered on {key}; is `fleet coordinator` running?"
        return m.MultiArmReply(False, {}, None, ErrorInfo(int(ErrorCode.NO_AGENT), why))

    def ask(self, key: str, payload: bytes, timeout_s: float) -> Iterator[zenoh.Reply]:
        """A command's query: its replies as they arrive (``AS_THEY_COME``), for up to
        ``timeout_s``."""
        return iter(
            self.session.get(
                key, payload=payload, encoding=JSON, consolidation=AS_THEY_COME, timeout=timeout_s
            )
        )

    def command_key(self, arm: str) -> str:
        """Where this client's commands to ``arm`` go (``arm/<arm>/cmd/<principal>``)."""
        return self.keys.command(arm, self.principal)

    # ------------------------------------------------------------------ protective stop

    def estop(
        self,
        arm: str | None = None,
        reason: str = "",
        source: str | None = None,
        timeout_s: float = 3.0,
        wait_still: bool = True,
        request: m.StopRequest | None = None,
        copies: dict[str, list[int]] | None = None,
    ) -> dict[str, m.StopAck | None]:
        """Stop one arm or device (or every arm and device) and wait for the agents'
        acknowledgments (devices are named ``<kind>/<id>`` in the result).

        The stop is re-put every 100 ms with the same ``stop_id`` until every targeted arm
        acknowledged it, and with ``wait_still`` until each was seen still (Zenoh's reliability
        is hop by hop, not end to end; each repeat earns a fresh ack); agents ignore the
        repeats. Each put goes both paths (``fleet/wire/stoppath.py``), and for the first 250 ms
        the datagram path repeats it every 10 ms. Returns the last ack per arm (None: no ack
        within ``timeout_s``: is that arm's agent running?).
        ``request``: a stop already put once (its repeats and acks are handled here).
        ``copies``: filled with each unit's count of ack copies received, ``[reliable,
        datagram]`` (which path confirmed it, or that neither did).
        """
        arms, devices = self._reached_by(arm)
        if request is None:
            request = self.stop_request(reason, source)
        acks: dict[str, m.StopAck | None] = dict.fromkeys([*arms, *devices])
        lock = threading.Lock()
        counts = copies if copies is not None else {}
        counts.update({label: [0, 0] for label in acks})

        def on_ack(label: str, ack: m.StopAck, datagram: bool) -> None:
            if ack.stop_id != request.stop_id or label not in acks:
                return
            with lock:
                counts[label][datagram] += 1
                held = acks[label]
                if held is None or not held.done:  # the two paths may deliver out of order
                    acks[label] = ack

        def complete() -> bool:
            with lock:
                return all(a is not None and (a.done or not wait_still) for a in acks.values())

        self.watch_stop_acks()
        with self._stop_lock:
            self._ack_waiters[request.stop_id] = on_ack
        started = time.monotonic()
        deadline = started + timeout_s
        next_put = started
        try:
            while True:
                # Until every unit confirmed (acked, and still with ``wait_still``): the agent
                # answers each repeat with a fresh ack, so a lost "still" ack is sent again.
                unacked = not complete()
                now = time.monotonic()
                if unacked and now >= next_put:
                    self.put_stop(request, arm)
                    next_put = now + 0.1
                elif unacked and now - started <= stoppath.BURST_S:
                    self.put_stop(request, arm, datagram_only=True)
                if complete() or now >= deadline:
                    break
                burst = now - started < stoppath.BURST_S
                time.sleep(stoppath.BURST_INTERVAL_S if burst else 0.1)
        finally:
            with self._stop_lock:
                if self._ack_waiters.get(request.stop_id) is on_ack:
                    del self._ack_waiters[request.stop_id]
        with lock:
            return dict(acks)

    def _reached_by(self, arm: str | None) -> tuple[list[str], dict[str, str]]:
        """The units a stop or reset of ``arm`` (None: the fleet's) reaches: arm ids, and
        devices by label (``<kind>/<id>`` -> id); an arm's reaches the devices mounted on it."""
        if arm is not None and arm in self.inventory.devices:
            return [], {f"{kind_of(self.inventory.device(arm)).key}/{arm}": arm}
        if arm is None:
            return list(self.inventory.arms), self.device_labels()
        mounted = {
            label: d
            for label, d in self.device_labels().items()
            if getattr(self.inventory.device(d), "mount", "") == arm
        }
        return [self.inventory.arm(arm).id], mounted

    def _unit_label(self, key: str, channel: str) -> str:
        """An arm's id or a device's ``<kind>/<id>``, from a per-unit key of ``channel``."""
        label = key[len(self.keys.prefix) + 1 :].removesuffix(f"/{channel}")
        kind, _, unit = label.partition("/")
        return unit if kind == keys.ARM else label

    def watch_stop_acks(self) -> None:
        """Subscribe to every stop acknowledgment once, on both paths, for the life of the
        client (idempotent; ``estop`` calls it). A subscription declared with each stop would
        reach the router over TCP: under loss, after the acks it waits for."""
        key = f"{self.keys.prefix}/**/{keys.ESTOP_ACK}"
        with self._stop_lock:
            if not self._ack_subscribers:
                self._ack_subscribers.append(
                    self.session.declare_subscriber(key, self._on_stop_ack)
                )
                # The acks' datagram copies, now or once that session opens.
                self._datagram_acks = self.datagram.subscribe(key, self._on_stop_ack)

    def _on_stop_ack(self, sample: zenoh.Sample) -> None:
        """An ack of an arm (labelled by its id) or a device (``<kind>/<id>``), handed to the
        ``estop`` waiting for its stop (the label from the key, not the payload)."""
        received_on = str(sample.key_expr)
        key = keys.reliable_key(received_on)
        label = self._unit_label(key, keys.ESTOP_ACK)
        try:
            ack = payloads.STOP_ACK.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            return
        with self._stop_lock:
            waiter = self._ack_waiters.get(ack.stop_id)
        if waiter is not None:
            waiter(label, ack, received_on != key)

    def device_snapshot(self, wait_s: float = 1.2) -> dict[str, Any]:
        """``<kind>/<id>`` -> the newest decoded state of every device (None: none heard
        within ``wait_s``; every device state repeats at least once a second)."""
        found: dict[str, Any] = dict.fromkeys(self.device_labels())
        if not found:
            return found
        lock = threading.Lock()
        subscribers = []
        prefix = f"{self.keys.prefix}/"
        for kind in {kind_of(d) for d in self.inventory.devices.values()}:
            decoder = kind.payloads[keys.STATE]

            def on_state(sample: zenoh.Sample, decoder: Any = decoder) -> None:
                label = str(sample.key_expr)[len(prefix) :].removesuffix(f"/{keys.STATE}")
                try:
                    state = decoder.decode(sample.payload.to_bytes())
                except payloads.PayloadError:
                    return
                with lock:
                    if label in found:
                        found[label] = state

            key = self.keys.device(kind.key, "*", keys.STATE)
            subscribers.append(self.session.declare_subscriber(key, on_state))
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            with lock:
                if all(v is not None for v in found.values()):
                    break
            time.sleep(0.05)
        for subscriber in subscribers:
            subscriber.undeclare()
        with lock:
            return dict(found)

    def device_labels(self) -> dict[str, str]:
        """``<kind>/<id>`` -> id for every device of the inventory (how ``estop`` and
        ``fleet status`` name them)."""
        return {f"{kind_of(d).key}/{d.id}": d.id for d in self.inventory.devices.values()}

    def stop_request(self, reason: str = "", source: str | None = None) -> m.StopRequest:
        """A new stop with a fresh ``stop_id``."""
        return m.StopRequest(
            stamp_ns=time.time_ns(),
            source=source or default_source(),
            stop_id=uuid.uuid4().hex,
            reason=reason,
        )

    def unit_key(self, unit: str, channel: str) -> str:
        """``channel`` of arm or device ``unit`` (InventoryError for neither)."""
        if unit in self.inventory.devices:
            kind = kind_of(self.inventory.device(unit)).key
            return self.keys.device(kind, unit, channel)
        return self.keys.arm(self.inventory.arm(unit).id, channel)

    def put_stop(
        self, request: m.StopRequest, arm: str | None = None, datagram_only: bool = False
    ) -> None:
        """Put ``request`` once on the fleet's (or one arm's or device's) stop key, on both
        paths (or only the datagram path: a fast repeat)."""
        key = self.keys.estop if arm is None else self.unit_key(arm, keys.ESTOP)
        with self._stop_lock:
            publisher = self._stop_pubs.get(key)
            if publisher is None:
                publisher = self._stop_pubs[key] = stoppath.TwoPathPublisher(
                    self.session, self.datagram, key
                )
        data = encode(request)
        if datagram_only:
            publisher.put_datagram(data)
        else:
            publisher.put(data)

    def reset(
        self, arm: str | None = None, source: str | None = None, reset_id: str | None = None
    ) -> None:
        """Release the stop latch of one arm or device (or of every one; an arm's reset
        releases the devices mounted on it too). Never moves anything. With ``reset_id``
        each unit reached answers on its ``reset/ack`` (``reset_and_report``)."""
        key = self.keys.reset if arm is None else self.unit_key(arm, keys.RESET)
        request = m.ResetRequest(
            stamp_ns=time.time_ns(), source=source or default_source(), reset_id=reset_id
        )
        self.session.put(key, encode(request), encoding=JSON, **STOP_QOS)

    def reset_and_report(
        self, arm: str | None = None, source: str | None = None, timeout_s: float = 3.0
    ) -> dict[str, m.ResetAck | None]:
        """``reset``, then what it did to each unit it reaches (arms by id, devices as
        ``<kind>/<id>``; None: no answer within ``timeout_s``: is its agent running?)."""
        arms, devices = self._reached_by(arm)
        answers: dict[str, m.ResetAck | None] = dict.fromkeys([*arms, *devices])
        reset_id = uuid.uuid4().hex
        done = threading.Event()
        lock = threading.Lock()

        def on_ack(sample: zenoh.Sample) -> None:
            label = self._unit_label(str(sample.key_expr), keys.RESET_ACK)
            try:
                ack = payloads.RESET_ACK.decode(sample.payload.to_bytes())
            except payloads.PayloadError:
                return
            with lock:
                if ack.reset_id != reset_id or label not in answers:
                    return
                answers[label] = ack
                if all(a is not None for a in answers.values()):
                    done.set()

        subscriber = self.session.declare_subscriber(
            f"{self.keys.prefix}/**/{keys.RESET_ACK}", on_ack
        )
        try:
            self.reset(arm, source, reset_id)
            done.wait(timeout_s)
        finally:
            subscriber.undeclare()
        with lock:
            return dict(answers)

    # ------------------------------------------------------------------ state

    def agents_alive(self) -> set[str]:
        """Arms whose agent liveliness token is present now."""
        alive = set()
        for reply in self.session.liveliness().get(self.keys.all_arms(keys.AGENT), timeout=1.0):
            if reply.ok is not None:
                alive.add(self.keys.parse_arm_key(str(reply.ok.key_expr)).arm)
        return alive

    def snapshot(
        self, arms: Iterable[str] | None = None, wait_s: float = 1.5
    ) -> dict[str, tuple[m.ArmStatus | None, m.Joints | None]]:
        """The latest status and joints of each arm, collected for up to ``wait_s`` seconds."""
        wanted = list(arms) if arms is not None else list(self.inventory.arms)
        statuses: dict[str, m.ArmStatus] = {}
        joints: dict[str, m.Joints] = {}
        done = threading.Event()
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                key = self.keys.parse_arm_key(str(sample.key_expr))
                data = sample.payload.to_bytes()
                payload = payloads.decode(key.channel, data)
                with lock:
                    if isinstance(payload, m.ArmStatus):
                        statuses[key.arm] = payload
                    elif isinstance(payload, m.Joints):
                        joints[key.arm] = payload
                    if all(a in statuses and a in joints for a in wanted):
                        done.set()
            except (keys.KeyError_, payloads.PayloadError):
                return  # someone else's key or a foreign payload: not ours to report

        subs = [
            self.session.declare_subscriber(self.keys.all_arms(channel), on_sample)
            for channel in (keys.STATUS, keys.JOINTS)
        ]
        done.wait(wait_s)
        for sub in subs:
            sub.undeclare()
        with lock:
            return {a: (statuses.get(a), joints.get(a)) for a in wanted}

    def fleet_state(self, wait_s: float = 0.5) -> m.FleetState | None:
        """The coordinator's latest fleet state (it publishes 5 times a second), or None when
        no coordinator spoke within ``wait_s``."""
        got: list[m.FleetState] = []
        ready = threading.Event()

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                got.append(payloads.STATE.decode(sample.payload.to_bytes()))
            except payloads.PayloadError:
                return  # a foreign payload: not ours to report
            ready.set()

        sub = self.session.declare_subscriber(self.keys.state, on_sample)
        ready.wait(wait_s)
        sub.undeclare()
        return got[-1] if got else None

    def close(self) -> None:
        """Close the session if this client opened it (idempotent)."""
        with self._stop_lock:
            publishers, self._stop_pubs = list(self._stop_pubs.values()), {}
            acks, self._ack_subscribers = self._ack_subscribers, []
        if not self.session.is_closed():
            for publisher in publishers:
                publisher.undeclare()
            if acks:
                acks[0].undeclare()
        datagram_acks, self._datagram_acks = self._datagram_acks, None
        if datagram_acks is not None:
            datagram_acks.cancel()
        if self._own_datagram:
            self.datagram.close()
        if self._own_session:
            close_bounded(self.session, "session")

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
