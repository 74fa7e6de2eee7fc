"""The agent's Zenoh side: stop and reset subscriptions, command queryables, stop acks and
liveliness tokens for every unit, and the device kinds' publishers (a served kind, the D1 arm,
declares its own on this session: ``fleet/d1arm/publishers.py``).

Publisher QoS, and why:
- a device's ``state``, ``lowstate`` and ``diag``: DROP (they repeat); ``contact``: BLOCK
  (events, rare and small).
- ``estop/ack``: REAL_TIME, on both paths (``fleet/wire/stoppath.py``), DROP: an
  ack goes with every repeat of its stop (the sender repeats until confirmed), and a put that
  waited for room in a TCP link backed off by loss held the safety thread (measured: seconds).
- ``reset/ack``: DATA_HIGH, DROP: one per unit and reset, rare; a lost one tells the resetting
  operator "no answer", never holds the safety thread.
- command replies go back on the query itself.
Callbacks run under the agent's guard: they only decode and hand off to the bounded inboxes
(``inbox.py``); they never block. The per-unit stop and reset callbacks run directly on
Zenoh's receive thread (``direct``): by default zenoh-python gives every callback a Python thread
of its own, which at 250 arms was 770 threads in one agent. Two kinds keep their thread: the
heartbeat (anyone allowed to beat can flood it; on the receive thread each beat would wait for
the GIL ahead of the next stop) and the command queries (one that finds the queue full answers
"busy" at once, and a reply must never wait for room in a congested send queue on the thread
that receives the stops).
"""

from __future__ import annotations

from collections.abc import Callable

import zenoh

from edge_agent.inbox import CommandInbox, SafetyInbox
from fleet.control import direct
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.security.session import datagram_session, open_session
from fleet.wire import keys
from fleet.wire.payloads import DEVICE_PAYLOADS
from fleet.wire.session import close_bounded
from fleet.wire.stoppath import TwoPathPublisher

JSON = zenoh.Encoding.APPLICATION_JSON


def principal_of(key: object) -> str | None:
    """The principal a heartbeat or command key ends with (the router lets only that principal
    use the key); None when the last chunk is not a name (a wildcard query)."""
    chunk = str(key).rpartition("/")[2]
    return chunk if keys.is_name(chunk) else None


