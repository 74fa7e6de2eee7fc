"""Reading a recording (``fleet replay``, tests): finished or not.

``fleet record`` finishes its file on a clean exit (summary, indexes, footer); a recorder killed
with SIGKILL, by the OOM killer or a power cut leaves an *unfinished* file: the chunks it
flushed (every ``FLUSH_PERIOD_S``, see ``fleet/record/writer.py``), no summary, no footer, and
possibly one record cut short at the end. The ``mcap`` library's ``make_reader`` starts from the
footer and fails on such a file; this reader scans the records from the start (the way
``mcap.reader.NonSeekingReader`` does), keeps every message of every whole chunk, and reports
where and why it stopped. It reads finished files, old and new, the same way.

A recording is hostile input (issue 28: a 61 KB file took 1.97 GB and 241 s to read; an 8 KB
file expanded to 3 million messages). So the reader decompresses chunks itself, never past what
is left of its budget (``ReadLimits``: decompressed bytes, message count, one message's size,
scaled with the file's size and capped), and a file over any cap is refused with one line
naming the file and the cap (``RecordingTooLarge``). The file is opened through
``fleet.files.open_regular`` (no FIFO, no device).
"""

from __future__ import annotations

import io
import os
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, McapRecord, Message, Metadata
from mcap.stream_reader import StreamReader

from fleet.files import FileReadError, open_regular
from fleet.record.errors import RecordingTooLarge, RecordingUnreadable

MAX_METADATA_RECORDS = 16
"""Metadata records kept from one file (ours writes one; a hostile file may hold millions)."""
MAX_RECORDING_FILE_BYTES = 1 << 40
"""The file itself may be large (hours of a fleet): what is kept is bounded by ``ReadLimits``."""
BYTES_PER_FILE_BYTE = 64
"""Decompressed bytes allowed per byte of file. Ours compress about 3.5 : 1 (180,000 joints
messages of three arms: 15.3 MB of payloads in a 4.35 MB file)."""
MESSAGES_PER_FILE_BYTE = 0.5
"""Messages allowed per byte of file; ours hold about 0.04 (same measure)."""
MIN_DECOMPRESSED_BYTES = 64 << 20
MAX_DECOMPRESSED_BYTES = 4 << 30
MIN_MESSAGES = 200_000
MAX_MESSAGES = 20_000_000
MESSAGE_HEADER_BYTES = 22
"""A message record's fields before its data (channel id, sequence, log and publish times)."""
MAX_MESSAGE_BYTES = 4 << 20
"""One message's payload: key-space payloads are at most 1 MiB (``max_payload_bytes``); the
URDFs recorded for Foxglove are tens of KiB."""


@dataclass(frozen=True)
class ReadLimits:
    """What one recording may expand to in memory."""

    decompressed_bytes: int
    messages: int
    message_bytes: int = MAX_MESSAGE_BYTES

    @classmethod
    def for_size(cls, size_bytes: int) -> ReadLimits:
        """The limits for a file of ``size_bytes``: proportional to it, within fixed bounds (a
        file under 1 MB keeps at most 64 MiB of payloads and 500,000 messages)."""
        return cls(
            decompressed_bytes=min(
                MAX_DECOMPRESSED_BYTES,
                max(MIN_DECOMPRESSED_BYTES, size_bytes * BYTES_PER_FILE_BYTE),
            ),
            messages=min(MAX_MESSAGES, max(MIN_MESSAGES, int(size_bytes * MESSAGES_PER_FILE_BYTE))),
        )


@dataclass(frozen=True)
class Recorded:
    """One recorded message: its original key, payload and log time."""

    key: str
    data: bytes
    log_time_ns: int


@dataclass(frozen=True)
class Recording:
    """What a recording file holds. ``complete``: the file was finished (its footer read);
    otherwise ``problem`` says where and why reading stopped, and ``messages`` holds every
    message before that point."""

    path: str
    messages: list[Recorded]
    complete: bool
    size_bytes: int
    read_bytes: int
    problem: str | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    """The file's named metadata records (the first MAX_METADATA_RECORDS of them)."""

    def describe(self) -> str:
        """One line for people: finished, or unfinished with what was read."""
        count = f"{len(self.messages)} messages"
        if self.complete:
            return f"{self.path}: finished, {count}"
        return (
            f"{self.path}: unfinished (the recorder did not close it: killed, crashed or still "
            f"running): {count} read, up to byte {self.read_bytes} of {self.size_bytes} "
            f"({self.problem})"
        )


@dataclass(frozen=True)
class _Stopped:
    """The parser failed here: the rest of the file is cut short or damaged."""

    why: str


