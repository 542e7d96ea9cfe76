"""The context of one app: settings, database, job store, mesh store, job runner, metrics, limiter, keys."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from fastapi import Request

from api.db import Database
from api.jobstore import JobStore
from api.keycache import KeyCache
from api.metrics import ServiceMetrics
from api.ratelimit import TenantRateLimiter
from api.settings import Settings
from api.waiters import JobWaiters

if TYPE_CHECKING:
    from api.jobs import JobRunner
    from api.store import MeshStore


@dataclass
class AppContext:
    """Everything a route needs, created by :func:`api.app.create_app` and held in ``app.state.ctx``."""

    settings: Settings
    db: Database
    store: MeshStore
    runner: JobRunner
    metrics: ServiceMetrics
    limiter: TenantRateLimiter
    #: Every job state change and query (:mod:`api.jobstore`).
    jobs: JobStore
    #: Called when a sweep was submitted: its first plans are fed now, not at the feeder's next pass.
    sweep_submitted: Callable[[], None] = lambda: None
    #: Requests waiting for a job to end (``wait_s``), woken by the runner.
    waiters: JobWaiters = field(default_factory=JobWaiters)
    #: Keys found valid in the last second (:mod:`api.keycache`).
    keys: KeyCache = field(default_factory=KeyCache)


def get_context(request: Request) -> AppContext:
    """The context of the app serving ``request``."""
    ctx = request.app.state.ctx
    assert isinstance(ctx, AppContext)
    return ctx


__all__ = ["AppContext", "get_context"]
