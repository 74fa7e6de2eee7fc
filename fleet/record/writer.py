"""The MCAP file ``fleet record`` writes: JSON messages with JSON Schemas, small chunks, and
flushed every ``FLUSH_PERIOD_S`` so that a killed recorder loses at most that much.

MCAP is what Foxglove (and ``mcap`` tools in C++, Go, Rust, TypeScript) open directly; each
channel is named by its Zenoh key, with ``message_encoding = "json"`` and the payload's JSON
Schema (generated from the msgspec Struct of ``fleet/wire/messages.py``). The payload bytes are
stored exactly as they crossed the key space; ``log_time`` is when the recorder received them.

Why the flush: the ``mcap`` Writer keeps the open chunk in memory until it reaches
``chunk_size`` (1 MiB by default, about 40 s of three arms) and the file object buffers again;
a SIGKILL then left a 0-byte file after 10 s and after 40 s. ``Writer.flush()`` (public since
mcap 1.5) closes the open chunk, writes it with its message indexes and flushes the stream, so
the operating system holds every message up to the last flush. That survives the process being
killed; it does not survive a power cut (no fsync but at the end: the OS writes back within
about 30 s).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import msgspec
from mcap.writer import CompressionType, Writer

from fleet.wire import keys, payloads

FLUSH_PERIOD_S = 0.5
"""A chunk is closed and the file flushed this often (if anything was added): a killed recorder
loses at most this much (plus what waits in its queue, normally nothing)."""
CHUNK_SIZE = 64 * 1024
"""A chunk is also closed at this size (a burst): the chunk in memory stays small."""
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
    """(schema name, JSON Schema) of an arm channel's payload, from the channel table."""
    if channel == keys.RAW_COMMAND:
        return "D1Command", _RAW_COMMAND_SCHEMA  # a plain object: its own words say more
    known = payloads.CHANNELS.get(channel)
    if known is None:
        return "JSON", _ANY_OBJECT
    struct = known.payload.struct
    return struct.__name__, _struct_schema(struct)


@dataclass(frozen=True)
class DerivedMessage:
    """A message on a channel that is not a Zenoh key (e.g. ``foxglove.FrameTransforms``)."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    data: bytes


class RecordingWriter:
    """One recording file. Not thread-safe: one thread writes (the recorder's), and
    ``finish``/``abandon`` run once that thread has stopped."""

    def __init__(self, path: str | Path, metadata: dict[str, dict[str, str]] | None = None) -> None:
        """``metadata``: named records written right after the header (the fleet's layout)."""
        self.path = Path(path)
        self.added = 0
        """Messages added."""
        self.flushed = 0
        """Messages in the file as of the last flush (what a SIGKILL now would leave)."""
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed by finish/abandon
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="d1-fleet")
        for name, entries in (metadata or {}).items():
            self._writer.add_metadata(name, entries)
        self._file.flush()  # the header: a recorder killed at once leaves an empty recording
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._foreign_counts: dict[str, int] = {}

    def add(
        self,
        key: str,
        channel: str,
        data: bytes,
        log_time_ns: int,
        sequence: int,
        struct: Any = None,
    ) -> None:
        """One message on ``key`` (an arm ``channel``, or ``estop`` for the fleet's stop; a
        device's channel with its payload's ``struct``)."""
        self._writer.add_message(
            channel_id=self._channel(key, channel, struct),
            log_time=log_time_ns,
            publish_time=log_time_ns,
            data=data,
            sequence=sequence,
        )
        self.added += 1

    def add_foreign(self, message: DerivedMessage, log_time_ns: int) -> None:
        """A message of a channel that is no key (Foxglove's 3D channels: frames3d.py), with
        its own schema and encoding; readers of keys ignore it (its topic is no key)."""
        if message.topic not in self._channels:
            schema_key = f"{message.schema_encoding}:{message.schema_name}"
            if schema_key not in self._schemas:
                self._schemas[schema_key] = self._writer.register_schema(
                    name=message.schema_name,
                    encoding=message.schema_encoding,
                    data=message.schema_data,
                )
            self._channels[message.topic] = self._writer.register_channel(
                topic=message.topic,
                message_encoding=message.message_encoding,
                schema_id=self._schemas[schema_key],
            )
        sequence = self._foreign_counts.get(message.topic, 0)
        self._foreign_counts[message.topic] = sequence + 1
        self._writer.add_message(
            channel_id=self._channels[message.topic],
            log_time=log_time_ns,
            publish_time=log_time_ns,
            data=message.data,
            sequence=sequence % 2**32,
        )
        self.added += 1

    def attach(self, name: str, data: bytes, media_type: str, log_time_ns: int) -> None:
        """An MCAP attachment (the URDF)."""
        self._writer.add_attachment(log_time_ns, log_time_ns, name, media_type, data)

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS (nothing to do if nothing new)."""
        if self.added != self.flushed:
            self._writer.flush()
            self.flushed = self.added

    def finish(self) -> None:
        """Write the summary, indexes and footer; sync and close the file."""
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()

    def abandon(self) -> None:
        """Close the file without finishing it (after a failure): it stays readable up to its
        last whole chunk. Raises OSError if even the buffered bytes cannot be written."""
        self._file.close()

    def _channel(self, key: str, channel: str, struct: Any = None) -> int:
        if key in self._channels:
            return self._channels[key]
        if struct is None:
            name, schema = channel_schema(channel)
        else:
            name, schema = struct.__name__, _struct_schema(struct)
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode()
            )
        self._channels[key] = self._writer.register_channel(
            topic=key, message_encoding="json", schema_id=self._schemas[name]
        )
        return self._channels[key]
