"""Reading a recording (``fleet replay``, tests): finished or not.

``fleet record`` finishes its file on a clean exit (summary, indexes, footer); a recorder killed
with SIGKILL, by the OOM killer or a power cut leaves an *unfinished* file: the chunks it
flushed (every ``FLUSH_PERIOD_S``, see ``fleet/record/writer.py``), no summary, no footer, and
possibly one record cut short at the end. The ``mcap`` library's ``make_reader`` starts from the
footer and fails on such a file; this reader scans the records from the start (the way
``mcap.reader.NonSeekingReader`` does), keeps every message of every whole chunk, and reports
where and why it stopped. It reads finished files, old and new, the same way.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from mcap.records import Channel, Footer, Header, McapRecord, Message, Metadata
from mcap.stream_reader import StreamReader

from fleet.record.errors import RecordingUnreadable

MAX_METADATA_RECORDS = 16
"""Metadata records kept from one file (ours writes one; a hostile file may hold millions)."""


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
        except Exception as exc:  # noqa: BLE001 - any parser failure: see the docstring
            kind = type(exc)
            name = kind.__name__
            if kind.__module__ != "builtins":  # struct.error, mcap.EndOfFile, zstandard.ZstdError
                name = f"{kind.__module__.split('.')[0]}.{name}"
            yield _Stopped(f"{name}: {str(exc)[:120]}" if str(exc) else name)
            return
        yield record


def read_recording(path: str | Path) -> Recording:
    """Every message of an MCAP recording, in log-time order, finished or not. Raises
    OSError if the file cannot be opened, RecordingUnreadable if it is not MCAP at all."""
    with open(path, "rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        return _scan(stream, str(path), size)


def _scan(stream: IO[bytes], path: str, size: int) -> Recording:
    # A record can never be longer than the file: a damaged length must not allocate 4 GiB.
    reader = StreamReader(stream, validate_crcs=True, record_size_limit=max(size, 64))
    parsed = _parsed(reader.records)
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
