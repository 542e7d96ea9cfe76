"""Sweeps in the service: their tables and the feeder that turns a sweep's plans into ordinary jobs.

A sweep (:class:`Sweep`) stores its expanded plans; each plan becomes a planning job (:class:`api.db.Job`)
only when the tenant has room under its quota (``tenant_max_active_jobs`` counts the tenant's queued and
running jobs, the sweep's and its single plans alike), so the jobs of a sweep go through the same queue,
quota and tenant rules as ``POST /plans``. :class:`SweepFeeder` (a thread started with the app) does
that, and marks a sweep ``finished`` when every job of it has ended. :class:`SweepJob` links a plan of a
sweep to its job once the job exists.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from typing import Any

from sqlalchemy import JSON, Float, ForeignKey, Integer, String, delete, func, select, update
from sqlalchemy.orm import Mapped, mapped_column

from api.db import TERMINAL_STATES, Base, Database, now_s
from api.jobkinds import PLAN
from api.jobs import JobRunner
from api.jobstore import JobStore, new_job
from api.settings import Settings

_LOG = logging.getLogger(__name__)

#: Sweep states: ``running`` while plans wait for a job or a job has not ended, then ``finished``;
#: ``cancelled`` by ``DELETE /sweeps/{id}`` (its plans without a job are never fed).
SWEEP_STATES: tuple[str, ...] = ("running", "finished", "cancelled")


class Sweep(Base):
    """A feasibility sweep: its description, expanded plans and state."""

    __tablename__ = "sweeps"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    tenant: Mapped[str] = mapped_column(String(64), index=True)
    name: Mapped[str] = mapped_column(String(100))
    status: Mapped[str] = mapped_column(String(16), index=True)
    spec: Mapped[dict[str, Any]] = mapped_column(JSON)
    #: ``{"plans": [{"index", "sha256", "scenario", "labels"}], "meshes": {...}, "provenance": {...}}``.
    plans: Mapped[dict[str, Any]] = mapped_column(JSON)
    total: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[float] = mapped_column(Float)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)


class SweepJob(Base):
    """Plan ``index`` of a sweep and the job that plans it."""

    __tablename__ = "sweep_jobs"

    sweep_id: Mapped[str] = mapped_column(String(32), ForeignKey("sweeps.id"), primary_key=True)
    index: Mapped[int] = mapped_column(Integer, primary_key=True)
    job_id: Mapped[str] = mapped_column(String(32), index=True)


def new_sweep(
    tenant: str, name: str, spec: dict[str, Any], plans: list[dict[str, Any]], extra: dict[str, Any]
) -> Sweep:
    """A new ``running`` sweep row (not yet added to a session)."""
    return Sweep(
        id=uuid.uuid4().hex,
        tenant=tenant,
        name=name,
        status="running",
        spec=spec,
        plans={"plans": plans, **extra},
        total=len(plans),
        created_at=now_s(),
    )


class SweepStore:
    """The sweep tables' queries and state changes; the jobs' own go through :class:`JobStore`.

    A sweep is ``running`` until every plan has a job and every job ended (``finished``), or until it is
    cancelled (``cancelled``: plans without a job are never fed; under the tenant's quota lock, which the
    feeder holds while it queues, so no job is queued after it).

    Args:
        db: The service database.
    """

    def __init__(self, db: Database) -> None:
        self.db = db
        self.jobs = JobStore(db)

    def add(self, row: Sweep) -> None:
        """Store a new sweep."""
        with self.db.session() as s:
            s.add(row)

    def get(self, tenant: str, sweep_id: str) -> Sweep | None:
        """The tenant's sweep, or ``None``."""
        with self.db.session() as s:
            return s.scalar(select(Sweep).where(Sweep.id == sweep_id, Sweep.tenant == tenant))

    def links(self, sweep_id: str) -> dict[int, str]:
        """``{plan index: job id}`` of the sweep's plans that have a job."""
        with self.db.session() as s:
            rows = s.execute(
                select(SweepJob.index, SweepJob.job_id).where(SweepJob.sweep_id == sweep_id)
            ).all()
        return {int(i): str(j) for i, j in rows}

    def job_ids(self, sweep_id: str) -> list[str]:
        """The ids of the sweep's jobs."""
        return list(self.links(sweep_id).values())

    def job_states(self, sweep_id: str) -> list[tuple[str, str | None]]:
        """``(status, reason)`` of each of the sweep's jobs."""
        return [(status, reason) for _, status, reason in self.jobs.statuses(self.job_ids(sweep_id))]

    def cancel(self, row: Sweep, message: str) -> list[str]:
        """Cancel a running sweep and its jobs (see :meth:`JobStore.cancel`); the running jobs' ids."""
        with self.db.tenant_quota_session(row.tenant) as s:  # the lock the feeder queues under
            s.execute(
                update(Sweep)
                .where(Sweep.id == row.id, Sweep.status == "running")
                .values(status="cancelled", finished_at=now_s())
            )
        return self.jobs.cancel(self.job_ids(row.id), message).running

    def delete(self, row: Sweep, job_ids: list[str]) -> None:
        """Delete an ended sweep with its links and its (finished) jobs."""
        with self.db.session() as s:
            s.execute(delete(SweepJob).where(SweepJob.sweep_id == row.id))
            self.jobs.delete_finished(job_ids, s)
            s.execute(delete(Sweep).where(Sweep.id == row.id))


