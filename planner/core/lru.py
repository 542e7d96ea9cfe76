"""A thread-safe least-recently-used cache bounded by entry count and, optionally, by total weight.

One implementation for the caches of immutable, content-keyed things a process keeps: parsed meshes (by
their bytes' hash: :mod:`planner.meshio.load`), single-configuration deflections of the stiffness model,
and in the service the result documents (:mod:`api.results`), scenes, glTF cabins and exports. The most
recent entry is always kept, even when it alone exceeds the weight bound (a cache that refused its
largest item would redo the largest work every time).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class BoundedLRU(Generic[K, V]):
    """Least recently used entries go first, once more than ``max_entries`` or ``max_weight`` are kept.

    Args:
        max_entries: Entries kept at most (>= 1).
        weight: An entry's weight (e.g. its faces or characters); every entry weighs 0 without it.
        max_weight: Total weight kept at most (the latest entry is kept whatever it weighs).
    """

    def __init__(
        self,
        max_entries: int,
        weight: Callable[[V], float] | None = None,
        max_weight: float = float("inf"),
    ) -> None:
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.max_entries = max_entries
        self.max_weight = max_weight
        self._weight = weight
        self._items: OrderedDict[K, tuple[V, float]] = OrderedDict()
        self._total = 0.0
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        """The entry of ``key`` (now the most recent), or ``None``."""
        with self._lock:
            found = self._items.get(key)
            if found is None:
                return None
            self._items.move_to_end(key)
            return found[0]

    def put(self, key: K, value: V) -> None:
        """Keep ``value`` under ``key`` as the most recent entry; evict the oldest beyond the bounds."""
        w = float(self._weight(value)) if self._weight is not None else 0.0
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._total -= old[1]
            self._items[key] = (value, w)
            self._total += w
            while len(self._items) > 1 and (
                len(self._items) > self.max_entries or self._total > self.max_weight
            ):
                _, (_, gone) = self._items.popitem(last=False)
                self._total -= gone

    def pop(self, key: K) -> None:
        """Forget ``key`` (nothing if it is not kept)."""
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._total -= old[1]

    def clear(self) -> None:
        """Forget every entry."""
        with self._lock:
            self._items.clear()
            self._total = 0.0

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def weight(self) -> float:
        """Total weight kept now."""
        with self._lock:
            return self._total


__all__ = ["BoundedLRU"]
