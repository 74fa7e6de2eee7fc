"""A fleet client that lives on a lab host: the test drives it with one JSON request per line
on stdin and reads one JSON reply per line on stdout.

Everything goes through FleetClient's public methods (estop, reset, command, device_command,
multi, snapshot, device_snapshot, agents_alive); ``watch`` records the joints and status samples
of the arms and the state samples of the devices it receives, with their arrival time, for the
relay and standstill measurements; ``diag`` reads one arm's or device's counters.

``python -m tests.netlab.clientd INVENTORY`` (under ``ip netns exec``).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from fleet.client import FleetClient
from fleet.devices import kind_of
from fleet.inventory import load_inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m

MAX_WATCHED = 100_000
"""Samples kept by ``watch`` between two takes (older ones are dropped and counted)."""


class Watch:
    """Joints and status samples of every arm and state samples of every device (as
    ``(arrival ns, unit id, "state", state)``), with the time each arrived here."""

    def __init__(self, client: FleetClient) -> None:
        self._lock = threading.Lock()
        self.samples: list[tuple[int, str, str, Any]] = []
        self.dropped = 0
        self._subs = [
            client.session.declare_subscriber(
                client.keys.all_arms(channel), self._on_sample(client, channel)
            )
            for channel in (keys.JOINTS, keys.STATUS)
        ]
        self._subs += [
            client.session.declare_subscriber(key, on_state)
            for key, on_state in device_state_callbacks(client, self._add)
        ]

    def _add(self, now: int, unit: str, channel: str, value: Any) -> None:
        with self._lock:
            if len(self.samples) >= MAX_WATCHED:
                self.dropped += 1
                return
            self.samples.append((now, unit, channel, value))

    def _on_sample(self, client: FleetClient, channel: str) -> Any:
        kind = payloads.JOINTS if channel == keys.JOINTS else payloads.STATUS

        def on_sample(sample: zenoh.Sample) -> None:
            now = time.time_ns()
            try:
                arm = client.keys.parse_arm_key(str(sample.key_expr)).arm
                value = msgspec.to_builtins(kind.decode(sample.payload.to_bytes()))
            except (keys.KeyError_, payloads.PayloadError):
                return
            self._add(now, arm, channel, value)

        return on_sample

    def take(self) -> dict[str, Any]:
        """Every sample since the last take."""
        with self._lock:
            samples, self.samples = self.samples, []
            dropped, self.dropped = self.dropped, 0
        return {"samples": samples, "dropped": dropped}

    def close(self) -> None:
        """Undeclare the subscribers."""
        for sub in self._subs:
            sub.undeclare()


def device_state_callbacks(
    client: FleetClient, add: Callable[[int, str, str, Any], None]
) -> list[tuple[str, Callable[[zenoh.Sample], None]]]:
    """(key, callback) per device kind of the inventory: each decoded state sample goes to
    ``add(arrival ns, device id, "state", state as builtins)``."""
    found = []
    for kind in {kind_of(d) for d in client.inventory.devices.values()}:
        prefix = f"{client.keys.prefix}/{kind.key}/"
        decoder = kind.payloads[keys.STATE]

        def on_state(sample: zenoh.Sample, decoder: Any = decoder, prefix: str = prefix) -> None:
            now = time.time_ns()
            unit = str(sample.key_expr)[len(prefix) :].partition("/")[0]
            try:
                value = msgspec.to_builtins(decoder.decode(sample.payload.to_bytes()))
            except payloads.PayloadError:
                return
            add(now, unit, keys.STATE, value)

        found.append((client.keys.device(kind.key, "*", keys.STATE), on_state))
    return found


class Daemon:
    """The requests this client serves."""

    def __init__(self, client: FleetClient) -> None:
        self.client = client
        self.watch: Watch | None = None
        self._last_stop: m.StopRequest | None = None
        self._streams: dict[str, tuple[threading.Thread, threading.Event, list[Any]]] = {}
        self._as: dict[str, FleetClient] = {}
        self._states_lock = threading.Lock()
        self._states: dict[str, Any] = {}  # device id -> its newest state (guarded)
        self._state_subs = [
            client.session.declare_subscriber(key, on_state)
            for key, on_state in device_state_callbacks(client, self._on_state)
        ]

    def _on_state(self, _now: int, unit: str, _channel: str, value: Any) -> None:
        with self._states_lock:
            self._states[unit] = value

    def ready(self, timeout_s: float = 30.0) -> dict[str, Any]:
        """Wait until every arm and device reports link ok, every arm agent's token is present
        and the coordinator publishes its fleet state (a coordinator a test killed and the lab
        restarted may still be connecting: a multi-arm request then found nobody to answer it)."""
        arms = list(self.client.inventory.arms)
        deadline = time.monotonic() + timeout_s
        while True:
            snap = self.client.snapshot(arms, wait_s=1.0)
            devices = self.client.device_snapshot(wait_s=1.0)
            ok = all(s is not None and s.link == "ok" for s, _j in snap.values())
            ok = ok and all(s is not None and s.link == "ok" for s in devices.values())
            if (
                ok
                and self.client.agents_alive() >= set(arms)
                and self.client.fleet_state(wait_s=1.0) is not None
            ):
                return {"ready": True}
            if time.monotonic() > deadline:
                return {"ready": False, "snapshot": _builtins(snap), "devices": _builtins(devices)}
            time.sleep(0.2)

    def estop(
        self, arm: str | None = None, timeout_s: float = 5.0, reason: str = "", again: bool = False
    ) -> dict[str, Any]:
        """A protective stop, timed: the request's stamp, when estop() returned, the acks and
        each unit's ack copies per path (``[reliable, datagram]``).
        ``again``: the previous stop once more (same stop_id), e.g. after a partition."""
        if again and self._last_stop is not None:
            request = self._last_stop
        else:
            request = self._last_stop = self.client.stop_request(reason=reason, source="netlab")
        copies: dict[str, list[int]] = {}
        acks = self.client.estop(arm=arm, timeout_s=timeout_s, request=request, copies=copies)
        return {
            "stamp_ns": request.stamp_ns,
            "returned_ns": time.time_ns(),
            "acks": acks,
            "copies": copies,
        }

    def reset(self, arm: str | None = None) -> dict[str, Any]:
        """One reset put."""
        self.client.reset(arm=arm, source="netlab")
        return {}

    def reset_wait(self, timeout_s: float = 10.0) -> dict[str, Any]:
        """Reset every arm and device until none reports a latched stop."""
        arms = list(self.client.inventory.arms)
        deadline = time.monotonic() + timeout_s
        while True:
            self.client.reset(source="netlab")
            snap = self.client.snapshot(arms, wait_s=1.0)
            devices = self.client.device_snapshot(wait_s=1.0)
            if all(s is not None and not s.estopped for s, _j in snap.values()) and all(
                s is not None and not s.estopped for s in devices.values()
            ):
                return {"clear": True}
            if time.monotonic() > deadline:
                return {"clear": False, "snapshot": _builtins(snap), "devices": _builtins(devices)}

    def command(self, arm: str, command: dict[str, Any]) -> dict[str, Any]:
        """One command to one arm; the reply and how long it took."""
        typed = msgspec.convert(command, m.ArmCommand)  # type: ignore[arg-type]
        started = time.monotonic()
        reply = self.client.command(arm, typed)
        return {"reply": reply, "elapsed_s": time.monotonic() - started}

    def device_command(
        self, unit: str, command: dict[str, Any], principal: str | None = None
    ) -> dict[str, Any]:
        """One command (its kind's JSON) to one device, as ``principal`` (default this
        client's); the reply and how long it took."""
        client = self._client_as(principal)
        kind = kind_of(self.client.inventory.device(unit))
        typed = kind.payloads[keys.CMD].decode(msgspec.json.encode(command))
        started = time.monotonic()
        reply = client.device_command(unit, typed)
        return {"reply": reply, "elapsed_s": time.monotonic() - started}

    def _client_as(self, principal: str | None) -> FleetClient:
        """This client's session acting as ``principal`` (the router checks no principal in
        the lab: security is off)."""
        if principal is None or principal == self.client.principal:
            return self.client
        if principal not in self._as:
            inventory = self.client.inventory.with_principal(principal)
            self._as[principal] = FleetClient(
                inventory, session=self.client.session, datagram=self.client.datagram
            )
        return self._as[principal]

    def device_state(self, unit: str) -> dict[str, Any]:
        """The newest state of device ``unit`` heard (None: none yet)."""
        with self._states_lock:
            return {"state": self._states.get(unit)}

    def coordinator(self, wait_s: float = 2.0) -> dict[str, Any]:
        """The id of the coordinator publishing the fleet state (None: none heard)."""
        state = self.client.fleet_state(wait_s=wait_s)
        return {"id": None if state is None else state.coordinator}

    def multi(self, target: str, command: dict[str, Any], sync: bool = True) -> dict[str, Any]:
        """One multi-arm request through the coordinator."""
        typed = msgspec.convert(command, m.ArmCommand)  # type: ignore[arg-type]
        started = time.monotonic()
        reply = self.client.multi(target, typed, sync=sync)
        return {"reply": reply, "elapsed_s": time.monotonic() - started}

    def snapshot(self, arms: list[str] | None = None, wait_s: float = 1.5) -> dict[str, Any]:
        """The latest status and joints per arm."""
        return {"arms": self.client.snapshot(arms, wait_s=wait_s)}

    def alive(self) -> dict[str, Any]:
        """Arms whose agent token is present."""
        return {"arms": sorted(self.client.agents_alive())}

    def watch_start(self) -> dict[str, Any]:
        """Start recording joints and status samples."""
        if self.watch is None:
            self.watch = Watch(self.client)
        return {}

    def watch_take(self) -> dict[str, Any]:
        """The samples recorded since the last take."""
        assert self.watch is not None, "watch_start first"
        return self.watch.take()

    def diag(self, unit: str, wait_s: float = 2.5, after_ns: int = 0) -> dict[str, Any]:
        """The newest Diag of arm or device ``unit`` (1 Hz) stamped after ``after_ns``, once
        one is heard, within ``wait_s`` (None: none)."""
        got: list[Any] = []
        sub = self.client.session.declare_subscriber(
            self.client.unit_key(unit, keys.DIAG),
            lambda s: got.append(msgspec.json.decode(s.payload.to_bytes())),
        )
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and not any(d["stamp_ns"] > after_ns for d in got):
            time.sleep(0.05)
        sub.undeclare()
        newer = [d for d in got if d["stamp_ns"] > after_ns]
        return {"diag": newer[-1] if newer else None}

    def load_start(self, rate_hz: float, size: int, for_s: float) -> dict[str, Any]:
        """Publish ``size``-byte samples on the status key of an arm that does not exist
        (``zz-load``) at ``rate_hz`` for ``for_s`` seconds, with the agents' status QoS (DROP,
        DATA_HIGH; it was BLOCK, which let a frozen subscriber stall the router): a large
        fleet's status traffic in one stream, for every status subscriber (they drop it: too
        large for a status)."""
        key = self.client.keys.arm("zz-load", keys.STATUS)
        publisher = self.client.session.declare_publisher(
            key,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.DATA_HIGH,
        )
        payload = b"x" * size

        def run() -> None:
            start = time.monotonic()
            n = 0
            while time.monotonic() - start < for_s:
                publisher.put(payload)
                n += 1
                time.sleep(max(0.0, start + n / rate_hz - time.monotonic()))
            publisher.undeclare()

        threading.Thread(target=run, name="load", daemon=True).start()
        return {}

    def stream_start(
        self, name: str, arm: str, joint: int, angles: list[float], period_s: float
    ) -> dict[str, Any]:
        """Send ``move_joint`` commands with these angles, one every ``period_s``, on a thread
        of their own; ``stream_take`` returns each command's reply."""
        done = threading.Event()
        results: list[Any] = []

        def run() -> None:
            for angle in angles:
                if done.is_set():
                    return
                sent = time.time_ns()
                reply = self.client.command(arm, m.MoveJoint(joint=joint, angle_deg=angle))
                results.append({"angle_deg": angle, "sent_ns": sent, "reply": reply})
                done.wait(period_s)

        thread = threading.Thread(target=run, name=f"stream-{name}", daemon=True)
        thread.start()
        self._streams[name] = (thread, done, results)
        return {}

    def stream_take(self, name: str, timeout_s: float = 30.0) -> dict[str, Any]:
        """End stream ``name`` (the command under way completes); its results."""
        thread, done, results = self._streams.pop(name)
        done.set()
        thread.join(timeout_s)
        return {"finished": not thread.is_alive(), "results": results}

    def close(self) -> None:
        """Undeclare the device-state subscribers; close the clients acting as another
        principal (they share this client's session, which its owner closes)."""
        for sub in self._state_subs:
            sub.undeclare()
        for client in self._as.values():
            client.close()


def _builtins(value: Any) -> Any:
    return msgspec.to_builtins(value)


def main() -> int:
    """Serve requests until stdin closes."""
    # Replies on a descriptor of their own; whatever a library prints goes to the log.
    replies = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    zenoh.init_log_from_env_or("error")  # RUST_LOG=zenoh=info shows session losses
    inventory = load_inventory(sys.argv[1])
    encoder = msgspec.json.Encoder()
    with FleetClient(inventory) as client:
        client.watch_stop_acks()  # as a long-lived client (the viewer) has it before a stop
        daemon = Daemon(client)
        for line in sys.stdin:
            request = msgspec.json.decode(line)
            rid, op = request.pop("id"), request.pop("op")
            try:
                result = getattr(daemon, op)(**request)
                reply = {"id": rid, "ok": True, "result": result}
            except Exception as exc:  # noqa: BLE001 - reported to the test, which fails on it
                reply = {"id": rid, "ok": False, "error": f"{type(exc).__name__}: {exc}"}
            replies.write(encoder.encode(reply).decode() + "\n")
            replies.flush()
        if daemon.watch is not None:
            daemon.watch.close()
        daemon.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
