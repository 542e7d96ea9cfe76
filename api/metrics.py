"""Prometheus metrics of one service instance (prometheus-client), served at ``GET /metrics``.

Each app has its own :class:`~prometheus_client.CollectorRegistry` (several apps may live in one test
process). Counted as they happen: HTTP requests by route template, method and status, with their
latency; job outcomes by status and reason, and job durations. Read at scrape time from the database
and the runner (:class:`QueueCollector`): jobs queued and running in the whole database, jobs running
on this instance, and whether the job forkserver is still warming up.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

#: Buckets of the planning job duration [s]: sub-second free moves up to the 600 s time-limit ceiling.
JOB_DURATION_BUCKETS = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0, 120.0, 300.0, 600.0)
#: Buckets of the HTTP request latency [s].
HTTP_LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


class ServiceMetrics:
    """The instruments of one service instance, registered in ``registry`` (default: a new one)."""

    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry if registry is not None else CollectorRegistry()
        r = self.registry
        self.http_requests = Counter(
            "cabinplan_http_requests", "HTTP requests answered.", ["method", "route", "status"], registry=r
        )
        self.http_latency = Histogram(
            "cabinplan_http_request_duration_seconds",
            "Time from the request's start to its response's end.",
            ["method", "route"],
            buckets=HTTP_LATENCY_BUCKETS,
            registry=r,
        )
        self.job_outcomes = Counter(
            "cabinplan_jobs_finished",
            "Planning jobs finished on this instance.",
            ["status", "reason"],
            registry=r,
        )
        self.job_duration = Histogram(
            "cabinplan_job_duration_seconds",
            "Wall-clock time of a planning job on this instance (its start to its outcome).",
            ["status"],
            buckets=JOB_DURATION_BUCKETS,
            registry=r,
        )
        self.workers_replaced = Counter(
            "cabinplan_job_workers_replaced",
            "Job worker processes replaced by fresh ones, by cause: tasks (its job budget spent), rss (its "
            "memory bound), killed (its job past the hard limit, cancelled or no longer ours), died.",
            ["cause"],
            registry=r,
        )
        self.warmup_seconds = Gauge(
            "cabinplan_warmup_seconds", "Time the job forkserver took to warm up.", registry=r
        )
        self.rate_limited = Counter(
            "cabinplan_rate_limited_requests", "Requests refused by the per-tenant rate limit.", registry=r
        )


class QueueCollector(Collector):
    """Gauges read at scrape time: queue depth, running jobs, this instance's jobs, warming up.

    Args:
        counts: Returns ``(queued, running)`` of the whole database.
        local_busy: Jobs running on this instance.
        warming: True while the forkserver warms up.
    """

    def __init__(
        self,
        counts: Callable[[], tuple[int, int]],
        local_busy: Callable[[], int],
        warming: Callable[[], bool],
    ) -> None:
        self.counts = counts
        self.local_busy = local_busy
        self.warming = warming

    def collect(self) -> Iterator[GaugeMetricFamily]:
        """The gauges, read now."""
        queued, running = self.counts()
        yield GaugeMetricFamily(
            "cabinplan_jobs_queued", "Jobs waiting for a worker (whole database).", queued
        )
        yield GaugeMetricFamily("cabinplan_jobs_running", "Jobs running (whole database).", running)
        yield GaugeMetricFamily(
            "cabinplan_instance_jobs_running", "Jobs running on this instance.", self.local_busy()
        )
        yield GaugeMetricFamily(
            "cabinplan_warming_up", "1 while the job forkserver warms up.", 1.0 if self.warming() else 0.0
        )


__all__ = ["HTTP_LATENCY_BUCKETS", "JOB_DURATION_BUCKETS", "QueueCollector", "ServiceMetrics"]
