"""``fleet record``: chosen arms' keys into an MCAP file (JSON messages with JSON Schemas).

MCAP is what Foxglove (and ``mcap`` tools in C++, Go, Rust, TypeScript) open directly; each
channel is named by its Zenoh key, with ``message_encoding = "json"`` and the payload's JSON
Schema (generated from the msgspec Struct of ``fleet/wire/messages.py``). The payload bytes are
stored exactly as they crossed the key space; ``log_time`` is when we received them.

Threads: Zenoh callbacks only copy (key, bytes, time) into a bounded queue (overflow is
counted, never blocks Zenoh); the ``recorder`` thread writes the file.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

import msgspec
import zenoh
from mcap.writer import Writer

from fleet.wire import keys
from fleet.wire import messages as m

log = logging.getLogger("fleet.record")

RECORDED_CHANNELS = (keys.JOINTS, keys.STATUS, keys.CONTACT, keys.RAW_COMMAND, keys.ESTOP)
RECORDED_CHANNELS += (keys.ESTOP_ACK,)
_RAW_COMMAND_SCHEMA = {
    "title": "D1 command (raw)",
    "description": "The JSON text the agent wrote to rt/arm_Command<suffix> (seq, address, "
    "funcode, data), exactly as written.",
    "type": "object",
}
_ANY_OBJECT = {"title": "JSON object", "type": "object"}


def _struct_schema(struct: Any) -> dict[str, Any]:
    """The Struct's own JSON Schema object (with any nested definitions), not a ``$ref``."""
    (_ref,), components = msgspec.json.schema_components([struct])
    schema = dict(components[struct.__name__])
    others = {k: v for k, v in components.items() if k != struct.__name__}
    if others:
        schema["$defs"] = others
    return schema


def channel_schema(channel: str) -> tuple[str, dict[str, Any]]:
    """(schema name, JSON Schema) of an arm channel's payload."""
    if channel == keys.JOINTS:
        return "Joints", _struct_schema(m.Joints)
    if channel == keys.STATUS:
        return "ArmStatus", _struct_schema(m.ArmStatus)
    if channel == keys.ESTOP:
        return "StopRequest", _struct_schema(m.StopRequest)
    if channel == keys.ESTOP_ACK:
        return "StopAck", _struct_schema(m.StopAck)
    if channel == keys.RAW_COMMAND:
        return "D1Command", _RAW_COMMAND_SCHEMA
    contact = getattr(m, "ContactEvent", None)  # owned by the contact detector, when present
    if channel == keys.CONTACT and contact is not None:
        return "ContactEvent", _struct_schema(contact)
    return "JSON", _ANY_OBJECT


class Recorder:
    """Records ``arms`` of one fleet to ``path``. A context manager; ``close()`` finishes the
    file (an unfinished MCAP file is still readable up to its last chunk, but has no index)."""

    def __init__(
        self, session: zenoh.Session, space: keys.KeySpace, arms: Iterable[str], path: str | Path
    ) -> None:
        self.space = space
        self.arms = list(arms)
        self.path = Path(path)
        self.counts: dict[str, int] = {}
        self.dropped = 0
        self._queue: queue.Queue[tuple[str, bytes, int]] = queue.Queue(maxsize=20000)
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._writer = Writer(self._file)
        self._writer.start(profile="", library="d1-fleet")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._subs = [
            session.declare_subscriber(space.arm(arm, channel), self._on_sample)
            for arm in self.arms
            for channel in RECORDED_CHANNELS
        ]
        self._subs.append(session.declare_subscriber(space.estop, self._on_sample))
        self._thread.start()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: copy and queue, never block."""
        try:
            self._queue.put_nowait(
                (str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())
            )
        except queue.Full:
            self.dropped += 1

    def _channel(self, key: str) -> int:
        if key in self._channels:
            return self._channels[key]
        channel = keys.ESTOP if key == self.space.estop else self.space.parse_arm_key(key).channel
        name, schema = channel_schema(channel)
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode()
            )
        self._channels[key] = self._writer.register_channel(
            topic=key, message_encoding="json", schema_id=self._schemas[name]
        )
        return self._channels[key]

    def _run(self) -> None:
        try:
            while not (self._stop.is_set() and self._queue.empty()):
                try:
                    key, payload, stamp = self._queue.get(timeout=0.1)
                except queue.Empty:
                    continue
                sequence = self.counts.get(key, 0)
                self._writer.add_message(
                    channel_id=self._channel(key),
                    log_time=stamp,
                    publish_time=stamp,
                    data=payload,
                    sequence=sequence,
                )
                self.counts[key] = sequence + 1
        except BaseException:
            log.exception("recorder thread failed: the file is incomplete")
            raise

    def close(self) -> None:
        """Undeclare, drain the queue, finish and close the file (idempotent)."""
        if self._stop.is_set():
            return
        for sub in self._subs:
            sub.undeclare()
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._writer.finish()
        self._file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
