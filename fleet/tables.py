"""Tables keyed by what the network names, bounded without hiding the fleet's own units.

A table with a plain cap fills with made-up names (issue 28: 1100 stops for invented arms filled
the Foxglove bridge's 1000-channel table, and the real ``arm/a3/estop`` was then never shown). So a
``PinnedTable`` keeps two parts:

- **pinned** entries, for keys of the inventory's own arms and devices (and fixed fleet-level
  keys): always admitted, never evicted. Their number is bounded by the inventory, not by the
  network.
- **others**, at most ``capacity``, least recently used evicted first (``on_evict`` is told, so
  the caller can release what the entry holds, e.g. unadvertise a channel).

Pure: no I/O, no lock (the owner's thread uses it).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class PinnedTable(Generic[K, V]):
    """Entries made on demand; pinned ones kept, the others bounded by LRU eviction."""

    def __init__(
        self,
        capacity: int,
        pinned: Callable[[K], bool],
        on_evict: Callable[[K, V], None] = lambda _key, _value: None,
    ) -> None:
        if capacity < 1:
            raise ValueError(f"a table's capacity is at least 1 (got {capacity})")
        self.capacity = capacity
        self.evicted = 0
        """Entries evicted so far (made-up keys pushed out by newer ones)."""
        self._pinned_of = pinned
        self._on_evict = on_evict
        self._pinned: dict[K, V] = {}
        self._others: OrderedDict[K, V] = OrderedDict()

    def __len__(self) -> int:
        return len(self._pinned) + len(self._others)

    def __contains__(self, key: object) -> bool:
        return key in self._pinned or key in self._others

    def get(self, key: K, make: Callable[[K], V]) -> V:
        """The entry of ``key``, made by ``make(key)`` if absent (evicting the least recently
        used other entry when the others are full)."""
        value = self._pinned.get(key)
        if value is not None or key in self._pinned:
            return value  # type: ignore[return-value]
        if key in self._others:
            self._others.move_to_end(key)
            return self._others[key]
        if self._pinned_of(key):
            value = self._pinned[key] = make(key)
            return value
        while len(self._others) >= self.capacity:
            old_key, old_value = self._others.popitem(last=False)
            self.evicted += 1
            self._on_evict(old_key, old_value)
        value = self._others[key] = make(key)
        return value

    def pinned_count(self) -> int:
        """How many entries are pinned."""
        return len(self._pinned)
