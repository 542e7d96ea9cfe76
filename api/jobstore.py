"""Every job state change and every job query: the job state machine, in one module.

A job (:class:`api.db.Job`) moves between five states. The allowed moves are the table
:data:`TRANSITIONS` (event -> the states it leaves, the state it enters); every status write of the
service is one of them, made by :func:`_move`, which puts the source states in the ``WHERE`` clause of
one conditional ``UPDATE``: a move that lost a race (the job moved meanwhile, or belongs to another
instance) matches no row and changes nothing. ::

    event     from       to          who
    submit    (none)     queued      POST /<collection>, a sweep's feeder
    claim     queued     running     a runner (attempt counted, owner and lease set)
    cancel    queued     cancelled   the client (DELETE), a cancelled sweep
    succeed   running    succeeded   the owner, with the result
    fail      running    failed      the owner (refusal, crash, time limit, not launched), lease expiry
    kill      running    cancelled   the owner, after a cancellation request; lease expiry
    requeue   running    queued      the owner (not launched, shutdown), lease expiry
    delete    terminal   (gone)      the client (DELETE of a finished job), retention

Within ``running`` the owner writes ``progress`` and renews its lease, and a client sets
``cancel_requested`` (the owner kills the job at its next heartbeat, whichever instance received the
request). Every write of the owner is conditional on ``owner``, so an instance that lost its lease never
overwrites the new owner's work.

:class:`JobStore` holds the database; routes, the runner (:mod:`api.jobs`) and the sweep feeder call it,
and none of them writes SQL about jobs.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Final, cast

from sqlalchemy import ColumnElement, CursorResult, delete, func, or_, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from api.db import ACTIVE_STATES, JOB_STATES, TERMINAL_STATES, Database, Job, JobFile, now_s
from api.jobtypes import DEFAULT_KIND, KEEP_PREFIX, JobKind

_LOG = logging.getLogger(__name__)

#: A job that ran this many times and was interrupted again is failed with reason ``interrupted``.
MAX_ATTEMPTS = 2


@dataclass(frozen=True)
class Move:
    """One allowed state change: the states it leaves and the state it enters (``None``: the row goes)."""

    source: frozenset[str]
    target: str | None


#: The job state machine: every allowed status change (see the module docstring).
TRANSITIONS: Final[dict[str, Move]] = {
    "submit": Move(frozenset(), "queued"),
    "claim": Move(frozenset({"queued"}), "running"),
    "cancel": Move(frozenset({"queued"}), "cancelled"),
    "succeed": Move(frozenset({"running"}), "succeeded"),
    "fail": Move(frozenset({"running"}), "failed"),
    "kill": Move(frozenset({"running"}), "cancelled"),
    "requeue": Move(frozenset({"running"}), "queued"),
    "delete": Move(frozenset(TERMINAL_STATES), None),
}

#: The event that ends a running job in each terminal state.
END_EVENT: Final[dict[str, str]] = {"succeeded": "succeed", "failed": "fail", "cancelled": "kill"}


def allowed(event: str, status: str | None) -> bool:
    """Whether ``event`` may happen to a job in ``status`` (``None``: no job yet)."""
    move = TRANSITIONS[event]
    return (status is None and not move.source) or (status in move.source)


def rows_matched(result: Any) -> int:
    """Rows matched by an UPDATE/DELETE result."""
    return int(cast(CursorResult[Any], result).rowcount or 0)


def _move(s: Session, event: str, *where: ColumnElement[bool], **values: Any) -> int:
    """Apply ``event`` to the jobs matching ``where`` that are in one of its source states.

    Returns the number of jobs moved. ``values`` are the other columns the move writes.
    """
    move = TRANSITIONS[event]
    assert move.source and move.target is not None, f"{event} is not an update"
    status = Job.status == next(iter(move.source)) if len(move.source) == 1 else Job.status.in_(move.source)
    return rows_matched(s.execute(update(Job).where(*where, status).values(status=move.target, **values)))


#: The columns a job has again when it goes back to the queue.
_REQUEUED: Final[dict[str, Any]] = {
    "stage": None,
    "progress": 0.0,
    "started_at": None,
    "owner": None,
    "lease_expires_at": None,
}


class QuotaExceeded(Exception):
    """The tenant has ``active`` queued + running jobs, at or over its ``limit``."""

    def __init__(self, active: int, limit: int) -> None:
        super().__init__(f"{active} jobs queued or running; this tenant may have at most {limit} at a time")
        self.active = active
        self.limit = limit


class IdempotencyKeyReused(Exception):
    """The tenant's ``Idempotency-Key`` names job ``job_id``, submitted with another body."""

    def __init__(self, job_id: str) -> None:
        super().__init__("this Idempotency-Key was already used with a different request body")
        self.job_id = job_id


