"""Jobs: the runner that executes them in worker processes, and start-up recovery.

Jobs live in the database (:class:`api.db.Job`); every change of their state is one move of the state
machine in :mod:`api.jobstore`, which the runner calls (it writes no SQL itself). The runner only claims
and executes jobs, so nothing submitted is lost when the service stops. :class:`ProcessJobRunner` (the
default) runs jobs in warm, reused worker processes (:class:`planner.core.procpool.WarmPool`, the sweep
executor's pool): forked from a forkserver that has imported and warmed up the planner once, each worker
runs one job at a time and keeps what the planner caches by content (compiled kernels, parsed meshes, a
cabin's collision geometry) for its next jobs, so a job costs its planning time plus a small overhead
instead of a process start and a cold cabin. A worker is replaced by a fresh one after
``worker_max_jobs`` jobs or once its resident memory exceeds ``worker_max_rss_bytes`` after a job, so
memory never grows without bound; ``worker_max_jobs = 1`` gives a fresh process per job. The job's kind
(:mod:`api.jobkinds`) names the function the worker runs. A dispatcher thread, never the event loop:

* claims queued jobs oldest first (a conditional ``UPDATE ... WHERE status='queued'``, so a job is
  claimed once even with several service instances on one PostgreSQL database), up to ``workers`` at a
  time, and counts the attempt;
* reads ``progress`` and ``done`` messages from each job's pipe and writes them to the database (the
  latest progress at most every :data:`PROGRESS_PERIOD_S`, with its detail -- a campaign's units --,
  the outcome once);
* stores the files a running job hands over to keep (``keep`` messages: a campaign's finished cycles,
  :meth:`api.jobstore.JobStore.keep`) and gives them to the job's next attempt (``kept``), so a job whose
  instance died resumes from them;
* kills a job whose hard wall-clock limit (``time_limit_s + job_grace_s``) expires (SIGKILL of its
  worker) and marks it failed with reason ``time_limit_exceeded``; the pool forks a fresh worker in its
  place (one spare is kept forked ahead, so the next job starts at once);
* kills a running job's worker on cancellation (status ``cancelled``), replaced the same way; a worker
  that dies without an outcome makes its job (only its job) fail with reason ``worker_crashed``.

Several instances may share one database (PostgreSQL). Each runner has an instance id; a claimed job
carries its ``owner`` and a lease (``lease_expires_at``) that the owner renews every ``job_lease_s / 3``
(the heartbeat). Every instance re-queues the jobs whose lease lapsed (:func:`expire_leases`, also at
start-up): their instance died. A job re-queued :data:`MAX_ATTEMPTS` times fails with reason
``interrupted``. Every write of a job's progress or outcome is conditional on ``owner``, so an instance
that lost its lease (paused, cut off from the database) never overwrites the new owner's work, and
kills its own copy at the next heartbeat. A cancellation sets ``cancel_requested``; the owner sees it
at its next heartbeat, whichever instance received the request. On a clean shutdown running jobs are
killed and re-queued without counting the attempt.

Job workers die with the service: each arms a parent-death signal when it starts, busy or idle, and the
forkserver watches the server (:mod:`planner.core.lifeline`), so a SIGKILLed server leaves no process behind.
Before it claims the first job the runner starts the forkserver and its workers and waits for the warm-up
(imports, the collision kernels
loaded from their ahead-of-time build, or built first on a fresh install -- numba's JIT without a C
compiler --, one reference plan): ``/ready`` answers 503 with stage ``compiling kernels``
until then, and no job's time limit is spent on it.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.context import ForkServerContext
from multiprocessing.process import BaseProcess
from typing import Any, Protocol

from api import results
from api.db import Database
from api.jobkinds import kind_of
from api.jobstore import (
    KEEP_PREFIX,
    MAX_ATTEMPTS,
    JobStore,
    expire_leases,
    purge_expired,
    recover_jobs,
    rows_matched,
)
from api.metrics import ServiceMetrics
from api.settings import Settings
from api.store import local_mesh_file
from api.worker import run_job, worker_setup
from planner.core.lifeline import SERVER_PID_ENV
from planner.core.procpool import SINGLE_THREAD_ENV, WarmPool, Worker

_LOG = logging.getLogger(__name__)

#: Stage reported (``/ready``, queued jobs) while the forkserver warms up.
WARMUP_STAGE = "compiling kernels"

#: Jobs remembered in :attr:`ProcessJobRunner.ran_on`.
RAN_ON_KEPT = 256

#: Period of the retention purge [s].
PURGE_PERIOD_S = 60.0

#: A running job's progress is written at most this often [s] (:meth:`ProcessJobRunner._drain`).
PROGRESS_PERIOD_S = 0.25


class JobRunner(Protocol):
    """What the service needs of a job executor (pluggable: processes here, a cluster elsewhere)."""

    #: Identity of this instance in the jobs' ``owner`` column.
    instance_id: str

    def start(self) -> None:
        """Start executing queued jobs."""

    def stop(self) -> None:
        """Stop; running jobs are re-queued."""

    def wake(self) -> None:
        """A job was queued: look for work now."""

    def cancel(self, job_id: str) -> None:
        """Kill the job if it is running here (it becomes ``cancelled``)."""

    def on_job_end(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(job_id)`` (in the runner's thread) each time a job of this instance ends."""

    def alive(self) -> bool:
        """True while the runner can execute jobs."""

    def busy(self) -> int:
        """Jobs running now."""

    def warming(self) -> str | None:
        """The warm-up stage while the runner is not yet ready to run jobs, else ``None``."""


