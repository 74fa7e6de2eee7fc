"""Watching the key space from a test: a subscriber that keeps every decoded sample, and a
device agent's liveliness token."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from fleet.client import FleetClient
from fleet.wire import keys

T = TypeVar("T")


class Collector(Generic[T]):
    """Subscribes to one key and keeps every decoded sample with its receive time (monotonic).

    The Zenoh callback only decodes and appends under a lock (it never blocks).
    """

    def __init__(self, session: zenoh.Session, key: str, decode: Callable[[bytes], T]) -> None:
        self._lock = threading.Lock()
        self._items: list[tuple[float, T]] = []
        self._decode = decode
        self._subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        item = self._decode(sample.payload.to_bytes())
        with self._lock:
            self._items.append((time.monotonic(), item))

    @property
    def items(self) -> list[T]:
        with self._lock:
            return [item for _t, item in self._items]

    @property
    def timed(self) -> list[tuple[float, T]]:
        with self._lock:
            return list(self._items)

    def latest(self) -> T | None:
        with self._lock:
            return self._items[-1][1] if self._items else None

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def close(self) -> None:
        self._subscriber.undeclare()


def agent_token(client: FleetClient, kind: str, device: str) -> bool:
    """True once ``device``'s agent announced it serves commands (its liveliness token)."""
    key = client.keys.device(kind, device, keys.AGENT)
    return any(r.ok is not None for r in client.session.liveliness().get(key, timeout=1.0))
