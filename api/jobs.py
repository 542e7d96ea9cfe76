"""Planning jobs: the runner that executes them in worker processes, and start-up recovery.

Jobs live in the database (:class:`api.db.Job`); the runner only claims and executes them, so nothing
submitted is lost when the service stops. :class:`ProcessJobRunner` (the default) runs each job in a
fresh process forked from a forkserver that has imported the planner once (warm start, no shared
state between jobs). A dispatcher thread, never the event loop:

* claims queued jobs oldest first (a conditional ``UPDATE ... WHERE status='queued'``, so a job is
  claimed once even with several service instances on one PostgreSQL database), up to ``workers`` at a
  time, and counts the attempt;
* reads ``progress`` and ``done`` messages from each job's pipe and writes them to the database;
* kills a job whose hard wall-clock limit (``time_limit_s + job_grace_s``) expires and marks it failed
  with reason ``time_limit_exceeded``: the process is gone, so its slot is free for the next job (the
  "worker" is replaced by construction);
* kills a running job on cancellation (status ``cancelled``); a process that dies without an outcome
  makes its job fail with reason ``worker_crashed``.

On start-up (:func:`recover_jobs`) a job left ``running`` by a dead process is re-queued once (the
attempt counter) and failed with reason ``interrupted`` if it was already retried; queued jobs simply
run. On a clean shutdown running jobs are killed and re-queued without counting the attempt.

One service instance per database: recovery treats every ``running`` row as left by a dead process, and
a cancellation reaches only this instance's processes (jobs carry no owner lease yet), so two instances
must not share a database.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.context import ForkServerContext
from multiprocessing.process import BaseProcess
from typing import Any, Protocol, cast

from sqlalchemy import CursorResult, select, update

from api.db import Database, Job, now_s
from api.settings import Settings

_LOG = logging.getLogger(__name__)

#: A job that ran this many times and was interrupted again is failed with reason ``interrupted``.
MAX_ATTEMPTS = 2


class JobRunner(Protocol):
    """What the service needs of a job executor (pluggable: processes here, a cluster elsewhere)."""

    def start(self) -> None:
        """Start executing queued jobs."""

    def stop(self) -> None:
        """Stop; running jobs are re-queued."""

    def wake(self) -> None:
        """A job was queued: look for work now."""

    def cancel(self, job_id: str) -> None:
        """Kill the job if it is running (it becomes ``cancelled``)."""

    def alive(self) -> bool:
        """True while the runner can execute jobs."""

    def busy(self) -> int:
        """Jobs running now."""


def recover_jobs(db: Database) -> dict[str, int]:
    """Start-up recovery of jobs left ``running`` by a process that died; returns the counts.

    Jobs with fewer than :data:`MAX_ATTEMPTS` attempts go back to ``queued``; the others fail with reason
    ``interrupted``. Nothing is left ``running``.
    """
    with db.session() as s:
        requeued = rows_matched(
            s.execute(
                update(Job)
                .where(Job.status == "running", Job.attempts < MAX_ATTEMPTS)
                .values(status="queued", stage=None, progress=0.0, started_at=None)
            )
        )
        failed = rows_matched(
            s.execute(
                update(Job)
                .where(Job.status == "running")
                .values(
                    status="failed",
                    reason="interrupted",
                    message=f"the service stopped while the job was running, {MAX_ATTEMPTS} times",
                    finished_at=now_s(),
                )
            )
        )
    counts = {"requeued": requeued, "failed": failed}
    if counts["requeued"] or counts["failed"]:
        _LOG.warning("recovered interrupted jobs: %s", counts)
    return counts


def rows_matched(result: Any) -> int:
    """Rows matched by an UPDATE/DELETE result."""
    return int(cast(CursorResult[Any], result).rowcount or 0)


@dataclass
class _Running:
    job_id: str
    process: BaseProcess
    conn: Connection
    deadline: float
    outcome: dict[str, Any] | None = None
    eof: bool = False


_context_lock = threading.Lock()


#: Thread pools of numerical libraries in each job process: one thread (a job is one core's work, and a
#: forked child must not inherit a thread pool the forkserver started).
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}


def _mp_context(preload: bool) -> ForkServerContext:
    """The forkserver context; with ``preload`` the forkserver imports and warms up the planner once.

    The forkserver inherits this process's environment when it starts (at the first job), so the
    single-thread settings are put in place first.
    """
    with _context_lock:
        for name, value in SINGLE_THREAD_ENV.items():
            os.environ.setdefault(name, value)
        ctx = multiprocessing.get_context("forkserver")
        assert isinstance(ctx, ForkServerContext)
        if preload:
            ctx.set_forkserver_preload(["api.warmup"])
        return ctx


#: Tries of a job's terminal-state write (a busy SQLite file, a dropped PostgreSQL connection).
END_WRITE_ATTEMPTS = 5


class ProcessJobRunner:
    """Runs each job in its own process with a hard wall-clock limit (see the module docstring).

    Args:
        db: The job database.
        settings: Worker count, grace and data directory.
        poll_s: Dispatcher wake-up period [s].
    """

    def __init__(self, db: Database, settings: Settings, poll_s: float = 0.05) -> None:
        self.db = db
        self.settings = settings
        self.poll_s = poll_s
        self.empty_dir = settings.data_dir / "empty"
        self._running: dict[str, _Running] = {}
        self._cancel: set[str] = set()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._ctx = _mp_context(settings.forkserver_preload)

    # ----------------------------------------------------------------------- protocol
    def start(self) -> None:
        """Start the dispatcher thread."""
        self.empty_dir.mkdir(parents=True, exist_ok=True)
        self._stopping.clear()
        self._thread = threading.Thread(target=self._loop, name="cabinplan-jobs", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop dispatching; kill running jobs and put them back in the queue (attempt not counted)."""
        self._stopping.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        with self._lock:
            running = list(self._running.values())
            self._running.clear()
        for r in running:
            self._kill(r)
            with self.db.session() as s:
                s.execute(
                    update(Job)
                    .where(Job.id == r.job_id, Job.status == "running")
                    .values(
                        status="queued", stage=None, progress=0.0, started_at=None, attempts=Job.attempts - 1
                    )
                )

    def wake(self) -> None:
        """Look for queued work now."""
        self._wake.set()

    def cancel(self, job_id: str) -> None:
        """Ask the dispatcher to kill the job if it runs."""
        with self._lock:
            self._cancel.add(job_id)
        self._wake.set()

    def alive(self) -> bool:
        """The dispatcher thread runs."""
        return self._thread is not None and self._thread.is_alive() and not self._stopping.is_set()

    def busy(self) -> int:
        """Jobs running now."""
        with self._lock:
            return len(self._running)

    # ----------------------------------------------------------------------- dispatcher
    def _loop(self) -> None:
        while not self._stopping.is_set():
            try:
                self._step()
            except Exception:  # keep dispatching: a database hiccup must not stop every job
                _LOG.exception("job dispatcher step failed")
                time.sleep(0.5)

    def _step(self) -> None:
        self._apply_cancels()
        self._fill()
        with self._lock:
            running = list(self._running.values())
        if running:
            handles: list[Any] = [r.conn for r in running if not r.eof]
            handles += [r.process.sentinel for r in running]
            wait(handles, timeout=self.poll_s)
        else:
            self._wake.wait(self.poll_s)
            self._wake.clear()
        for r in running:
            self._drain(r)
            if r.eof and not r.process.is_alive():
                self._finish(r)
            elif time.monotonic() > r.deadline:
                self._kill(r)
                self._drain(r)
                if r.outcome is not None:  # it finished in the last instant
                    self._finish(r)
                else:
                    limit = self._hard_limit_s(r.job_id)
                    self._end(
                        r,
                        "failed",
                        reason="time_limit_exceeded",
                        message=f"the job ran past its hard wall-clock limit of {limit:.3g} s and was killed",
                    )

    def _hard_limit_s(self, job_id: str) -> float:
        with self.db.session() as s:
            limit = s.scalar(select(Job.time_limit_s).where(Job.id == job_id))
        return float(limit or 0.0) + self.settings.job_grace_s

    def _apply_cancels(self) -> None:
        """Kill the running jobs asked for; keep requests for jobs still being launched."""
        with self._lock:
            cancels, self._cancel = self._cancel, set()
            targets = [self._running[j] for j in cancels if j in self._running]
            pending = [j for j in cancels if j not in self._running]
        if pending:
            with self.db.session() as s:
                launching = set(s.scalars(select(Job.id).where(Job.id.in_(pending), Job.status == "running")))
            with self._lock:
                self._cancel |= launching
        for r in targets:
            self._kill(r)
            self._end(r, "cancelled", reason="cancelled", message="cancelled by the client while running")

    def _fill(self) -> None:
        while not self._stopping.is_set():
            with self._lock:
                if len(self._running) >= self.settings.workers:
                    return
            job = self._claim()
            if job is None:
                return
            self._launch(job)

    def _claim(self) -> dict[str, Any] | None:
        """Claim the oldest queued job (conditional update); its launch description, or ``None``."""
        with self.db.session() as s:
            for job_id in s.scalars(
                select(Job.id).where(Job.status == "queued").order_by(Job.created_at, Job.id).limit(8)
            ).all():
                claimed = rows_matched(
                    s.execute(
                        update(Job)
                        .where(Job.id == job_id, Job.status == "queued")
                        .values(
                            status="running", started_at=now_s(), attempts=Job.attempts + 1, stage="starting"
                        )
                    )
                )
                if claimed:
                    row = s.get(Job, job_id)
                    assert row is not None
                    return {
                        "id": row.id,
                        "scenario": row.scenario,
                        "meshes": dict(row.meshes),
                        "empty_dir": str(self.empty_dir),
                        "time_limit_s": row.time_limit_s,
                        "nice": self.settings.worker_nice,
                    }
        return None

    def _launch(self, job: dict[str, Any]) -> None:
        from api.worker import run_job  # the child's entry point (preloaded by the forkserver)

        parent, child = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(
            target=run_job, args=(job, child), name=f"cabinplan-job-{job['id']}", daemon=True
        )
        try:
            proc.start()
        except Exception as exc:  # no process: fail the job now rather than at its deadline
            _LOG.exception("job %s: the worker process did not start", job["id"])
            parent.close()
            child.close()
            with self.db.session() as s:
                s.execute(
                    update(Job)
                    .where(Job.id == job["id"], Job.status == "running")
                    .values(
                        status="failed",
                        reason="worker_start_failed",
                        message=f"the worker process did not start: {type(exc).__name__}: {exc}",
                        finished_at=now_s(),
                    )
                )
            return
        child.close()
        deadline = time.monotonic() + float(job["time_limit_s"]) + self.settings.job_grace_s
        with self._lock:
            self._running[job["id"]] = _Running(job["id"], proc, parent, deadline)
        _LOG.info("job %s started (pid %s)", job["id"], proc.pid)

    def _drain(self, r: _Running) -> None:
        while not r.eof:
            try:
                if not r.conn.poll(0):
                    return
                msg = r.conn.recv()
            except (EOFError, OSError):
                r.eof = True
                return
            if msg[0] == "progress":
                with self.db.session() as s:
                    s.execute(
                        update(Job)
                        .where(Job.id == r.job_id, Job.status == "running")
                        .values(stage=str(msg[1])[:32], progress=float(msg[2]))
                    )
            elif msg[0] == "done":
                r.outcome = msg[1]

    def _finish(self, r: _Running) -> None:
        out = r.outcome
        if out is None:
            code = r.process.exitcode
            self._end(
                r,
                "failed",
                reason="worker_crashed",
                message=f"the worker process ended without a result (exit code {code})",
            )
            return
        values: dict[str, Any] = {}
        if out.get("provenance"):  # what really made the plan (the submit-time hashes are a forecast)
            values["provenance"] = out["provenance"]
        self._end(
            r,
            str(out["status"]),
            reason=out.get("reason"),
            message=out.get("message"),
            result_json=out.get("document"),
            profile_csv=out.get("csv"),
            plot_png=out.get("png"),
            **values,
        )

    def _kill(self, r: _Running) -> None:
        if r.process.is_alive():
            r.process.kill()
        r.process.join(timeout=5.0)

    def _end(self, r: _Running, status: str, **values: Any) -> None:
        """Write the terminal state (only over ``running``: a cancellation is never overwritten).

        The slot is released first, so that whoever reads the terminal state also sees the slot free.
        """
        with self._lock:
            self._running.pop(r.job_id, None)
        try:
            for attempt in range(END_WRITE_ATTEMPTS):
                try:
                    with self.db.session() as s:
                        s.execute(
                            update(Job)
                            .where(Job.id == r.job_id, Job.status == "running")
                            .values(
                                status=status,
                                finished_at=now_s(),
                                progress=1.0 if status == "succeeded" else Job.progress,
                                **values,
                            )
                        )
                    break
                except Exception:  # a busy or dropped database: retry, then leave it to start-up recovery
                    if attempt == END_WRITE_ATTEMPTS - 1:
                        _LOG.exception("job %s: terminal state %s not written", r.job_id, status)
                    else:
                        time.sleep(0.5 * (attempt + 1))
        finally:
            r.process.join(timeout=5.0)
            r.conn.close()
            try:
                r.process.close()
            except ValueError:
                pass
        _LOG.info("job %s %s (%s)", r.job_id, status, values.get("reason"))
        self._wake.set()


__all__ = ["MAX_ATTEMPTS", "JobRunner", "ProcessJobRunner", "recover_jobs", "rows_matched"]