@dataclass
class _Running:
    job_id: str
    worker: Worker
    deadline: float
    started: float
    outcome: dict[str, Any] | None = None
    eof: bool = False
    #: Its worker was killed (and reaped) by the runner.
    killed: bool = False
    #: Latest (stage, fraction) and detail reported and not yet written; when progress was last written.
    progress: tuple[str, float] | None = None
    detail: dict[str, Any] | None = None
    progress_at: float = 0.0

    @property
    def conn(self) -> Connection:
        return self.worker.conn

    @property
    def process(self) -> BaseProcess:
        return self.worker.process


_context_lock = threading.Lock()


def _mp_context(preload: bool) -> ForkServerContext:
    """The forkserver context; it watches this server, and with ``preload`` warms up the planner once.

    The forkserver inherits this process's environment when it starts, so the single-thread settings
    and the server's pid (:data:`planner.core.lifeline.SERVER_PID_ENV`) are put in place first.
    """
    with _context_lock:
        for name, value in SINGLE_THREAD_ENV.items():
            os.environ.setdefault(name, value)
        os.environ[SERVER_PID_ENV] = str(os.getpid())
        ctx = multiprocessing.get_context("forkserver")
        assert isinstance(ctx, ForkServerContext)
        ctx.set_forkserver_preload(["api.forkserver", *(["api.warmup"] if preload else [])])
        return ctx


#: Tries of a job's terminal-state write (a busy SQLite file, a dropped PostgreSQL connection).
END_WRITE_ATTEMPTS = 5


