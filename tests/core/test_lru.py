"""planner.core.lru.BoundedLRU: least recently used out first, by count and by weight, thread-safe."""

from __future__ import annotations

import threading

import pytest

from planner.core.lru import BoundedLRU


def test_the_least_recently_used_go_first_beyond_the_entry_count() -> None:
    c: BoundedLRU[str, int] = BoundedLRU(3)
    for k, v in zip("abc", range(3), strict=True):
        c.put(k, v)
    assert c.get("a") == 0  # a is now the most recent: b is the oldest
    c.put("d", 3)
    assert c.get("b") is None and [c.get(k) for k in "acd"] == [0, 2, 3] and len(c) == 3
    c.pop("c")
    c.pop("missing")
    assert len(c) == 2 and c.get("c") is None
    c.clear()
    assert len(c) == 0 and c.weight() == 0.0


def test_the_weight_bound_evicts_the_oldest_but_always_keeps_the_latest() -> None:
    c: BoundedLRU[str, str] = BoundedLRU(10, len, 10)
    c.put("a", "x" * 4)
    c.put("b", "x" * 4)
    assert c.weight() == 8
    c.put("c", "x" * 4)  # 12 > 10: a goes
    assert c.get("a") is None and c.weight() == 8
    c.put("b", "x")  # a new value for a kept key: its weight replaced, not added
    assert c.weight() == 5 and c.get("b") == "x"
    c.put("huge", "x" * 50)  # heavier than the bound alone: kept, everything older goes
    assert len(c) == 1 and c.get("huge") is not None and c.weight() == 50
    with pytest.raises(ValueError, match="max_entries"):
        BoundedLRU(0)


def test_concurrent_use_keeps_the_bounds_and_the_weight_consistent() -> None:
    c: BoundedLRU[int, bytes] = BoundedLRU(16, len, 400)

    def work(seed: int) -> None:
        for k in range(2000):
            key = (seed * 7919 + k) % 64
            if k % 5 == 0:
                c.pop(key)
            elif c.get(key) is None:
                c.put(key, bytes(key % 40 + 1))

    threads = [threading.Thread(target=work, args=(s,)) for s in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    kept = [c.get(k) for k in range(64)]
    assert len(c) <= 16 and c.weight() == sum(len(v) for v in kept if v is not None)
    assert c.weight() <= 400 or len(c) == 1
