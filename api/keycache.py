"""The API keys this process accepted in the last second, so that a request does not query the key table.

Every authenticated request used to look its key up in the database (a session, a query, a commit:
about 0.7 ms of the service's CPU, on every status poll). A key found valid is remembered for
:data:`KEY_CACHE_TTL_S`; a revocation through this process forgets every remembered key at once
(:func:`api.auth.revoke_key`), so here it takes effect at the next request; on another instance sharing
the database it takes effect within :data:`KEY_CACHE_TTL_S`. Unknown and revoked keys are never
remembered: a key created a moment ago works at once, and a refused key is looked up every time.
"""

from __future__ import annotations

import threading
import time

#: How long a key found valid is trusted without asking the database again [s].
KEY_CACHE_TTL_S = 1.0
#: Keys remembered at most (all are forgotten beyond: a bound, not an eviction policy).
KEY_CACHE_MAX = 4096


class KeyCache:
    """Digest of a valid key -> its (tenant, key id), each for :data:`KEY_CACHE_TTL_S` (thread-safe)."""

    def __init__(self, ttl_s: float = KEY_CACHE_TTL_S) -> None:
        self.ttl_s = ttl_s
        self._lock = threading.Lock()
        self._keys: dict[str, tuple[str, str, float]] = {}

    def get(self, digest: str) -> tuple[str, str] | None:
        """The (tenant, key id) of ``digest`` if it was found valid less than the TTL ago."""
        with self._lock:
            hit = self._keys.get(digest)
        if hit is None or time.monotonic() >= hit[2]:
            return None
        return hit[0], hit[1]

    def put(self, digest: str, tenant: str, key_id: str) -> None:
        """Remember that ``digest`` is a valid key of ``tenant`` (its id ``key_id``)."""
        with self._lock:
            if len(self._keys) >= KEY_CACHE_MAX:
                self._keys.clear()
            self._keys[digest] = (tenant, key_id, time.monotonic() + self.ttl_s)

    def clear(self) -> None:
        """Forget every key (one was revoked)."""
        with self._lock:
            self._keys.clear()


__all__ = ["KEY_CACHE_MAX", "KEY_CACHE_TTL_S", "KeyCache"]