class ZenohRelay:
    """Declares everything an agent needs on the key space, for the arms and devices it serves.

    ``devices``: device id -> its kind's key word; ``mounts``: arms this agent does not serve
    that devices it serves are mounted on (their stops and resets reach those devices too, and
    their statuses go to ``on_mount_status``: their leases cover those devices)."""

    def __init__(
        self,
        inventory: Inventory,
        arm_ids: list[str],
        inboxes: tuple[SafetyInbox, CommandInbox],
        guard: ThreadGuard,
        devices: dict[str, str] | None = None,
        mounts: list[str] | None = None,
        on_mount_status: Callable[[str, bytes], None] | None = None,
    ) -> None:
        devices = devices or {}
        self.keys = keys.KeySpace(inventory.fleet)
        self.session = open_session(inventory)
        # The stops' datagram path: stops and heartbeats also arrive over UDP, acks
        # also leave that way; opened here, before anything is announced.
        self.datagram = datagram_session(inventory, beside=self.session)
        safety, commands = inboxes
        wrap = guard.wrap

        def on_stop(arm: str | None):  # type: ignore[no-untyped-def]
            return direct(
                wrap(lambda sample: safety.on_stop(arm, sample.payload.to_bytes()), "estop")
            )

        def on_reset(arm: str | None):  # type: ignore[no-untyped-def]
            return direct(
                wrap(lambda sample: safety.on_reset(arm, sample.payload.to_bytes()), "reset")
            )

        def on_query(arm: str):  # type: ignore[no-untyped-def]
            return wrap(lambda query: commands.on_query(arm, query), "cmd")

        def on_heartbeat(datagram: bool):  # type: ignore[no-untyped-def]
            return wrap(
                lambda sample: safety.on_heartbeat(  # length checked before any copy
                    principal_of(sample.key_expr), sample.payload, datagram
                ),
                "heartbeat",
            )

        sub = self.session.declare_subscriber
        self._subscribers: list[zenoh.Subscriber[None]] = [
            sub(self.keys.estop, on_stop(None)),
            sub(self.keys.reset, on_reset(None)),
        ]
        stop_keys: list[tuple[str, str | None]] = [(self.keys.estop, None)]
        for arm in [*arm_ids, *(mounts or [])]:
            stop_keys.append((self.keys.arm(arm, keys.ESTOP), arm))
            self._subscribers.append(sub(self.keys.arm(arm, keys.RESET), on_reset(arm)))
        for device, kind in devices.items():
            estop, reset = (self.keys.device(kind, device, c) for c in (keys.ESTOP, keys.RESET))
            stop_keys.append((estop, device))
            self._subscribers.append(sub(reset, on_reset(device)))
        for key, unit in stop_keys[1:]:
            self._subscribers.append(sub(key, on_stop(unit)))
        if on_mount_status is not None:

            def on_status(arm: str):  # type: ignore[no-untyped-def]
                return direct(  # decode and store the newest: microseconds
                    wrap(lambda s: on_mount_status(arm, s.payload.to_bytes()), "mount-status")
                )

            for arm in mounts or []:
                self._subscribers.append(sub(self.keys.arm(arm, keys.STATUS), on_status(arm)))
        datagram, on_reliable_beat = self.datagram, on_heartbeat(False)

        def on_reliable_heartbeat(sample: zenoh.Sample) -> None:
            beat = on_reliable_beat(sample)
            if beat is not None and beat.datagram_copies:
                datagram.heard_reliably()  # its copies are due on the datagram path too

        self._subscribers.append(sub(self.keys.heartbeat, on_reliable_heartbeat))
        # Resets never take the datagram path: a reset must not overtake the stop before it.
        units = dict(stop_keys)
        safety_stop = safety.on_stop

        def on_datagram_stop(sample: zenoh.Sample) -> None:
            key = keys.reliable_key(str(sample.key_expr))
            if key in units:
                safety_stop(units[key], sample.payload.to_bytes(), True)

        # The datagram copies' own keys (``keys.DATAGRAM``), on the receive thread (``direct``:
        # decoding a beat and keeping the newest per source is microseconds), declared again
        # and again (``DatagramSession.subscribe``). The TCP subscriptions stay: if this
        # session is down, the reliable copies still arrive.
        self._datagram_subscriptions = [
            # watched: the beats come on both paths, so a datagram session that hears none
            # while TCP delivers them is deaf and is replaced (``stoppath.DEAF_S``)
            self.datagram.subscribe(self.keys.heartbeat, direct(on_heartbeat(True)), watched=True),
            self.datagram.subscribe(
                f"{self.keys.prefix}/**/{keys.ESTOP}", direct(wrap(on_datagram_stop, "estop"))
            ),
        ]
        self.datagram.open()
        self.stop_acks: dict[str, TwoPathPublisher] = {}
        """Every served unit's ``estop/ack`` (the safety thread's)."""
        self.reset_acks: dict[str, zenoh.Publisher] = {}
        """Every served unit's ``reset/ack`` (the safety thread's)."""
        self._tokens: list[zenoh.LivelinessToken] = []
        self._queryables: list[zenoh.Queryable[None]] = []
        self._kinds_closing: list[Callable[[], None]] = []
        for arm in arm_ids:
            ack_key = self.keys.arm(arm, keys.ESTOP_ACK)
            self.stop_acks[arm] = TwoPathPublisher(self.session, self.datagram, ack_key)
            self.reset_acks[arm] = self._reset_ack_publisher(self.keys.arm(arm, keys.RESET_ACK))
            self._queryables.append(
                self.session.declare_queryable(self.keys.commands(arm), on_query(arm))
            )
        self.device_publishers: dict[str, dict[str, zenoh.Publisher]] = {}
        for device, kind in devices.items():
            self.device_publishers[device] = self._declare_device_publishers(kind, device)
            ack_key = self.keys.device(kind, device, keys.ESTOP_ACK)
            self.stop_acks[device] = TwoPathPublisher(self.session, self.datagram, ack_key)
            reset_ack_key = self.keys.device(kind, device, keys.RESET_ACK)
            self.reset_acks[device] = self._reset_ack_publisher(reset_ack_key)
            commands_key = f"{self.keys.device(kind, device, keys.CMD)}/*"
            self._queryables.append(self.session.declare_queryable(commands_key, on_query(device)))
        self._token_keys = [self.keys.arm(arm, keys.AGENT) for arm in arm_ids]
        self._token_keys += [self.keys.device(kind, d, keys.AGENT) for d, kind in devices.items()]

    def announce(self, kinds_closing: list[Callable[[], None]]) -> None:
        """Declare the agent's tokens, once every kind declared its publishers: an agent is
        announced only once it can serve its robots. ``kinds_closing`` undeclare what the
        kinds declared on this session (at ``close``, after the tokens)."""
        self._kinds_closing = list(kinds_closing)
        for token in self._token_keys:
            self._tokens.append(self.session.liveliness().declare_token(token))

    def _declare_device_publishers(self, kind: str, device: str) -> dict[str, zenoh.Publisher]:
        """state, lowstate (a G1's) and diag: DROP (they repeat); contact: BLOCK (events)."""
        drop, block = zenoh.CongestionControl.DROP, zenoh.CongestionControl.BLOCK
        lowstate = keys.LOWSTATE in DEVICE_PAYLOADS.get(kind, {})
        extra = ((keys.LOWSTATE, drop, zenoh.Priority.DATA),) if lowstate else ()
        return {
            channel: self.session.declare_publisher(
                self.keys.device(kind, device, channel),
                encoding=JSON,
                congestion_control=congestion,
                priority=priority,
            )
            for channel, congestion, priority in (
                (keys.STATE, drop, zenoh.Priority.DATA_HIGH),
                (keys.CONTACT, block, zenoh.Priority.DATA_HIGH),
                (keys.DIAG, drop, zenoh.Priority.DATA),
                *extra,
            )
        }

    def _reset_ack_publisher(self, key: str) -> zenoh.Publisher:
        return self.session.declare_publisher(
            key,
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.DATA_HIGH,
        )

    def reset_ack(self, unit: str) -> zenoh.Publisher:
        """The ``reset/ack`` publisher of arm or device ``unit``."""
        return self.reset_acks[unit]

    def stop_ack(self, unit: str) -> TwoPathPublisher:
        """The ``estop/ack`` publisher of arm or device ``unit``."""
        return self.stop_acks[unit]

    def device_put(self, device: str) -> Callable[[str, bytes, bool], None]:
        """A driver's ``Put`` onto its device's publishers."""
        publishers = self.device_publishers[device]

        def put(channel: str, payload: bytes, _reliable: bool) -> None:
            publishers[channel].put(payload)

        return put

    def close(self) -> None:
        """Undeclare tokens first (the fleet sees the agent leave), then close the session."""
        for token in self._tokens:
            token.undeclare()
        self._tokens.clear()
        for undeclare in self._kinds_closing:
            undeclare()
        self._kinds_closing.clear()
        for queryable in self._queryables:
            queryable.undeclare()
        self._queryables.clear()
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._subscribers.clear()
        for ack in self.stop_acks.values():
            ack.undeclare()
        self.stop_acks.clear()
        for reset_ack in self.reset_acks.values():
            reset_ack.undeclare()
        self.reset_acks.clear()
        for device_pubs in self.device_publishers.values():
            for publisher in device_pubs.values():
                publisher.undeclare()
        self.device_publishers.clear()
        for subscription in self._datagram_subscriptions:
            subscription.cancel()
        self._datagram_subscriptions.clear()
        self.datagram.close()
        close_bounded(self.session, "session")