@dataclass(frozen=True)
class Submitted:
    """The outcome of :meth:`JobStore.submit`: the job, and whether it is an earlier one (a replay)."""

    job: Job
    replayed: bool


@dataclass(frozen=True)
class Cancelled:
    """The outcome of :meth:`JobStore.cancel`: queued jobs cancelled, running ones asked to stop."""

    cancelled: list[str]
    running: list[str]


def _of_kind(kind: JobKind) -> ColumnElement[bool]:
    if kind.name == DEFAULT_KIND:
        return or_(Job.kind.is_(None), Job.kind == kind.name)
    return Job.kind == kind.name


#: Legacy columns of files written by earlier versions (before on-request files).
_LEGACY_FILES: Final[dict[str, Any]] = {"plot.png": Job.plot_png, "profile.csv": Job.profile_csv}


def new_job(
    kind: JobKind,
    tenant: str,
    job_input: dict[str, Any],
    name: str,
    request_sha256: str,
    meshes: dict[str, str],
    provenance: dict[str, Any],
    time_limit_s: float,
    idempotency_key: str | None = None,
) -> Job:
    """A new ``queued`` job of ``kind``, not yet stored (:meth:`JobStore.submit`, ``add_queued``).

    Args:
        kind: What runs it.
        tenant: Whose it is.
        job_input: The input as the worker reads it (a scenario dict for plans).
        name: The input's name (shown in the job document).
        request_sha256: What an idempotent replay compares (the request body's canonical hash).
        meshes: ``{mesh id: stored file}`` of the tenant's meshes the input names.
        provenance: The job's provenance (the input's hashes; the worker replaces it with the real one).
        time_limit_s: The job's planning time limit [s] (the runner adds its grace).
        idempotency_key: The client's ``Idempotency-Key``, if any.
    """
    return Job(
        id=uuid.uuid4().hex,
        tenant=tenant,
        kind=kind.name,
        status=TRANSITIONS["submit"].target,
        progress=0.0,
        scenario=job_input,
        scenario_name=name,
        request_sha256=request_sha256,
        idempotency_key=idempotency_key,
        meshes=meshes,
        provenance=provenance,
        time_limit_s=float(time_limit_s),
        attempts=0,
        created_at=now_s(),
    )