class ProcessJobRunner:
    """Runs jobs in warm, reused worker processes with a hard wall-clock limit (see the module docstring).

    Args:
        db: The job database.
        settings: Worker count, grace, lease, retention and data directory.
        metrics: Where job outcomes and durations are counted (default: a private registry).
        poll_s: Dispatcher wake-up period [s].
    """

    def __init__(
        self, db: Database, settings: Settings, metrics: ServiceMetrics | None = None, poll_s: float = 0.05
    ) -> None:
        self.db = db
        self.store = JobStore(db)
        self.settings = settings
        self.metrics = metrics or ServiceMetrics()
        self.poll_s = poll_s
        self.instance_id = uuid.uuid4().hex
        self.empty_dir = settings.data_dir / "empty"
        self.heartbeat_s = max(0.05, min(settings.job_lease_s / 3.0, 2.0))
        self._running: dict[str, _Running] = {}
        self._cancel: set[str] = set()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._warm = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_sync = 0.0
        self._last_purge = 0.0
        self._ctx = _mp_context(settings.forkserver_preload)
        self._pool = self._new_pool()
        #: Job id -> (worker pid, which job of that worker it was: 1 for a fresh worker) of the latest
        #: :data:`RAN_ON_KEPT` jobs started here (logs, tests).
        self.ran_on: OrderedDict[str, tuple[int, int]] = OrderedDict()
        self._end_listeners: list[Callable[[str], None]] = []

    def _new_pool(self) -> WarmPool:
        return WarmPool(
            self._ctx,
            run_job,
            slots=self.settings.workers,
            tasks_per_process=self.settings.worker_max_jobs,
            max_rss_bytes=self.settings.worker_max_rss_bytes,
            setup=worker_setup,
            setup_args=(os.getpid(), self.settings.worker_nice),
            name="cabinplan-job-worker",
            on_retire=lambda cause: self.metrics.workers_replaced.labels(cause=cause).inc(),
        )

    # ----------------------------------------------------------------------- protocol
    def start(self) -> None:
        """Start the dispatcher thread (it warms the forkserver up first)."""
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
            self.store.requeue(r.job_id, self.instance_id)
        self._pool.close()
        self._pool = self._new_pool()  # a later start() forks fresh workers
        self._warm.clear()

    def wake(self) -> None:
        """Look for queued work now."""
        self._wake.set()

    def on_job_end(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(job_id)`` each time a job of this instance ends (terminal state written or not)."""
        self._end_listeners.append(listener)

    def cancel(self, job_id: str) -> None:
        """Ask the dispatcher to kill the job if it runs here (others see ``cancel_requested``)."""
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

    def warming(self) -> str | None:
        """:data:`WARMUP_STAGE` until the forkserver is warm, then ``None``."""
        return None if self._warm.is_set() else WARMUP_STAGE

    # ----------------------------------------------------------------------- dispatcher
    def _warm_up(self) -> None:
        """Start the forkserver (it imports and warms up the planner) and fork the idle workers from it."""
        t0 = time.perf_counter()
        try:
            self._pool.start()
        except Exception:  # workers are then forked per job as they are needed: slower, never wrong
            _LOG.exception("job worker warm-up failed")
        took = time.perf_counter() - t0
        self.metrics.warmup_seconds.set(took)
        _LOG.info("job forkserver warm (%.1f s)", took)
        self._warm.set()

    def _loop(self) -> None:
        if not self._warm.is_set():
            self._warm_up()
        while not self._stopping.is_set():
            try:
                self._step()
            except Exception:  # keep dispatching: a database hiccup must not stop every job
                _LOG.exception("job dispatcher step failed")
                time.sleep(0.5)

    def _step(self) -> None:
        self._apply_cancels()
        now = time.monotonic()
        if now - self._last_sync >= self.heartbeat_s:
            self._last_sync = now
            self._sync()
            self.store.expire_leases()
        if now - self._last_purge >= PURGE_PERIOD_S:
            self._last_purge = now
            self.store.purge_expired(self.settings.retention_days * 86400.0)
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
            if r.outcome is not None:
                self._finish(r)
            elif r.eof or not r.process.is_alive():
                self._drain(r)  # what it sent before it died
                if r.outcome is not None:
                    self._finish(r)
                else:
                    self._crashed(r)
            elif time.monotonic() > r.deadline:
                self._drain(r)
                if r.outcome is not None:  # it finished in the last instant
                    self._finish(r)
                    continue
                self._kill(r)
                limit = self._hard_limit_s(r.job_id)
                self._end(
                    r,
                    "failed",
                    reason="time_limit_exceeded",
                    message=f"the job ran past its hard wall-clock limit of {limit:.3g} s and was killed",
                )

    def _sync(self) -> None:
        """Heartbeat: renew the leases of this instance's jobs; act on remote cancels and lost leases."""
        with self._lock:
            mine = dict(self._running)
        if not mine:
            return
        rows = self.store.heartbeat(self.instance_id, mine, self.settings.job_lease_s)
        seen = set()
        for job_id, status, owner, cancel in rows:
            seen.add(job_id)
            r = mine[job_id]
            if status != "running" or owner != self.instance_id:
                _LOG.warning(
                    "job %s: lease lost (now %s, owner %s); killing the local copy", job_id, status, owner
                )
                self._drop(r)
            elif cancel:
                self._kill(r)
                self._end(r, "cancelled", reason="cancelled", message="cancelled by the client while running")
        for job_id in set(mine) - seen:  # deleted under us (retention, or a finished plan deleted)
            self._drop(mine[job_id])

    def _drop(self, r: _Running) -> None:
        """Kill a job's worker without writing anything (the job is no longer this instance's)."""
        with self._lock:
            self._running.pop(r.job_id, None)
        self._kill(r)

    def _hard_limit_s(self, job_id: str) -> float:
        return self.store.time_limit_s(job_id) + self.settings.job_grace_s

    def _apply_cancels(self) -> None:
        """Kill the running jobs asked for; keep requests for jobs still being launched."""
        with self._lock:
            cancels, self._cancel = self._cancel, set()
            targets = [self._running[j] for j in cancels if j in self._running]
            pending = [j for j in cancels if j not in self._running]
        if pending:
            launching = self.store.launching(self.instance_id, pending)
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
            if job is None or not self._launch(job):
                return

    def _claim(self) -> dict[str, Any] | None:
        """Claim the oldest queued job (:meth:`JobStore.claim`); its launch description, or ``None``."""
        row = self.store.claim(self.instance_id, self.settings.job_lease_s)
        if row is None:
            return None
        kept = self.store.kept(row.id, KEEP_PREFIX)  # an earlier attempt's finished work (campaigns)
        return {
            "id": row.id,
            "kind": row.kind,
            "runner": kind_of(row.kind).runner,  # pickled by reference: the worker imports its module
            "kept": kept,
            "scenario": row.scenario,
            "meshes": dict(row.meshes),
            "empty_dir": str(self.empty_dir),
            "time_limit_s": row.time_limit_s,
        }

    def _launch(self, job: dict[str, Any]) -> bool:
        """Hand the job to a warm worker; False when it went back to the queue (try again on a later pass)."""
        try:  # the tenant's mesh files on this instance's disk (another instance may have taken them)
            root = self.settings.mesh_dir
            meshes = {k: str(local_mesh_file(self.db, root, v)) for k, v in job["meshes"].items()}
        except FileNotFoundError as exc:  # the mesh is gone (deleted): the job can never run
            self._fail_unlaunched(job["id"], "mesh_unavailable", f"a cabin mesh is unavailable: {exc}")
            return True
        except Exception:  # a passing failure (the database, the disk): back to the queue, not failed
            _LOG.exception("job %s: its mesh files could not be fetched now; re-queued", job["id"])
            self._requeue_unlaunched(job["id"])
            return False
        job = {**job, "meshes": meshes}
        try:
            worker = self._pool.send(job)
        except Exception as exc:  # no worker: fail the job now rather than at its deadline
            _LOG.exception("job %s: no worker process took it", job["id"])
            why = f"the worker process did not start: {type(exc).__name__}: {exc}"
            self._fail_unlaunched(job["id"], "worker_start_failed", why)
            return True
        started = time.monotonic()
        deadline = started + float(job["time_limit_s"]) + self.settings.job_grace_s
        with self._lock:
            self._running[job["id"]] = _Running(job["id"], worker, deadline, started, progress_at=started)
            self.ran_on[job["id"]] = (worker.pid or 0, worker.served)
            while len(self.ran_on) > RAN_ON_KEPT:
                self.ran_on.popitem(last=False)
        _LOG.info("job %s started (worker pid %s, its job %d)", job["id"], worker.pid, worker.served)
        return True

    def _fail_unlaunched(self, job_id: str, reason: str, message: str) -> None:
        """Fail a job this instance claimed but could not start (only over its own ``running``)."""
        self.store.end(job_id, self.instance_id, "failed", reason=reason, message=message)
        self.metrics.job_outcomes.labels(status="failed", reason=reason).inc()

    def _requeue_unlaunched(self, job_id: str) -> None:
        """Put a job this instance claimed but could not start back in the queue, its attempt uncounted."""
        try:
            self.store.requeue(job_id, self.instance_id)
        except Exception:  # the database itself is away: the lease lapses and any instance re-queues it
            _LOG.exception("job %s: not re-queued now; its lease will lapse", job_id)

    def _drain(self, r: _Running) -> None:
        """Read the job's messages; write its latest progress at most once a :data:`PROGRESS_PERIOD_S`.

        A plan reports each stage as it starts, several a second; each write is a committed (synced)
        transaction on the dispatcher's thread, which meanwhile hands no finished worker its next job.
        So the latest progress waits until the period since the job's last progress write (or its
        start) is over, and a job that ends first never writes it: its end write supersedes it.
        """
        while not r.eof:
            try:
                if not r.conn.poll(0):
                    break
                msg = r.conn.recv()
            except (EOFError, OSError):
                r.eof = True
                break
            if msg[0] == "progress":
                if len(msg) > 3 and msg[3] is not None:
                    r.detail = msg[3]
                r.progress = (str(msg[1]), float(msg[2]))
            elif msg[0] == "keep":  # a file the job keeps for a relaunch (a campaign's finished cycle)
                self.store.keep(r.job_id, self.instance_id, str(msg[1]), bytes(msg[2]))
            elif msg[0] == "done":
                r.outcome = msg[1]
        if r.outcome is not None or r.eof:
            if r.detail is not None and r.outcome is not None:  # its last units stay in its document
                self.store.progress(r.job_id, self.instance_id, "finishing", 0.99, r.detail)
            r.progress = r.detail = None
            return
        now = time.monotonic()
        if r.progress is not None and now - r.progress_at >= PROGRESS_PERIOD_S:
            self.store.progress(r.job_id, self.instance_id, *r.progress, r.detail)
            r.progress = r.detail = None
            r.progress_at = now

    def _crashed(self, r: _Running) -> None:
        """The job's worker died without an outcome: reap it (a fresh one takes its place), fail the job."""
        try:
            r.process.join(timeout=1.0)
            code = r.process.exitcode
        except ValueError:
            code = None
        r.killed = True
        self._pool.discard(r.worker, died=True)
        self._end(
            r,
            "failed",
            reason="worker_crashed",
            message=f"the worker process ended without a result (exit code {code})",
        )

    def _finish(self, r: _Running) -> None:
        """The job's outcome arrived: its worker returns to the pool (or retires); the outcome is written.

        The freed worker is handed the next queued job before the outcome is written (a 1-MB blob, a
        synced commit, the waiting readers woken): it plans while the dispatcher writes, instead of
        idling for the write and then the claim (measured under ``bench.load``: 16 ms a job, median).
        """
        out = r.outcome
        assert out is not None
        with self._lock:
            self._running.pop(r.job_id, None)
        if not r.killed:
            self._pool.release(r.worker)
            try:
                self._fill()
            except Exception:  # the outcome is written all the same; the next step claims again
                _LOG.exception("job dispatcher: claiming the next job failed")
        values: dict[str, Any] = {}
        if out.get("provenance"):  # what really made the plan (the submit-time hashes are a forecast)
            values["provenance"] = out["provenance"]
        self._end(
            r,
            str(out["status"]),
            served=out.get("json") if out.get("packed") is not None else None,
            reason=out.get("reason"),
            message=out.get("message"),
            result_packed=out.get("packed"),
            **values,
        )

    def _kill(self, r: _Running) -> None:
        """SIGKILL the job's worker (the pool forks a fresh one in its place); at most once."""
        if not r.killed:
            r.killed = True
            self._pool.discard(r.worker)

    def _end(self, r: _Running, status: str, served: bytes | None = None, **values: Any) -> None:
        """Write the terminal state (only over this instance's ``running``: never over a cancellation).

        The slot is released first, so that whoever reads the terminal state also sees the slot free.
        ``served``: the result's JSON, kept (:mod:`api.results`) once the result is written, before the
        end listeners (long-polling readers) run.
        """
        with self._lock:
            self._running.pop(r.job_id, None)
        written = 0
        try:
            for attempt in range(END_WRITE_ATTEMPTS):
                try:
                    written = int(self.store.end(r.job_id, self.instance_id, status, **values))
                    break
                except Exception:  # a busy or dropped database: retry, then leave it to the lease expiry
                    if attempt == END_WRITE_ATTEMPTS - 1:
                        _LOG.exception("job %s: terminal state %s not written", r.job_id, status)
                    else:
                        time.sleep(0.5 * (attempt + 1))
        finally:
            if not r.killed and r.outcome is None:  # never left running without its job
                self._kill(r)
        if written:
            if served is not None:
                results.remember(r.job_id, served)
            reason = values.get("reason")
            self.metrics.job_outcomes.labels(status=status, reason=str(reason or "")).inc()
            self.metrics.job_duration.labels(status=status).observe(time.monotonic() - r.started)
        _LOG.info("job %s %s (%s)", r.job_id, status, values.get("reason"))
        self._wake.set()
        for listener in self._end_listeners:
            try:
                listener(r.job_id)
            except Exception:  # a listener's failure must not stop the dispatcher
                _LOG.exception("job %s: end listener failed", r.job_id)


__all__ = [
    "MAX_ATTEMPTS",
    "WARMUP_STAGE",
    "JobRunner",
    "ProcessJobRunner",
    "expire_leases",
    "purge_expired",
    "recover_jobs",
    "rows_matched",
]