def _parsed(records: Iterator[McapRecord]) -> Iterator[McapRecord | _Stopped]:
    """``records``, ending with ``_Stopped`` if the parser fails. The one place the mcap
    parser's exceptions are caught: on a file cut short or damaged it raised, in our fuzzing of
    truncated and corrupted recordings, EndOfFile, RecordLengthLimitExceeded, InvalidMagic,
    CRCValidationError (McapError), struct.error, ZstdError, UnicodeDecodeError and
    OverflowError; lz4 raises its own. Any of them means "the readable part ends here"."""
    while True:  # bounded: each record consumes at least 9 bytes of a finite file
        try:
            record = next(records)
        except StopIteration:
            return
        except RecordingTooLarge:
            raise
        except _Damaged as exc:
            yield _Stopped(str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - any parser failure: see the docstring
            kind = type(exc)
            name = kind.__name__
            if kind.__module__ != "builtins":  # struct.error, mcap.EndOfFile, zstandard.ZstdError
                name = f"{kind.__module__.split('.')[0]}.{name}"
            yield _Stopped(f"{name}: {str(exc)[:120]}" if str(exc) else name)
            return
        yield record


def read_recording(path: str | Path, limits: ReadLimits | None = None) -> Recording:
    """Every message of an MCAP recording, in log-time order, finished or not. Raises
    OSError if the file cannot be opened, RecordingUnreadable if it is not MCAP at all (or not
    a regular file), RecordingTooLarge if it expands past ``limits`` (by default
    ``ReadLimits.for_size`` of the file)."""
    try:
        stream = open_regular(path, MAX_RECORDING_FILE_BYTES, "recording")
    except FileReadError as exc:
        raise RecordingUnreadable(str(exc)) from None
    with stream:
        size = os.fstat(stream.fileno()).st_size
        return _scan(stream, str(path), size, limits)


class _Budget:
    """What is left of one file's ``ReadLimits``; refuses the file when spent."""

    def __init__(self, path: str, limits: ReadLimits) -> None:
        self.path = path
        self.limits = limits
        self.bytes_left = limits.decompressed_bytes
        self.messages = 0

    def refuse(self, what: str) -> RecordingTooLarge:
        return RecordingTooLarge(
            f"{self.path}: refused: {what} (a recording expanding this much is damaged or "
            "hostile; fleet record never writes one)"
        )

    def spend(self, decompressed: int) -> None:
        if decompressed > self.bytes_left:
            raise self.refuse(
                f"it decompresses to more than {self.limits.decompressed_bytes} bytes"
            )
        self.bytes_left -= decompressed

    def message(self, length: int) -> None:
        if length > self.limits.message_bytes:
            raise self.refuse(f"a message of {length} bytes, more than {self.limits.message_bytes}")
        self.messages += 1
        if self.messages > self.limits.messages:
            raise self.refuse(f"more than {self.limits.messages} messages")


class _Damaged(Exception):
    """A chunk that cannot be read (the readable part of the file ends before it)."""


def _decompress(chunk: Chunk, budget: _Budget) -> bytes:
    """The chunk's records, never decompressing more than the budget has left (+1 byte, to
    know it was exceeded): a declared ``uncompressed_size`` is not trusted."""
    cap = budget.bytes_left + 1
    if chunk.compression == "":
        data = chunk.data
    elif chunk.compression == "zstd":
        # The window (the decompressor's own memory) is capped too: ours are at most 1 MiB.
        decompressor = zstandard.ZstdDecompressor(max_window_size=MIN_DECOMPRESSED_BYTES)
        reader = decompressor.stream_reader(io.BytesIO(chunk.data))
        parts, total = [], 0
        while total < cap:
            part = reader.read(min(1 << 20, cap - total))
            if not part:
                break
            parts.append(part)
            total += len(part)
        data = b"".join(parts)
    elif chunk.compression == "lz4":
        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=cap)
    else:
        raise _Damaged(f"a chunk compressed with {chunk.compression[:40]!r}, unknown here")
    budget.spend(len(data))
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _Damaged("a chunk whose CRC does not match its records")
    return data


def _chunk_records(chunk: Chunk, budget: _Budget) -> Iterator[McapRecord]:
    """The channels and messages in ``chunk`` (what ``mcap``'s ``breakup_chunk`` does, with
    the budget checked before each message is kept)."""
    data = _decompress(chunk, budget)
    stream = ReadDataStream(io.BytesIO(data))
    while stream.count < len(data):
        opcode = stream.read1()
        length = stream.read8()
        if length > len(data) - stream.count:
            raise _Damaged("a record longer than the rest of its chunk")
        if opcode == Opcode.CHANNEL:
            yield Channel.read(stream)
        elif opcode == Opcode.MESSAGE:
            budget.message(length - MESSAGE_HEADER_BYTES)
            yield Message.read(stream, length)
        else:
            stream.read(length)


def _records(reader: StreamReader, budget: _Budget) -> Iterator[McapRecord]:
    """The file's records with every chunk broken up under the budget."""
    for record in reader.records:
        if isinstance(record, Chunk):
            yield from _chunk_records(record, budget)
        else:
            if isinstance(record, Message):
                budget.message(len(record.data))
            yield record


def _scan(stream: IO[bytes], path: str, size: int, limits: ReadLimits | None = None) -> Recording:
    # A record can never be longer than the file: a damaged length must not allocate 4 GiB.
    reader = StreamReader(
        stream, validate_crcs=True, record_size_limit=max(size, 64), emit_chunks=True
    )
    budget = _Budget(path, limits or ReadLimits.for_size(size))
    parsed = _parsed(_records(reader, budget))
    first = next(parsed, None)
    if not isinstance(first, Header):
        why = first.why if isinstance(first, _Stopped) else "no MCAP header"
        raise RecordingUnreadable(f"{path}: not an MCAP recording ({size} bytes; {why})")
    topics: dict[int, str] = {}
    messages: list[Recorded] = []
    metadata: dict[str, dict[str, str]] = {}
    footer, problem = False, None
    for record in parsed:
        if isinstance(record, _Stopped):
            problem = record.why
        elif isinstance(record, Channel):
            topics[record.id] = record.topic
        elif isinstance(record, Message):
            topic = topics.get(record.channel_id)
            if topic is None:
                problem = f"a message on channel {record.channel_id}, which no record declares"
                break
            messages.append(Recorded(topic, record.data, record.log_time))
        elif isinstance(record, Metadata):
            if len(metadata) < MAX_METADATA_RECORDS:
                metadata.setdefault(record.name, dict(record.metadata))
        elif isinstance(record, Footer):
            footer = True
    complete = footer and problem is None
    if not complete and problem is None:
        problem = "no footer: the file ends after its last whole record"
    messages.sort(key=lambda r: r.log_time_ns)  # stable: file order among equal times
    return Recording(path, messages, complete, size, stream.tell(), problem, metadata)