class JobStore:
    """Every job state change and query (see the module docstring).

    Args:
        db: The service database.
    """

    def __init__(self, db: Database) -> None:
        self.db = db

    # ------------------------------------------------------------------ submitting
    def submit(self, job: Job, max_active: int) -> Submitted:
        """Queue ``job`` (event ``submit``) under its tenant's quota, or replay its idempotency key.

        The count of the tenant's active jobs and the insert run in one transaction under the tenant's
        quota lock (:meth:`api.db.Database.tenant_quota_session`), so concurrent submissions cannot pass
        the quota together. ``job.idempotency_key`` set: a job of the tenant with that key is returned
        instead (``replayed``) when its ``request_sha256`` is the same.

        Raises:
            QuotaExceeded: the tenant has ``max_active`` jobs queued or running.
            IdempotencyKeyReused: the key names a job submitted with another body.
        """
        assert allowed("submit", None) and job.status == TRANSITIONS["submit"].target
        key = job.idempotency_key
        if key is not None:
            replay = self.replay(job.tenant, key, job.request_sha256)
            if replay is not None:
                return Submitted(replay, True)
        try:
            with self.db.tenant_quota_session(job.tenant) as s:
                active = self._active_count(s, job.tenant)
                if active >= max_active:
                    raise QuotaExceeded(active, max_active)
                s.add(job)
        except IntegrityError:  # a concurrent request with the same Idempotency-Key won the race
            replay = None if key is None else self.replay(job.tenant, key, job.request_sha256)
            if replay is None:
                raise
            return Submitted(replay, True)
        return Submitted(job, False)

    def replay(self, tenant: str, key: str, request_sha256: str) -> Job | None:
        """The tenant's job submitted with ``Idempotency-Key`` ``key``, or ``None``.

        Raises:
            IdempotencyKeyReused: it was submitted with another body (``request_sha256`` differs).
        """
        with self.db.session() as s:
            row = s.scalar(select(Job).where(Job.tenant == tenant, Job.idempotency_key == key))
        if row is not None and row.request_sha256 != request_sha256:
            raise IdempotencyKeyReused(row.id)
        return row

    @staticmethod
    def _active_count(s: Session, tenant: str) -> int:
        return int(
            s.scalar(
                select(func.count())
                .select_from(Job)
                .where(Job.tenant == tenant, Job.status.in_(ACTIVE_STATES))
            )
            or 0
        )

    def active_count(self, s: Session, tenant: str) -> int:
        """The tenant's queued + running jobs, counted in the caller's (quota-locked) session."""
        return self._active_count(s, tenant)

    @staticmethod
    def add_queued(s: Session, job: Job) -> None:
        """Add a new queued job in the caller's session (a sweep's feeder, under the quota lock)."""
        assert job.status == TRANSITIONS["submit"].target
        s.add(job)
        s.flush()  # the job row before anything linking to it (foreign keys in order)

    # ------------------------------------------------------------------ reading
    def get(self, tenant: str, job_id: str, kind: JobKind | None = None) -> Job | None:
        """The tenant's job ``job_id`` (of ``kind`` when given), or ``None``."""
        where = [Job.id == job_id, Job.tenant == tenant]
        if kind is not None:
            where.append(_of_kind(kind))
        with self.db.session() as s:
            return s.scalar(select(Job).where(*where))

    def page(
        self, tenant: str, kind: JobKind, status: str | None, limit: int, offset: int
    ) -> tuple[list[Job], int]:
        """A page of the tenant's jobs of ``kind`` (newest first) and their total count."""
        assert status is None or status in JOB_STATES
        where = [Job.tenant == tenant, _of_kind(kind)]
        if status is not None:
            where.append(Job.status == status)
        with self.db.session() as s:
            rows = s.scalars(
                select(Job).where(*where).order_by(Job.created_at.desc(), Job.id).limit(limit).offset(offset)
            ).all()
            total = s.scalar(select(func.count()).select_from(Job).where(*where)) or 0
        return list(rows), int(total)

    def result_blob(self, job_id: str) -> tuple[bytes | None, str | None]:
        """``(packed document, legacy JSON text)`` of a job's result (either may be ``None``)."""
        with self.db.session() as s:
            row = s.execute(select(Job.result_packed, Job.result_json).where(Job.id == job_id)).one_or_none()
        return (row[0], row[1]) if row is not None else (None, None)

    def stored_file(self, job_id: str, name: str) -> bytes | None:
        """A file stored for the job (made on an earlier request, or written by an earlier version)."""
        with self.db.session() as s:
            data = s.scalar(select(JobFile.data).where(JobFile.job_id == job_id, JobFile.name == name))
            if data is None and name in _LEGACY_FILES:
                legacy = s.scalar(select(_LEGACY_FILES[name]).where(Job.id == job_id))
                data = legacy.encode() if isinstance(legacy, str) else legacy
        return data

    def store_file(self, job_id: str, name: str, data: bytes) -> None:
        """Keep a file made for a finished job (a concurrent maker's identical copy wins: no error)."""
        try:
            with self.db.session() as s:
                if s.scalar(select(Job.id).where(Job.id == job_id)) is not None:
                    s.add(JobFile(job_id=job_id, name=name, data=data))
        except IntegrityError:
            pass

    def statuses(self, job_ids: Sequence[str]) -> list[tuple[str, str, str | None]]:
        """``(id, status, reason)`` of the jobs ``job_ids`` that exist."""
        if not job_ids:
            return []
        with self.db.session() as s:
            rows = s.execute(select(Job.id, Job.status, Job.reason).where(Job.id.in_(list(job_ids)))).all()
        return [(str(i), str(st), r) for i, st, r in rows]

    def rows(self, job_ids: Sequence[str]) -> list[Job]:
        """The jobs ``job_ids`` that exist (without their results: :meth:`result_blob`)."""
        if not job_ids:
            return []
        with self.db.session() as s:
            return list(s.scalars(select(Job).where(Job.id.in_(list(job_ids)))).all())

    def active_of(self, job_ids: Sequence[str]) -> int:
        """How many of ``job_ids`` are queued or running."""
        return sum(status in ACTIVE_STATES for _, status, _ in self.statuses(job_ids))

    def queue_counts(self) -> tuple[int, int]:
        """``(queued, running)`` jobs of the whole database (every instance)."""
        with self.db.session() as s:
            rows = {
                str(status): int(n)
                for status, n in s.execute(
                    select(Job.status, func.count()).where(Job.status.in_(ACTIVE_STATES)).group_by(Job.status)
                ).all()
            }
        return rows.get("queued", 0), rows.get("running", 0)

    @staticmethod
    def active_jobs(s: Session, tenant: str) -> list[Job]:
        """The tenant's queued and running jobs, read in the caller's session (a mesh deletion's check)."""
        return list(s.scalars(select(Job).where(Job.tenant == tenant, Job.status.in_(ACTIVE_STATES))).all())

    # ------------------------------------------------------------------ the client's moves
    def cancel(self, job_ids: Sequence[str], message: str) -> Cancelled:
        """Cancel the queued jobs of ``job_ids`` (event ``cancel``); ask the owners of the running ones.

        A running job gets ``cancel_requested``: its owner (this instance or another) kills it at its
        next heartbeat (event ``kill``). ``message`` is the cancelled jobs' message.
        """
        if not job_ids:
            return Cancelled([], [])
        ids = list(job_ids)
        with self.db.session() as s:
            queued = list(s.scalars(select(Job.id).where(Job.id.in_(ids), Job.status == "queued")).all())
            if queued:
                _move(
                    s,
                    "cancel",
                    Job.id.in_(queued),
                    reason="cancelled",
                    message=message,
                    finished_at=now_s(),
                )
            running = list(s.scalars(select(Job.id).where(Job.id.in_(ids), Job.status == "running")).all())
            if running:
                s.execute(
                    update(Job)
                    .where(Job.id.in_(running), Job.status == "running")
                    .values(cancel_requested=True)
                )
        cancelled = [j for j in queued if j not in running]
        return Cancelled(cancelled, running)

    def delete_finished(self, job_ids: Sequence[str], s: Session | None = None) -> int:
        """Delete the finished jobs of ``job_ids`` with their files (event ``delete``); how many went."""
        if not job_ids:
            return 0
        if s is None:
            with self.db.session() as own:
                return self.delete_finished(job_ids, own)
        ids = list(job_ids)
        gone = rows_matched(
            s.execute(delete(Job).where(Job.id.in_(ids), Job.status.in_(TRANSITIONS["delete"].source)))
        )
        s.execute(delete(JobFile).where(JobFile.job_id.in_(ids)))
        return gone

    # ------------------------------------------------------------------ the runner's moves
    def claim(self, owner: str, lease_s: float) -> Job | None:
        """Claim the oldest queued job for ``owner`` (event ``claim``, attempt counted); it, or ``None``.

        A conditional update per candidate, so a job is claimed once even with several instances on
        one PostgreSQL database.
        """
        with self.db.session() as s:
            for job_id in s.scalars(
                select(Job.id).where(Job.status == "queued").order_by(Job.created_at, Job.id).limit(8)
            ).all():
                t = now_s()
                if _move(
                    s,
                    "claim",
                    Job.id == job_id,
                    started_at=t,
                    attempts=Job.attempts + 1,
                    stage="starting",
                    owner=owner,
                    lease_expires_at=t + lease_s,
                    cancel_requested=False,
                ):
                    return s.get(Job, job_id)
        return None

    def progress(
        self, job_id: str, owner: str, stage: str, fraction: float, detail: dict[str, Any] | None = None
    ) -> None:
        """The owner's progress of a running job (stage name cut to its column's 32 characters).

        ``detail``: what the job reports beyond the fraction (a campaign's units), kept when ``None``.
        """
        values: dict[str, Any] = {"stage": stage[:32], "progress": fraction}
        if detail is not None:
            values["progress_detail"] = detail
        with self.db.session() as s:
            s.execute(
                update(Job)
                .where(Job.id == job_id, Job.status == "running", Job.owner == owner)
                .values(**values)
            )

    def keep(self, job_id: str, owner: str, name: str, data: bytes) -> bool:
        """Keep a file a running job made (a campaign's finished cycle), only while ``owner`` runs it.

        Kept files outlive the job's process (a relaunch reads them: :meth:`kept`) and go with the job.
        """
        with self.db.session() as s:
            mine = s.scalar(
                select(Job.id).where(Job.id == job_id, Job.status == "running", Job.owner == owner)
            )
            if mine is None:
                return False
            s.merge(JobFile(job_id=job_id, name=name, data=data))
        return True

    def kept(self, job_id: str, prefix: str) -> dict[str, bytes]:
        """``{name: data}`` of the job's files whose names start with ``prefix``."""
        with self.db.session() as s:
            rows = s.execute(
                select(JobFile.name, JobFile.data).where(
                    JobFile.job_id == job_id, JobFile.name.startswith(prefix)
                )
            ).all()
        return {str(n): bytes(d) for n, d in rows}

    def heartbeat(
        self, owner: str, job_ids: Iterable[str], lease_s: float
    ) -> list[tuple[str, str, Any, bool]]:
        """Renew the leases of ``owner``'s running jobs; ``(id, status, owner, cancel_requested)`` of each.

        Jobs missing from the answer were deleted (retention, a client's DELETE of a finished job).
        """
        ids = list(job_ids)
        with self.db.session() as s:
            s.execute(
                update(Job)
                .where(Job.id.in_(ids), Job.status == "running", Job.owner == owner)
                .values(lease_expires_at=now_s() + lease_s)
            )
            rows = s.execute(
                select(Job.id, Job.status, Job.owner, Job.cancel_requested).where(Job.id.in_(ids))
            ).all()
        return [(str(i), str(st), o, bool(c)) for i, st, o, c in rows]

    def launching(self, owner: str, job_ids: Sequence[str]) -> set[str]:
        """Those of ``job_ids`` that ``owner`` claimed and runs (its process may still be starting)."""
        with self.db.session() as s:
            return set(
                s.scalars(
                    select(Job.id).where(
                        Job.id.in_(list(job_ids)), Job.status == "running", Job.owner == owner
                    )
                )
            )

    def time_limit_s(self, job_id: str) -> float:
        """The job's planning time limit [s] (0 when it is gone)."""
        with self.db.session() as s:
            return float(s.scalar(select(Job.time_limit_s).where(Job.id == job_id)) or 0.0)

    def end(self, job_id: str, owner: str, status: str, **values: Any) -> bool:
        """End ``owner``'s running job in ``status`` (events ``succeed``, ``fail``, ``kill``).

        Never over another instance's job or over a state it left (a cancellation, a lease expiry).
        ``values``: ``reason``, ``message``, ``result_packed``, ``provenance``. Returns whether it was
        written.
        """
        with self.db.session() as s:
            return bool(
                _move(
                    s,
                    END_EVENT[status],
                    Job.id == job_id,
                    Job.owner == owner,
                    finished_at=now_s(),
                    progress=1.0 if status == "succeeded" else Job.progress,
                    lease_expires_at=None,
                    **values,
                )
            )

    def requeue(self, job_id: str, owner: str) -> None:
        """Put ``owner``'s running job back in the queue, its attempt not counted (event ``requeue``).

        Not launched (its files could not be fetched now), or the instance is shutting down.
        """
        with self.db.session() as s:
            _move(s, "requeue", Job.id == job_id, Job.owner == owner, attempts=Job.attempts - 1, **_REQUEUED)

    def expire_leases(self, now: float | None = None) -> dict[str, int]:
        """Re-queue (or fail) the running jobs whose lease lapsed: their instance died. Returns the counts.

        A lapsed job whose cancellation was requested is killed (``cancelled``); one with fewer than
        :data:`MAX_ATTEMPTS` attempts is re-queued; the others fail with reason ``interrupted``. Rows
        without a lease (written by an older version) count as lapsed.
        """
        t = now_s() if now is None else now
        lapsed = (or_(Job.lease_expires_at.is_(None), Job.lease_expires_at < t),)
        free = {"owner": None, "lease_expires_at": None}
        with self.db.session() as s:
            # Read first: every instance runs this at each heartbeat, and an UPDATE is a write
            # transaction (an fsync on SQLite) even when it matches nothing.
            if not s.scalar(select(func.count()).select_from(Job).where(Job.status == "running", *lapsed)):
                return {"requeued": 0, "failed": 0, "cancelled": 0}
            cancelled = _move(
                s,
                "kill",
                *lapsed,
                Job.cancel_requested.is_(True),
                reason="cancelled",
                message="cancelled by the client while running (its instance stopped)",
                finished_at=t,
                **free,
            )
            requeued = _move(s, "requeue", *lapsed, Job.attempts < MAX_ATTEMPTS, **_REQUEUED)
            failed = _move(
                s,
                "fail",
                *lapsed,
                reason="interrupted",
                message=f"the service stopped while the job was running, {MAX_ATTEMPTS} times",
                finished_at=t,
                **free,
            )
        counts = {"requeued": requeued, "failed": failed, "cancelled": cancelled}
        if requeued or failed or cancelled:
            _LOG.warning("jobs of a stopped instance recovered: %s", counts)
        return counts

    def purge_expired(self, retention_s: float, now: float | None = None) -> int:
        """Delete jobs that finished more than ``retention_s`` ago (event ``delete``); returns how many."""
        cutoff = (now_s() if now is None else now) - retention_s
        with self.db.session() as s:
            ids = list(
                s.scalars(
                    select(Job.id).where(
                        Job.status.in_(TERMINAL_STATES),
                        Job.finished_at.is_not(None),
                        Job.finished_at < cutoff,
                    )
                ).all()
            )
            n = self.delete_finished(ids, s)
        if n:
            _LOG.info("retention: deleted %d finished job(s) older than %.0f days", n, retention_s / 86400)
        return n


def expire_leases(db: Database, now: float | None = None) -> dict[str, int]:
    """:meth:`JobStore.expire_leases` on ``db``."""
    return JobStore(db).expire_leases(now)


def recover_jobs(db: Database) -> dict[str, int]:
    """Start-up recovery: :func:`expire_leases` now (jobs of live instances keep running)."""
    counts = expire_leases(db)
    return {"requeued": counts["requeued"], "failed": counts["failed"]}


def purge_expired(db: Database, retention_s: float, now: float | None = None) -> int:
    """:meth:`JobStore.purge_expired` on ``db``."""
    return JobStore(db).purge_expired(retention_s, now)


__all__ = [
    "END_EVENT",
    "KEEP_PREFIX",
    "MAX_ATTEMPTS",
    "TRANSITIONS",
    "Cancelled",
    "IdempotencyKeyReused",
    "JobStore",
    "Move",
    "QuotaExceeded",
    "Submitted",
    "allowed",
    "new_job",
    "expire_leases",
    "purge_expired",
    "recover_jobs",
    "rows_matched",
]
