"""Reading the fleet's TOML files (inventory, choreographies): the one place that turns every way
the TOML parser fails into one error.

The parser raises more than ``msgspec.DecodeError`` on hostile text: ``ValueError`` for an
integer of more than 4300 digits (Python's int-from-text limit), ``RecursionError`` for arrays or
inline tables nested about a thousand deep; reading raises ``UnicodeDecodeError`` for bytes that
are not UTF-8. Each caller adds the file name and turns ``TomlError`` into its own error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec

from fleet.files import MAX_FILE_BYTES, FileReadError, read_regular


class TomlError(ValueError):
    """A file that cannot be read as TOML text; the message says why (not the file name)."""


def decode_toml(text: str) -> dict[str, Any]:
    """The TOML document as a dict; TomlError (and only that) for anything else."""
    try:
        document = msgspec.toml.decode(text)
    except msgspec.DecodeError as exc:
        raise TomlError(f"not valid TOML: {exc}") from None
    except RecursionError:
        raise TomlError("not valid TOML: arrays or tables nested too deep") from None
    except ValueError as exc:  # int() of more than 4300 digits, in the parser
        raise TomlError(f"not valid TOML: {brief_text(str(exc), 90)}") from None
    if not isinstance(document, dict):  # pragma: no cover - TOML documents are tables
        raise TomlError("not valid TOML: expected a table")
    return document


def read_text(path: str | Path, what: str = "it") -> str:
    """The file's text; TomlError for a missing or unreadable file or bytes that are not UTF-8
    (``what`` names the file in the message: "cannot read the inventory")."""
    try:  # a regular file, size-capped: a named pipe or /dev/zero must not hang or flood us
        return read_regular(path, MAX_FILE_BYTES, what.removeprefix("the ")).decode("utf-8")
    except FileReadError as exc:
        raise TomlError(f"cannot read {what}: {str(exc).partition(': ')[2]}") from None
    except OSError as exc:
        raise TomlError(f"cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TomlError(f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None


def brief(value: Any, limit: int = 60) -> str:
    """``repr(value)`` for an error message, shortened: a file's 400-digit number or 10 kB string
    must not fill the terminal (and ``repr`` of a huge int can itself raise)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits"
    return brief_text(repr(value), limit)


def brief_text(text: str, limit: int = 60) -> str:
    """``text`` cut to ``limit`` characters."""
    return text if len(text) <= limit else text[: limit - 3] + "..."
