"""Seeing the wire, pure parts: which channel a concrete key is, how a sample prints, and the
rate statistics of ``fleet hz``. No transport: the CLI (fleet/cli/wire_tools.py) feeds them.
"""

from __future__ import annotations

import json
import math
import statistics
from collections import deque
from dataclasses import dataclass
from typing import Any

import msgspec

from fleet.wire import keys, payloads

RAW_TEXT_LIMIT = 4096
"""``fleet echo`` prints at most this much of an undecodable or raw payload."""


def kind_of(keyspace: keys.KeySpace, key: str) -> str | None:
    """The channel kind of a concrete key of this fleet (a ``payloads.CHANNELS`` kind such as
    ``joints`` or ``gripper/state``; a payload-less channel's word, ``agent``, ``raw/feedback``
    or ``g1/agent``), or None for a key outside the key space."""
    try:
        parsed = keyspace.parse_key(key)
    except keys.KeyError_:
        return None
    row = payloads.channel_of(parsed)
    if row is not None:
        return row.kind
    return (
        parsed.channel
        if parsed.kind in (keys.ARM, keys.FLEET_LEVEL)
        else (f"{parsed.kind}/{parsed.channel}")
    )


def key_expr(keyspace: keys.KeySpace, expr: str) -> str:
    """A user's key expression: as given if it starts with ``fleet/``, else under the fleet's
    prefix (``arm/*/joints`` -> ``fleet/lab/arm/*/joints``)."""
    expr = expr.strip()
    if expr.startswith("fleet/"):
        return expr
    return f"{keyspace.prefix}/{expr.lstrip('/')}" if expr else keyspace.everything


@dataclass(frozen=True)
class Decoded:
    """One sample as ``fleet echo`` shows it: its kind, the payload as builtins (or the raw text
    for a channel without a schema), and why it did not decode (counted by the caller)."""

    key: str
    kind: str | None
    payload: Any
    error: str | None = None


def decode_sample(keyspace: keys.KeySpace, key: str, data: bytes) -> Decoded:
    """Decode ``data`` through the channel table; never raises."""
    kind = kind_of(keyspace, key)
    if kind is not None and kind in payloads.CHANNELS:
        try:
            value = payloads.decode(kind, data)
        except payloads.PayloadError as exc:
            return Decoded(key, kind, _text(data), exc.why[:300])
        return Decoded(key, kind, msgspec.to_builtins(value))
    if kind is None:
        return Decoded(key, None, _text(data), "no channel of the key space")
    return Decoded(key, kind, _text(data))  # raw/feedback, agent tokens: no schema


def _text(data: bytes) -> str:
    text = data[:RAW_TEXT_LIMIT].decode("utf-8", errors="backslashreplace")
    return text + ("..." if len(data) > RAW_TEXT_LIMIT else "")


def format_line(sample: Decoded, stamp_ns: int, as_json: bool) -> str:
    """One line: ``--json`` gives an object per line (key, kind, received_ns, payload, error)."""
    if as_json:
        out = {"key": sample.key, "kind": sample.kind, "received_ns": stamp_ns}
        out["payload"] = sample.payload
        if sample.error is not None:
            out["error"] = sample.error
        return json.dumps(out, separators=(",", ":"), allow_nan=False, default=str)
    if sample.error is not None:
        return f"{sample.key}: UNDECODABLE ({sample.error}): {sample.payload!r}"
    if isinstance(sample.payload, str):
        return f"{sample.key}: {sample.payload}"
    return f"{sample.key}: {json.dumps(sample.payload, separators=(', ', ': '), default=str)}"


class RateWindow:
    """``fleet hz`` for one key: the last ``window`` arrival intervals (monotonic seconds).

    A gap is an interval over ``gap_factor`` times the window's median interval (a lost sample
    at a steady rate shows as one interval of twice the period)."""

    def __init__(self, window: int = 100, gap_factor: float = 1.8) -> None:
        self.intervals: deque[float] = deque(maxlen=max(2, window))
        self.gap_factor = gap_factor
        self.count = 0
        self.gaps = 0
        self.longest_s = 0.0
        self._last: float | None = None

    def add(self, now: float) -> None:
        """A sample arrived at ``now``."""
        self.count += 1
        if self._last is not None:
            interval = max(0.0, now - self._last)
            if len(self.intervals) >= 3 and interval > self.gap_factor * statistics.median(
                self.intervals
            ):
                self.gaps += 1
            self.longest_s = max(self.longest_s, interval)
            self.intervals.append(interval)
        self._last = now

    def stats(self) -> dict[str, float | int | None]:
        """rate_hz, min_s, max_s, std_s (the jitter), window, samples, gaps, longest_s."""
        n = len(self.intervals)
        mean = sum(self.intervals) / n if n else 0.0
        return {
            "rate_hz": None if mean <= 0 else 1.0 / mean,
            "min_s": min(self.intervals) if n else None,
            "max_s": max(self.intervals) if n else None,
            "std_s": statistics.pstdev(self.intervals) if n > 1 else None,
            "window": n,
            "samples": self.count,
            "gaps": self.gaps,
            "longest_s": self.longest_s,
        }


def format_rate(key: str, stats: dict[str, float | int | None]) -> str:
    """``ros2 topic hz``'s lines, on one line per key."""

    def sec(value: float | int | None) -> str:
        return "-" if value is None or not math.isfinite(value) else f"{value:.4f}s"

    rate = stats["rate_hz"]
    rate_text = "-" if rate is None else f"{rate:.3f}"
    return (
        f"{key}: average rate {rate_text} Hz  min {sec(stats['min_s'])} max {sec(stats['max_s'])} "
        f"std dev {sec(stats['std_s'])} window {stats['window']}  samples {stats['samples']} "
        f"gaps {stats['gaps']} (longest {sec(stats['longest_s'])})"
    )
