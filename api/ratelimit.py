"""Per-tenant request rate limit (the `limits` library, moving window).

Every authenticated request counts against its tenant's window (``Settings.rate_limit``, e.g. ``120 per
10 seconds``); beyond it the answer is 429 ``rate_limited`` with ``Retry-After`` (whole seconds until the
oldest request of the window leaves it). The windows live where ``Settings.rate_limit_storage_uri`` says:
``memory://`` (default) in this instance's memory, so N instances behind a balancer give a tenant up to N
times the rate; ``redis://...`` in a Redis every instance shares, so the limit holds for the deployment.
A storage that does not answer lets the request through (logged and counted): the service stays up when
only its limiter's store is down.
"""

from __future__ import annotations

import logging
import math
import time

from limits import RateLimitItem, parse
from limits.storage import storage_from_string
from limits.strategies import MovingWindowRateLimiter

_LOG = logging.getLogger(__name__)

#: Longest wait for the rate-limit store [s]; past it the request is let through (and logged).
STORE_TIMEOUT_S = 0.5


class TenantRateLimiter:
    """The moving-window limiter of one instance.

    Args:
        rate: A rate in the `limits` notation (``"120 per 10 seconds"``).
        storage_uri: Where the windows live: ``memory://`` or a Redis URI (``redis://host:6379/0``).
        namespace: Prefix of the window keys in a shared store (one per deployment sharing a Redis).
    """

    def __init__(self, rate: str, storage_uri: str = "memory://", namespace: str = "cabinplan") -> None:
        self.item: RateLimitItem = parse(rate)
        options: dict[str, float | str | bool] = {}
        if not storage_uri.startswith("memory"):
            # A store that stops answering must not hold every request: give up after STORE_TIMEOUT_S.
            options = {
                "key_prefix": f"{namespace}:ratelimit",
                "socket_timeout": STORE_TIMEOUT_S,
                "socket_connect_timeout": STORE_TIMEOUT_S,
            }
        self.storage = storage_from_string(storage_uri, **options)
        self.limiter = MovingWindowRateLimiter(self.storage)
        self.store_errors = 0

    def hit(self, tenant: str) -> float | None:
        """Count one request of ``tenant``: ``None`` when allowed, else the seconds until one is."""
        try:
            if self.limiter.hit(self.item, tenant):
                return None
            stats = self.limiter.get_window_stats(self.item, tenant)
        except Exception as exc:  # the store is down: let the request through rather than fail it
            self.store_errors += 1
            _LOG.warning("rate-limit store unavailable, request of %r let through: %s", tenant, exc)
            return None
        return max(0.0, float(stats.reset_time) - time.time())

    def describe(self) -> str:
        """The limit as text (``120 per 10 seconds``)."""
        return f"{self.item.amount} per {self.item.multiples} {self.item.GRANULARITY.name}(s)"


def retry_after_header(wait_s: float) -> str:
    """``Retry-After`` value: whole seconds, at least 1."""
    return str(max(1, math.ceil(wait_s)))


__all__ = ["TenantRateLimiter", "retry_after_header"]
