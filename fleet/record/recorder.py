"""``fleet record``: chosen arms' keys into an MCAP file (the file format: ``writer.py``).

Threads: Zenoh callbacks only stamp each sample and append it to a bounded inbox (overflow is
counted in ``dropped``, never blocks Zenoh); the ``recorder`` thread turns it into key and
bytes, checks it, counts the joints' gaps by ``seq``, writes the file and flushes it every
``FLUSH_PERIOD_S``.

Throughput (``python -m bench.record_burst``, 2-core host, 3 arms of joints): the thread writes
about 40,000 samples/s (mcap's ``add_message`` alone takes ~6 us); nothing was lost at 30,000
samples/s, a quarter was dropped at our full inbox at 60,000/s. A plain subscriber lost nothing
at those rates: that loss is ours, and counted. Moving the str/bytes copies and the
``queue.Queue`` lock out of the callback doubled what the recorder keeps under a burst (it
dropped 7 % at 30,000/s and 55 % at 60,000/s before): every microsecond a callback holds the GIL
delays Zenoh's own reading of the socket.

What the recorder keeps count of (``fleet record`` prints each at the end):
- ``dropped``: samples lost at our own full queue (the recorder thread fell behind);
- ``gaps``: per arm, joints samples missing by ``seq`` -- lost anywhere between the agent and
  us (Zenoh drops joints under congestion by design), including at our queue;
- ``bad``: samples skipped, per key: a payload that does not decode as its channel's payload
  (through ``fleet/wire/payloads.py``), or a key that is not one we record (a put on a
  wildcard such as ``fleet/lab/**`` reaches every subscriber with that wildcard as its key).
  One bad sample never stops the recording.
If the thread fails anyway (the disk is full), ``error`` holds the exception, ``failed`` is set,
and ``close()`` still finishes the file as far as it can.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Protocol

import zenoh

from fleet.control import CONTROL_DEPTH, direct
from fleet.devices import DeviceKind
from fleet.record.gaps import SeqGaps
from fleet.record.layout import LAYOUT_METADATA, FleetLayout, layout_metadata
from fleet.record.writer import FLUSH_PERIOD_S, DerivedMessage, RecordingWriter
from fleet.wire import keys, payloads
from fleet.wire.payloads import PayloadKind

log = logging.getLogger("fleet.record")

RECORDED_CHANNELS: tuple[str, ...] = (keys.JOINTS, keys.STATUS, keys.CONTACT, keys.RAW_COMMAND)
RECORDED_CHANNELS += (keys.ESTOP, keys.RESET, keys.ESTOP_ACK, keys.RESET_ACK, keys.DIAG)
DEVICE_CHANNELS: tuple[str, ...] = (keys.STATE, keys.CONTACT, keys.LOWSTATE, keys.ESTOP)
DEVICE_CHANNELS += (keys.RESET, keys.ESTOP_ACK, keys.RESET_ACK, keys.DIAG)
"""A device's keys recorded: its state (at its relay rate), grip events, a G1's lowstate (its
joints: what the replay viewer and Foxglove pose it with), stops, resets, their acks."""
CONTROL_CHANNELS = frozenset({keys.ESTOP, keys.RESET})
"""Stops and resets (the fleet's, each arm's, each device's) are recorded in arrival order
through the shared intake's ``direct`` callbacks (fleet/control.py: on the Zenoh thread that
received them, so a reset put right after a stop is never written before it), and a full
inbox still takes up to ``CONTROL_DEPTH`` more of them."""
QUEUE_DEPTH = 20000
"""Samples waiting for the recorder thread, at most: half a second of a 40,000/s burst."""
POLL_S = 0.005
"""The recorder thread looks at an empty inbox this often (no condition variable to signal:
that would cost every callback a lock)."""
BATCH = 1000
"""Samples written between two looks at the flush deadline."""
DRAIN_TIMEOUT_S = 5.0
"""``close()`` waits this long for the thread to write what is queued (20000 samples take
about 0.5 s), then abandons the rest (counted in ``unwritten``)."""
MAX_BAD_KEYS = 64
"""Distinct keys counted in ``bad``; more are counted under ``(other keys)`` (a flood of
distinct wildcard puts must not grow memory)."""
LOGGED_BAD = 10
"""The first bad samples are logged one by one; the rest are only counted."""


class Extras(Protocol):
    """Channels derived from the recorded ones, written next to them."""

    def attachments(self) -> list[tuple[str, bytes, str]]:
        """(name, data, media type) attached to the file at its start."""

    def initial(self) -> list[DerivedMessage]:
        """Messages written once at the start."""

    def derive(self, unit: str | None, channel: str, payload: Any) -> list[DerivedMessage]:
        """Messages derived from one recorded, decoded sample of an arm or device (``channel``
        its ``payloads.CHANNELS`` kind: ``joints``, ``g1/lowstate``), logged at its receive
        time."""


class Recorder:
    """Records ``arms`` of one fleet to ``path``. A context manager; ``close()`` finishes the
    file (an unfinished one, after a SIGKILL, is readable up to its last flush)."""

    def __init__(
        self,
        session: zenoh.Session,
        space: keys.KeySpace,
        arms: Iterable[str],
        path: str | Path,
        flush_period_s: float = FLUSH_PERIOD_S,
        layout: FleetLayout | None = None,
        extras: Extras | None = None,
        devices: dict[str, DeviceKind] | None = None,
    ) -> None:
        """``layout``: where the arms stand (kept in the file, for ``fleet viewer --replay``);
        ``extras``: channels derived from the recorded ones (the 3D channels: the CLI passes
        fleet/scene3d/frames3d.py's, which imports this package's layout and writer, so it
        cannot be imported here); ``devices``: device id -> its kind, whose ``DEVICE_CHANNELS``
        are recorded too (each payload checked by its kind's decoder, stored with its kind's
        schema)."""
        self.space = space
        self.arms = list(arms)
        self.path = Path(path)
        self.flush_period_s = flush_period_s
        self.counts: dict[str, int] = {}
        """Messages written, per key."""
        self.dropped = 0
        """Samples lost because our queue was full."""
        self.bad: dict[str, int] = {}
        """Samples skipped, per key: payload not decodable, or key not recorded."""
        self.seq = SeqGaps()
        self.unwritten = 0
        """Samples still queued when ``close()`` gave up waiting for the thread."""
        self.error: BaseException | None = None
        """What the recorder thread failed with (None while it works)."""
        self.failed = threading.Event()
        self.finished = False
        """The file got its summary and footer."""
        self.finish_error: str | None = None
        self._armset = set(self.arms)
        self._drop_lock = threading.Lock()  # guards ``dropped`` (Zenoh callbacks on many threads)
        self._stats_lock = threading.Lock()  # guards ``seq`` and ``bad`` (read while recording)
        # A deque, not a queue.Queue: append and popleft are atomic without a lock or a
        # condition, so a Zenoh callback holds the GIL for less time (see _on_sample).
        self._inbox: collections.deque[tuple[zenoh.Sample, int]] = collections.deque()
        self._routes: dict[str, tuple[str | None, str]] = {}  # key -> (arm, channel), cached
        metadata = None if layout is None else {LAYOUT_METADATA: layout_metadata(layout)}
        self._file = RecordingWriter(self.path, metadata)
        self._extras = extras
        if extras is not None:
            started_ns = time.time_ns()
            for name, data, media_type in extras.attachments():
                self._file.attach(name, data, media_type, started_ns)
            for message in extras.initial():
                self._file.add_foreign(message, started_ns)
        self._stop = threading.Event()
        self._abandon = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        control = direct(self._on_control)
        self._subs = [
            session.declare_subscriber(
                space.arm(arm, channel),
                control if channel in CONTROL_CHANNELS else self._on_sample,
            )
            for arm in self.arms
            for channel in RECORDED_CHANNELS
        ]
        self._subs += [session.declare_subscriber(k, control) for k in (space.estop, space.reset)]
        # Devices: their routes are known up front (a bounded set), so _where finds them.
        self._device_routes: dict[str, tuple[str, str, PayloadKind[Any]]] = {}
        for device, kind in (devices or {}).items():
            decoders = kind.payloads  # the kind's rows of the channel table
            for channel in DEVICE_CHANNELS:
                if channel not in decoders:  # a kind without it (a G1 reports no grips)
                    continue
                key = space.device(kind.key, device, channel)
                route = (device, f"{kind.key}/{channel}", decoders[channel])
                self._device_routes[key] = route
                on = control if channel in CONTROL_CHANNELS else self._on_sample
                self._subs.append(session.declare_subscriber(key, on))
        self._thread.start()

    @property
    def gaps(self) -> dict[str, int]:
        """``{arm: joints samples missing by seq}``, for the arms heard from so far."""
        with self._stats_lock:
            return self.seq.missing()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: stamp and hand off, never block. The sample is converted to text and
        bytes on the recorder thread: under a burst every microsecond a callback holds the GIL
        delays Zenoh's reading of the socket, and the router then drops joints (DROP)."""
        if len(self._inbox) < QUEUE_DEPTH:  # racy by a few samples across Zenoh threads: fine
            self._inbox.append((sample, time.time_ns()))
        else:
            with self._drop_lock:
                self.dropped += 1

    def _on_control(self, sample: zenoh.Sample) -> None:
        """The receiving Zenoh thread (``direct``): a stop or reset joins the one inbox in
        arrival order; a full inbox still takes CONTROL_DEPTH more of them."""
        if len(self._inbox) < QUEUE_DEPTH + CONTROL_DEPTH:
            self._inbox.append((sample, time.time_ns()))
        else:
            with self._drop_lock:
                self.dropped += 1

    # ------------------------------------------------------------------ the recorder thread

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:
            self.error = exc
            self.failed.set()
            log.exception("recorder thread failed; %s is readable up to its last flush", self.path)
            raise

    def _loop(self) -> None:
        next_flush = time.monotonic() + self.flush_period_s
        inbox = self._inbox
        while not self._abandon.is_set():
            now = time.monotonic()
            if now >= next_flush:  # checked per batch: a steady stream still gets flushed
                self._file.flush()
                next_flush = now + self.flush_period_s
            if not inbox:
                if self._stop.is_set():
                    break  # stopped and drained (the subscriptions are gone)
                self._stop.wait(POLL_S)
                continue
            for _ in range(min(len(inbox), BATCH)):
                sample, stamp_ns = inbox.popleft()
                self._record(str(sample.key_expr), sample.payload.to_bytes(), stamp_ns)
        self._file.flush()

    def _record(self, key: str, payload: bytes, stamp_ns: int) -> None:
        route = self._device_routes.get(key)
        if route is not None:
            device, channel, decoder = route
            try:
                decoded = decoder.decode(payload)
            except payloads.PayloadError as exc:
                self._skip(key, str(exc))
                return
            self._write(key, "device", payload, stamp_ns, decoder.struct)
            self._derive(device, channel, decoded, stamp_ns)
            return
        where = self._where(key)
        if where is None:
            self._skip(key, "not a key this recorder records")
            return
        arm, channel = where
        try:
            decoded = payloads.decode(channel, payload)
        except payloads.PayloadError as exc:
            self._skip(key, str(exc))
            return
        if arm is not None and channel == keys.JOINTS:
            with self._stats_lock:
                self.seq.add(arm, decoded.seq)
        self._write(key, channel, payload, stamp_ns)
        self._derive(arm, channel, decoded, stamp_ns)

    def _write(
        self, key: str, channel: str, payload: bytes, stamp_ns: int, struct: Any = None
    ) -> None:
        count = self.counts.get(key, 0)
        self._file.add(key, channel, payload, stamp_ns, count % 2**32, struct)  # MCAP: a uint32
        self.counts[key] = count + 1

    def _derive(self, unit: str | None, channel: str, decoded: Any, stamp_ns: int) -> None:
        if self._extras is not None:
            for message in self._extras.derive(unit, channel, decoded):
                self._file.add_foreign(message, stamp_ns)

    def _where(self, key: str) -> tuple[str | None, str] | None:
        """(arm, channel) of a recorded key, (None, estop|reset) for the fleet's stop and
        reset, else None."""
        route = self._routes.get(key)
        if route is not None:
            return route
        if key in (self.space.estop, self.space.reset):
            route = (None, keys.ESTOP if key == self.space.estop else keys.RESET)
        else:
            try:
                parsed = self.space.parse_arm_key(key)
            except keys.KeyError_:
                return None
            if parsed.arm not in self._armset or parsed.channel not in RECORDED_CHANNELS:
                return None
            route = (parsed.arm, parsed.channel)
        self._routes[key] = route  # only keys we subscribed to: a bounded set
        return route

    def _skip(self, key: str, why: str) -> None:
        total = sum(self.bad.values())
        if total < LOGGED_BAD:
            log.warning("skipped a sample on %.200s: %.300s", key, why)
        elif total == LOGGED_BAD:
            log.warning("more bad samples: counted, no longer logged")
        slot = key if key in self.bad or len(self.bad) < MAX_BAD_KEYS else "(other keys)"
        with self._stats_lock:
            self.bad[slot] = self.bad.get(slot, 0) + 1

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Stop and finish the file (idempotent). Order: undeclare (no new samples) -> the
        thread writes what is queued and stops (at most DRAIN_TIMEOUT_S; then the rest is
        abandoned) -> finish the file here. The writer is never used by two threads at once:
        if the thread does not stop, the file is left as last flushed."""
        if self._closed:
            return
        self._closed = True
        for sub in self._subs:
            sub.undeclare()
        self._stop.set()
        self._thread.join(timeout=DRAIN_TIMEOUT_S)
        if self._thread.is_alive():
            self._abandon.set()
            self._thread.join(timeout=2.0)
        self.unwritten = len(self._inbox)
        if self._thread.is_alive():
            self.finish_error = "the recorder thread did not stop: the file is left unfinished"
            log.error("%s: %s", self.path, self.finish_error)
            return
        try:
            self._file.finish()
            self.finished = True
        except (OSError, ValueError) as exc:  # disk full, I/O error; ValueError: closed file
            self.finish_error = f"cannot finish the file: {type(exc).__name__}: {exc}"
            log.error("%s: %s", self.path, self.finish_error)
            with contextlib.suppress(OSError):  # reported: the buffered tail cannot be written
                self._file.abandon()

    def summary(self) -> str:
        """What was written, dropped and skipped, and the joints' gaps by seq, for people."""
        total = sum(self.counts.values())
        if self.finished:
            head = f"wrote {total} messages on {len(self.counts)} keys to {self.path} (finished)"
        else:
            head = (
                f"recorded {total} messages on {len(self.counts)} keys; {self.path} is UNFINISHED: "
                f"it holds at least the {self._file.flushed} flushed before the end"
            )
        bad = sum(self.bad.values())
        detail = ", ".join(f"{k}: {n}" for k, n in sorted(self.bad.items())[:5])
        lines = [
            head,
            f"  {self.dropped} dropped (our queue was full), {self.unwritten} unwritten at close, "
            f"{bad} bad samples skipped" + (f" ({detail})" if bad else ""),
        ]
        if self.seq.arms:
            lines.append("joints by seq (samples lost anywhere on the way):")
            lines.append(self.seq.describe())
        return "\n".join(lines)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
