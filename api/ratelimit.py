"""Per-tenant request rate limit (the `limits` library, moving window, in memory per instance).

Every authenticated request counts against its tenant's window (``Settings.rate_limit``, e.g. ``120 per
10 seconds``); beyond it the answer is 429 ``rate_limited`` with ``Retry-After`` (whole seconds until the
oldest request of the window leaves it). The window lives in this instance's memory: with N instances
behind a balancer a tenant gets up to N times the rate.
"""

from __future__ import annotations

import math
import time

from limits import RateLimitItem, parse
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter


class TenantRateLimiter:
    """The moving-window limiter of one instance.

    Args:
        rate: A rate in the `limits` notation (``"120 per 10 seconds"``).
    """

    def __init__(self, rate: str) -> None:
        self.item: RateLimitItem = parse(rate)
        self.limiter = MovingWindowRateLimiter(MemoryStorage())

    def hit(self, tenant: str) -> float | None:
        """Count one request of ``tenant``: ``None`` when allowed, else the seconds until one is."""
        if self.limiter.hit(self.item, tenant):
            return None
        stats = self.limiter.get_window_stats(self.item, tenant)
        return max(0.0, float(stats.reset_time) - time.time())

    def describe(self) -> str:
        """The limit as text (``120 per 10 seconds``)."""
        return f"{self.item.amount} per {self.item.multiples} {self.item.GRANULARITY.name}(s)"


def retry_after_header(wait_s: float) -> str:
    """``Retry-After`` value: whole seconds, at least 1."""
    return str(max(1, math.ceil(wait_s)))


__all__ = ["TenantRateLimiter", "retry_after_header"]