class SweepFeeder:
    """Submits the plans of running sweeps as jobs while their tenant has room under its quota.

    A pass runs when it is woken -- a sweep was submitted here (:meth:`wake`, from the route), a job of this
    instance ended (the runner's :meth:`~api.jobs.JobRunner.on_job_end`) -- and every ``poll_s`` besides,
    for what other instances sharing the database do. A sweep waiting on its tenant's quota costs a pass
    a few counts under the quota lock; its plans are read only when there is room for some.

    Args:
        db: The service database.
        settings: Quota (``tenant_max_active_jobs``).
        runner: Woken when jobs were queued; it wakes the feeder when one of its jobs ends.
        poll_s: Period of the feeder's pass over running sweeps when nothing wakes it [s].
    """

    def __init__(self, db: Database, settings: Settings, runner: JobRunner, poll_s: float = 1.0) -> None:
        self.db = db
        self.settings = settings
        self.runner = runner
        self.poll_s = poll_s
        self.jobs = JobStore(db)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        runner.on_job_end(self.job_ended)

    def job_ended(self, job_id: str) -> None:
        """A job of this instance ended (the runner's end listener): its tenant may have room now."""
        self.wake()

    def start(self) -> None:
        """Start the feeder thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="cabinplan-sweeps", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the feeder thread (queued jobs stay queued; the rest is fed after a restart)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)

    def wake(self) -> None:
        """A sweep was created or a job ended: feed now."""
        self._wake.set()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.feed()
            except Exception:  # keep feeding: a database hiccup must not stop every sweep
                _LOG.exception("sweep feeder pass failed")
                time.sleep(0.5)
            self._wake.wait(self.poll_s)
            self._wake.clear()

    def feed(self) -> int:
        """One pass: queue what the quotas allow, finish the sweeps whose jobs all ended; jobs queued."""
        queued = 0
        with self.db.session() as s:  # not the plans: a sweep's plans are read when there is room for some
            sweeps = s.execute(
                select(Sweep.id, Sweep.tenant, Sweep.total)
                .where(Sweep.status == "running")
                .order_by(Sweep.created_at)
            ).all()
        for sweep_id, tenant, total in sweeps:
            queued += self._feed_one(sweep_id, tenant, total)
            self._finish_if_done(sweep_id, total)
        if queued:
            self.runner.wake()
        return queued

    def _feed_one(self, sweep_id: str, tenant: str, total: int) -> int:
        with self.db.tenant_quota_session(tenant) as s:  # the lock POST /plans counts the quota under
            if s.scalar(select(Sweep.status).where(Sweep.id == sweep_id)) != "running":
                return 0  # cancelled (under this tenant's lock) since the pass listed it
            linked = int(
                s.scalar(select(func.count()).select_from(SweepJob).where(SweepJob.sweep_id == sweep_id)) or 0
            )
            if linked >= total:
                return 0  # every plan has its job
            room = self.settings.tenant_max_active_jobs - self.jobs.active_count(s, tenant)
            if room <= 0:
                return 0  # waiting on the quota
            stored: dict[str, Any] = s.execute(select(Sweep.plans).where(Sweep.id == sweep_id)).scalar_one()
            todo = stored["plans"][linked : linked + room]
            for plan in todo:
                scenario = plan["scenario"]
                job = new_job(
                    PLAN,
                    tenant,
                    scenario,
                    scenario["name"],
                    plan["sha256"],
                    dict(stored.get("meshes", {})),
                    {**stored.get("provenance", {}), "scenario_sha256": plan["sha256"]},
                    float(scenario["options"]["time_limit_s"]),
                )
                self.jobs.add_queued(s, job)  # the job row before its link (foreign keys in order)
                s.add(SweepJob(sweep_id=sweep_id, index=int(plan["index"]), job_id=job.id))
        return len(todo)

    def _finish_if_done(self, sweep_id: str, total: int) -> None:
        states = self.jobs.statuses(SweepStore(self.db).job_ids(sweep_id))
        ended = sum(status in TERMINAL_STATES for _, status, _ in states)
        with self.db.session() as s:
            if ended >= total:
                s.execute(
                    update(Sweep)
                    .where(Sweep.id == sweep_id, Sweep.status == "running")
                    .values(status="finished", finished_at=now_s())
                )


__all__ = ["SWEEP_STATES", "Sweep", "SweepFeeder", "SweepJob", "SweepStore", "new_sweep"]
