"""Plain CDR as ROS 2 writes it (XCDR1, little endian), pure: no I/O, no clock.

A serialized message starts with the 4-byte encapsulation header ``00 01 00 00`` (CDR_LE,
options 0); alignment is counted from the byte after it. Strings are a uint32 length that
counts the terminating NUL, the UTF-8 bytes, then the NUL; sequences a uint32 count, then the
elements. ``CdrReader`` is bounded: every length is checked against what is left, and any
short or malformed input raises ``CdrError`` (and only that).

``CdrTemplate``: a message whose strings and sequence lengths never change (a JointState's
names, a TFMessage's frames) is written once; each sample only packs its numbers into the copy
at offsets recorded then (``CdrWriter.slot``), a few C calls instead of one per field.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

HEADER_LE = b"\x00\x01\x00\x00"
"""CDR_LE, options 0: what rmw_zenoh (Fast-CDR) writes before every message."""
HEADER_BE = b"\x00\x00\x00\x00"


class CdrError(ValueError):
    """Bytes that are not the CDR of the expected type (short, bad header, bad string)."""


class CdrWriter:
    """Appends aligned little-endian primitives after the encapsulation header."""

    def __init__(self) -> None:
        self._buf = bytearray(HEADER_LE)
        self._slots: list[tuple[int, struct.Struct]] = []

    def _align(self, size: int) -> None:
        pad = -(len(self._buf) - 4) % size
        if pad:
            self._buf += b"\x00" * pad

    def u8(self, value: int) -> None:
        """An octet, uint8, byte or bool."""
        self._buf.append(value & 0xFF)

    def i32(self, value: int) -> None:
        """A signed 32-bit integer."""
        self._align(4)
        self._buf += struct.pack("<i", value)

    def u32(self, value: int) -> None:
        """An unsigned 32-bit integer."""
        self._align(4)
        self._buf += struct.pack("<I", value)

    def f64(self, value: float) -> None:
        """A double."""
        self._align(8)
        self._buf += struct.pack("<d", value)

    def f64s(self, values: list[float] | tuple[float, ...]) -> None:
        """A sequence of doubles (count, then the values)."""
        self.u32(len(values))
        if values:
            self._align(8)
            self._buf += struct.pack(f"<{len(values)}d", *values)

    def string(self, text: str) -> None:
        """A string: length with the NUL, UTF-8 bytes, NUL."""
        data = text.encode("utf-8")
        self.u32(len(data) + 1)
        self._buf += data + b"\x00"

    def strings(self, texts: list[str] | tuple[str, ...]) -> None:
        """A sequence of strings."""
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def slot(self, fmt: str, values: list[float] | tuple[float, ...]) -> None:
        """Numbers of one alignment written as ``<fmt`` (``iI``: a stamp, ``7d``: a pose) whose
        offset is recorded for ``template()``: they change from message to message."""
        packer = struct.Struct("<" + fmt)
        self._align(struct.calcsize("<" + fmt[-1]))
        self._slots.append((len(self._buf), packer))
        self._buf += packer.pack(*values)

    def template(self) -> CdrTemplate:
        """The message so far, with its slots to fill."""
        return CdrTemplate(bytes(self._buf), tuple(self._slots))

    def bytes(self) -> bytes:
        """The message so far, header included."""
        return bytes(self._buf)


class CdrTemplate:
    """A serialized message and the slots (offset, packer) of its changing numbers."""

    def __init__(self, data: bytes, slots: tuple[tuple[int, struct.Struct], ...]) -> None:
        self.data = data
        self.slots = slots

    def fill(self, *values: Sequence[float]) -> bytes:
        """The message with slot ``i`` holding ``values[i]`` (one sequence per slot, in the
        order they were written)."""
        if len(values) != len(self.slots):
            raise ValueError(f"{len(values)} slot values for {len(self.slots)} slots")
        buf = bytearray(self.data)
        for (offset, packer), group in zip(self.slots, values, strict=True):
            packer.pack_into(buf, offset, *group)
        return bytes(buf)


class CdrReader:
    """Reads what ``CdrWriter`` writes; raises CdrError on anything short or malformed."""

    def __init__(self, data: bytes, max_len: int = 1 << 16) -> None:
        if len(data) > max_len:
            raise CdrError(f"{len(data)} bytes is over the {max_len} byte limit")
        if len(data) < 4 or data[:2] not in (HEADER_LE[:2], HEADER_BE[:2]):
            raise CdrError("no CDR encapsulation header (00 01 or 00 00)")
        self._little = data[1] == 1
        self._data = data
        self._pos = 4

    def _take(self, size: int, align: int) -> bytes:
        self._pos += -(self._pos - 4) % align
        end = self._pos + size
        if end > len(self._data):
            raise CdrError(f"short CDR: {size} bytes wanted at {self._pos} of {len(self._data)}")
        out = self._data[self._pos : end]
        self._pos = end
        return out

    def u8(self) -> int:
        """An octet."""
        return self._take(1, 1)[0]

    def u32(self) -> int:
        """An unsigned 32-bit integer."""
        return int(struct.unpack("<I" if self._little else ">I", self._take(4, 4))[0])

    def string(self) -> str:
        """A string (NUL-terminated, UTF-8)."""
        size = self.u32()
        if size == 0:
            raise CdrError("a CDR string has at least its NUL")
        raw = self._take(size, 1)
        if raw[-1] != 0:
            raise CdrError("a CDR string must end with NUL")
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CdrError(f"a CDR string is not UTF-8: {exc}") from None

    @property
    def left(self) -> int:
        """Bytes not read yet."""
        return len(self._data) - self._pos
