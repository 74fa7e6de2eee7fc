"""Plumbing shared by the fuzz targets: instrumented imports and the atheris entry point.

Atheris is imported only when a target runs under the fuzzer (``FUZZ_INSTRUMENT=1``, set by
``fuzz/run.py``): the test suite imports the same targets without it.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

INSTRUMENTED = ("fleet", "edge_agent")
"""The packages whose Python code gives coverage feedback (msgspec's C parser gives none)."""


@contextlib.contextmanager
def instrumented() -> Iterator[None]:
    """Imports under this block are instrumented for coverage when running under the fuzzer."""
    if os.environ.get("FUZZ_INSTRUMENT") != "1":
        yield
        return
    import atheris

    with atheris.instrument_imports(include=list(INSTRUMENTED)):
        yield


def texts(data: bytes) -> list[str | bytes]:
    """The input as the decoders meet it: the raw bytes (a Zenoh payload) and, when it is
    UTF-8, the text (a DDS string)."""
    try:
        return [data, data.decode("utf-8")]
    except UnicodeDecodeError:
        return [data]


def toml_text(data: bytes) -> str:
    """TOML text from fuzzer bytes (a file that is not UTF-8 never reaches the parser:
    ``fleet.tomlfile.read_text`` refuses it first)."""
    return data.decode("utf-8", errors="replace")


def main(check: Callable[[bytes], None]) -> None:
    """Run ``check`` under atheris with the libFuzzer options of ``sys.argv``."""
    import atheris

    atheris.Setup(sys.argv, check)
    atheris.Fuzz()
