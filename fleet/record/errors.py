"""Errors of recording and replay.

``RecordError`` (a ValueError): a recording that cannot be used as asked; the message names the
file. Its kinds:

- ``RecordingUnreadable``: not an MCAP file at all (empty, another format, a header cut short).
  A file that is merely *unfinished* (the recorder was killed: no summary, no footer, maybe a
  record cut short at the end) is not an error: ``read_recording`` returns what it holds and
  says so (``Recording.complete``).
- ``RecordingTooLarge``: a recording that would expand past the reader's caps (decompressed
  bytes, message count, one message's size: ``fleet.record.reader.ReadLimits``): refused whole.
- ``TeachError``: the recorded joints cannot become a drag-teach choreography (fewer than two
  usable samples, a span longer than drag-teach replays).

A recorder that fails while recording is not an exception of this module: ``Recorder.error``
holds what its thread raised, and ``fleet record`` exits 1 naming it.
"""

from __future__ import annotations


class RecordError(ValueError):
    """A recording that cannot be used as asked; the message names the file."""


class RecordingUnreadable(RecordError):
    """Not an MCAP file (empty, another format, its header cut short)."""


class RecordingTooLarge(RecordError):
    """A recording that expands past the reader's caps (damaged or hostile)."""


class TeachError(RecordError):
    """Recorded joints that cannot become a drag-teach choreography."""
