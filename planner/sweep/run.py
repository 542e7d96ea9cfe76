"""Running a sweep: the executors (embedded process pool, Ray) and the driver that records the rows.

Both executors run :func:`planner.sweep.task.run_task` (a sweep's plan by default; a task may name another
runner, e.g. a campaign's cycle: :func:`~planner.sweep.task.task_runner`), one plan per task, with a hard
wall-clock limit per plan (``time_limit_s + limits.grace_s``, or ``limits.wall_time_limit_s`` when
smaller) counted from the moment the plan starts:

* :class:`EmbeddedExecutor` (default): plans run in warm worker processes on this machine (one per slot),
  forked from a forkserver that imported and warmed up the planner once. A worker past its plan's limit
  is killed (outcome ``time_limit_exceeded``) and replaced, the other plans go on: the isolation of the
  HTTP service's jobs (:mod:`api.jobs`) without paying a process start per plan.
* :class:`RayExecutor`: each plan is a Ray task (a streaming generator that first reports its start, then
  its outcome) on a local Ray started on demand (bound to 127.0.0.1) or on the cluster at ``address`` /
  ``RAY_ADDRESS``. At most ``max_in_flight`` tasks are submitted at a time; ``ray.wait`` with a timeout
  streams outcomes as they finish; a started task past its limit is killed with
  ``ray.cancel(force=True)``.

A task whose process died without an outcome (a killed Ray worker, a lost node, a crashed pool worker) is
submitted again, up to :data:`MAX_ATTEMPTS` times, then recorded as ``worker_crashed``; the journal keeps
one row per scenario hash, so no row is lost or duplicated.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import pickle
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

from planner.core.exceptions import InvalidInput
from planner.core.lifeline import SERVER_PID_ENV, die_with_parent
from planner.core.procpool import SINGLE_THREAD_ENV, WarmPool, Worker
from planner.sweep.expand import SweepPlan
from planner.sweep.results import Journal, TaskKey, make_row, write_tables
from planner.sweep.spec import Limits
from planner.sweep.task import run_task

_LOG = logging.getLogger(__name__)

#: Times a plan is submitted when its process dies without an outcome.
MAX_ATTEMPTS = 2

#: Longest time limit of the warm-up plan [s] (it only has to touch every kernel once).
WARMUP_TIME_LIMIT_S = 5.0


def hard_limit_s(plan: SweepPlan, limits: Limits) -> float:
    """Wall-clock limit of one plan process [s]: ``time_limit_s + grace_s``, at most ``wall_time_limit_s``."""
    limit = float(plan.scenario.options.time_limit_s) + float(limits.grace_s)
    if limits.wall_time_limit_s is not None:
        limit = min(limit, float(limits.wall_time_limit_s))
    return limit


#: The plan behind a job: a sweep's :class:`~planner.sweep.expand.SweepPlan`, a campaign's cycle, ...
PlanT = TypeVar("PlanT", bound=TaskKey)


@dataclass
class Job(Generic[PlanT]):
    """One submission of one plan (anything with a ``name`` and a ``sha256``: :class:`TaskKey`)."""

    plan: PlanT
    task: dict[str, Any]
    hard_limit_s: float
    attempt: int = 1
    submitted_at: float = 0.0
    started_at: float | None = None
    handle: Any = None
    #: Process id of the worker planning it, once known (Ray: reported at the task's start).
    pid: int | None = None


def _failed(reason: str, message: str) -> dict[str, Any]:
    return {"status": "failed", "reason": reason, "message": message, "document": None}


def killed_outcome(job: Job[Any]) -> dict[str, Any]:
    """Outcome of a plan killed at its hard limit."""
    return _failed(
        "time_limit_exceeded",
        f"the plan ran past its hard wall-clock limit of {job.hard_limit_s:.3g} s and was killed",
    )


#: Reason of an outcome that says the process died: the plan is tried again (see MAX_ATTEMPTS).
CRASHED = "worker_crashed"


class Executor(Protocol):
    """What the driver needs of an executor."""

    workers: int
    max_in_flight: int

    def submit(self, job: Job[Any]) -> None:
        """Start the job (sets ``job.handle``; ``job.started_at`` when known)."""

    def poll(self, jobs: Sequence[Job[Any]], timeout_s: float) -> list[tuple[Job[Any], dict[str, Any]]]:
        """Wait up to ``timeout_s`` for outcomes; the finished jobs (killed ones included)."""

    def close(self) -> None:
        """Stop every process this executor started."""


def _plan_and_send(task: dict[str, Any], conn: Connection) -> None:
    """An embedded worker's task: plan it, send the outcome (:class:`~planner.core.procpool.WarmPool`)."""
    conn.send(run_task(task))


#: Plans a reused embedded worker runs before it is replaced by a fresh one (bounds slow leaks).
DEFAULT_PLANS_PER_PROCESS = 200


class EmbeddedExecutor:
    """Plans in warm worker processes forked from a forkserver; one process per slot, hard-killed at a limit.

    The forkserver imports the planner and plans one warm-up plan before the first fork, so every worker
    starts with the imports, the compiled kernels and the cabin's clearance grid in place. A worker plans
    one task at a time and writes the plan's profile file itself (see :func:`plan_outcome`), then takes
    the next task: it is reused for up to ``plans_per_process`` plans, then replaced. Reuse keeps what a
    plan builds from content (parsed meshes, collision geometry: caches keyed by content hash) and never
    changes a result: each plan seeds its own random generators. The processes are a
    :class:`~planner.core.procpool.WarmPool`, as the HTTP service's job workers.

    Isolation is the service's: a worker whose plan runs past its hard limit is killed (SIGKILL) and its
    plan recorded ``time_limit_exceeded``; a worker that dies without an outcome has its plan submitted
    again (see :data:`MAX_ATTEMPTS`). Either way a replacement, forked ahead by a background thread,
    takes the slot; the other workers go on. ``plans_per_process=1`` gives a fresh process per plan.

    Args:
        workers: Plans running at the same time (one process each).
        warm_task: Task planned once in the forkserver before the first fork (e.g. the first plan).
        plans_per_process: Plans one worker runs before it exits (0: no limit; 1: a fresh process per
            plan, the strictest isolation, at a few hundred ms per plan).
    """

    #: The workers write each plan's profile file themselves (run_sweep passes ``profile_path``).
    writes_profiles = True

    def __init__(
        self,
        workers: int = 2,
        warm_task: dict[str, Any] | None = None,
        plans_per_process: int = DEFAULT_PLANS_PER_PROCESS,
    ) -> None:
        self.workers = int(workers)
        self.max_in_flight = self.workers
        self.plans_per_process = max(0, int(plans_per_process))
        #: Scenario hash -> process id of the worker planning it now.
        self.started: dict[str, int] = {}
        for name, value in SINGLE_THREAD_ENV.items():
            os.environ.setdefault(name, value)
        self._warm_file: str | None = None
        if warm_task is not None:
            # Pickled: a task names its runner by the function itself (pickled by reference).
            fd, self._warm_file = tempfile.mkstemp(prefix="cabinplan-sweep-warm-", suffix=".pkl")
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(warm_task, fh)
            # Read by planner.sweep._preload when the forkserver starts (the first plan process).
            os.environ["CABINPLAN_SWEEP_WARMUP"] = self._warm_file
        # The plan processes end with this process, even SIGKILLed (planner.core.lifeline): the forkserver
        # watches it (its pid inherited), each plan process arms its parent-death signal.
        os.environ[SERVER_PID_ENV] = str(os.getpid())
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["planner.sweep._preload"])
        self._pool = WarmPool(
            ctx,
            _plan_and_send,
            slots=self.workers,
            tasks_per_process=self.plans_per_process,
            setup=die_with_parent,
            setup_args=(os.getpid(),),
            name="cabinplan-sweep-plan",
        )
        self._running: dict[int, Worker] = {}
        self._pool.start()  # blocks until the forkserver has warmed up

    @property
    def _idle(self) -> list[Worker]:
        """The idle workers (tests read their pids)."""
        return self._pool.idle()

    def submit(self, job: Job[Any]) -> None:
        """Hand the plan to an idle worker (forked now if none waits)."""
        worker = self._pool.send(job.task)
        job.started_at = time.monotonic()
        job.handle = id(worker)
        job.pid = worker.pid
        self._running[id(worker)] = worker
        if job.pid is not None:
            self.started[job.plan.sha256] = job.pid

    def _release(self, job: Job[Any]) -> Worker:
        self.started.pop(job.plan.sha256, None)
        return self._running.pop(job.handle)

    def poll(self, jobs: Sequence[Job[Any]], timeout_s: float) -> list[tuple[Job[Any], dict[str, Any]]]:
        """Outcomes received within ``timeout_s``; workers dead without one; plans past their limit."""
        by_handle = {j.handle: j for j in jobs}
        workers = [self._running[h] for h in by_handle]
        now = time.monotonic()
        deadlines = [j.started_at + j.hard_limit_s - now for j in jobs if j.started_at is not None]
        handles: list[Any] = [w.conn for w in workers] + [w.process.sentinel for w in workers]
        wait(handles, timeout=max(0.0, min([timeout_s, *deadlines])))
        out = []
        for worker in workers:
            job = by_handle[id(worker)]
            outcome: dict[str, Any] | None = None
            try:
                if worker.conn.poll(0):
                    outcome = worker.conn.recv()
            except (EOFError, OSError):
                pass
            if outcome is not None:
                self._pool.release(self._release(job))
            elif not worker.process.is_alive():
                code = worker.process.exitcode
                self._pool.discard(self._release(job), died=True)
                outcome = _failed(CRASHED, f"the plan process died without an outcome (exit code {code})")
            elif time.monotonic() > (job.started_at or now) + job.hard_limit_s:
                self._pool.discard(self._release(job))
                outcome = killed_outcome(job)
            if outcome is not None:
                out.append((job, outcome))
        return out

    def close(self) -> None:
        """Kill every worker process."""
        self._running.clear()
        self._pool.close()
        if self._warm_file is not None:
            Path(self._warm_file).unlink(missing_ok=True)
            if os.environ.get("CABINPLAN_SWEEP_WARMUP") == self._warm_file:
                del os.environ["CABINPLAN_SWEEP_WARMUP"]


#: Read by Ray when it is imported. Off (its value here), Ray takes 127.0.0.1 as this node's address and
#: every server of a local Ray binds to loopback: GCS, raylet, object manager, the workers' and the
#: driver's gRPC servers, the dashboard and runtime-env agents (checked with ``ss -ltnup``, Ray 2.60).
#: Without it Ray replaces ``_node_ip_address="127.0.0.1"`` by the machine's address
#: (``ray._private.services.resolve_ip_for_localhost``) and binds its servers to all interfaces.
#: Meant for Windows and macOS; on Linux it only changes that address choice. Never set for a cluster.
RAY_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _ray(local: bool = False) -> Any:
    """Import Ray; ``local``: set :data:`RAY_LOOPBACK_ENV` first (a Ray started here binds loopback only)."""
    if local:
        os.environ.setdefault(RAY_LOOPBACK_ENV, "0")
    try:
        import ray
    except ImportError:
        raise InvalidInput(
            "--ray: Ray is not installed; install the extra: pip install 'cabinplan[ray]'", field="ray"
        ) from None
    return ray


def init_local_ray(num_cpus: int) -> Any:
    """Start a local Ray with ``num_cpus`` CPUs bound to loopback only (no dashboard); the ray module.

    Every server Ray starts listens on 127.0.0.1 (see :data:`RAY_LOOPBACK_ENV`); this needs the variable
    set before Ray is imported, so a process that imported Ray earlier gets a warning and Ray's default
    binding. Plan processes run single-threaded numerical libraries (:data:`SINGLE_THREAD_ENV`, inherited
    by the raylet's workers).
    """
    late = "ray" in sys.modules and os.environ.get(RAY_LOOPBACK_ENV) != "0"
    ray = _ray(local=True)
    if late:
        _LOG.warning("Ray was imported before %s=0: its servers bind to all interfaces", RAY_LOOPBACK_ENV)
    for name, value in SINGLE_THREAD_ENV.items():
        os.environ.setdefault(name, value)
    ray.init(
        num_cpus=int(num_cpus),
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        log_to_driver=False,
        configure_logging=False,
    )
    return ray


#: Set in a Ray worker once it has planned its warm-up task.
_WORKER_WARM = False


def _ray_plan(task: dict[str, Any], meshes: dict[str, Any] | None, warm: dict[str, Any] | None) -> Any:
    """The Ray task body: its process id once the worker is warm (the start), then the outcome.

    A fresh worker (the first task on it, or one started after a kill) first imports the planner and
    plans the warm-up task; the hard limit counts from the first item, so that cost is not charged to
    the plan.
    """
    global _WORKER_WARM
    if not _WORKER_WARM:
        from planner.sweep.task import warm_up

        warm_up(warm, meshes)
        _WORKER_WARM = True
    yield {"started": os.getpid()}
    yield run_task(task, meshes)


def _ray_warm(task: dict[str, Any] | None, meshes: dict[str, Any] | None) -> float:
    """Warm one Ray worker (import the planner, plan the warm-up plan once)."""
    global _WORKER_WARM
    from planner.sweep.task import warm_up

    seconds = warm_up(task, meshes)
    _WORKER_WARM = True
    return seconds


class RayExecutor:
    """Plans as Ray tasks (see the module docstring).

    Args:
        address: Cluster address (``ray://...`` or ``HOST:PORT``); default ``RAY_ADDRESS`` if set, else a
            local Ray with ``workers`` CPUs started now and bound to 127.0.0.1 (stopped by :meth:`close`).
        workers: CPUs of the local Ray (ignored on a cluster).
        max_in_flight: Most tasks submitted at a time; default the cluster's CPU count.
        meshes: Mesh name -> file bytes, put into the object store once and handed to every task.
        warm_task: Planned once in each worker before the sweep starts, and by any worker started later
            before its first plan.
    """

    def __init__(
        self,
        address: str | None = None,
        workers: int = 2,
        max_in_flight: int | None = None,
        meshes: dict[str, bytes] | None = None,
        warm_task: dict[str, Any] | None = None,
    ) -> None:
        address = address or os.environ.get("RAY_ADDRESS") or None
        ray = self._ray = _ray(local=address is None)
        self._owns = False
        if not ray.is_initialized():
            if address:
                ray.init(
                    address=address,
                    log_to_driver=False,
                    configure_logging=False,
                    runtime_env={"env_vars": dict(SINGLE_THREAD_ENV)},
                )
            else:
                init_local_ray(workers)
                self._owns = True
        cpus = int(ray.cluster_resources().get("CPU", workers))
        self.workers = max(1, cpus)
        self.max_in_flight = int(max_in_flight) if max_in_flight else self.workers
        #: Scenario hash -> worker process id of the plans running now (on their worker's node).
        self.started: dict[str, int] = {}
        self._plan = ray.remote(num_cpus=1, max_retries=0, num_returns="streaming")(_ray_plan)
        self._meshes = ray.put(meshes or {})
        self._warm_task = warm_task
        if warm_task is not None:
            warm = ray.remote(num_cpus=1, max_retries=0)(_ray_warm)
            ray.get([warm.remote(warm_task, self._meshes) for _ in range(self.workers)])

    def submit(self, job: Job[Any]) -> None:
        """Submit the plan task (its start is known once it reports it)."""
        job.handle = self._plan.remote(job.task, self._meshes, self._warm_task)
        job.started_at = None

    def _next(self, job: Job[Any]) -> tuple[str, Any]:
        """('started', pid) | ('outcome', dict) | ('crashed', message) of a ready generator."""
        ray = self._ray
        try:
            ref = next(job.handle)
            item = ray.get(ref)
        except StopIteration:
            return "crashed", "the task ended without an outcome"
        except ray.exceptions.TaskCancelledError:
            return "crashed", "the task was cancelled"
        except ray.exceptions.RayTaskError as exc:  # the task body raised (never by design)
            return "outcome", _failed("internal_error", f"the plan task failed: {exc}")
        except ray.exceptions.RayError as exc:  # the worker or its node died
            return "crashed", f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        if isinstance(item, dict) and "started" in item:
            return "started", item["started"]
        return "outcome", item

    def poll(self, jobs: Sequence[Job[Any]], timeout_s: float) -> list[tuple[Job[Any], dict[str, Any]]]:
        """Wait for the next task events; kill started tasks past their hard limit."""
        ray = self._ray
        by_ref = {j.handle: j for j in jobs}
        now = time.monotonic()
        deadlines = [j.started_at + j.hard_limit_s - now for j in jobs if j.started_at is not None]
        wait_s = max(0.0, min([timeout_s, *deadlines]))
        ready, rest = ray.wait(list(by_ref), num_returns=1, timeout=wait_s)
        if rest and ready:
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        out = []
        for ref in ready:
            job = by_ref[ref]
            kind, value = self._next(job)
            if kind == "started":
                job.started_at = time.monotonic()
                job.pid = int(value)
                self.started[job.plan.sha256] = job.pid
                continue
            self.started.pop(job.plan.sha256, None)
            if kind == "crashed":
                value = _failed(CRASHED, f"the plan's Ray worker died without an outcome ({value})")
            out.append((job, value))
        finished = {id(j) for j, _ in out}
        now = time.monotonic()
        for job in jobs:
            if id(job) in finished or job.started_at is None:
                continue
            if now > job.started_at + job.hard_limit_s:
                ray.cancel(job.handle, force=True)
                self.started.pop(job.plan.sha256, None)
                out.append((job, killed_outcome(job)))
        return out

    def close(self) -> None:
        """Shut down the local Ray this executor started (a cluster is left running)."""
        if self._owns:
            self._ray.shutdown()


@dataclass
class Counts:
    """Progress of a sweep run."""

    total: int
    skipped: int = 0
    succeeded: int = 0
    failed: int = 0
    running: int = 0
    retried: int = 0
    reasons: dict[str, int] = field(default_factory=dict)

    @property
    def done(self) -> int:
        """Plans with a row (skipped ones included)."""
        return self.skipped + self.succeeded + self.failed


Progress = Callable[[Counts], None]


def _task(plan: SweepPlan, base_dir: Path | None) -> dict[str, Any]:
    return {
        "scenario": plan.scenario.model_dump(mode="json"),
        "base_dir": str(base_dir) if base_dir else None,
    }


def sweep_meshes(plans: Sequence[SweepPlan]) -> dict[str, bytes]:
    """Bytes of every mesh file the plans name (not the packaged reference cabins), read once.

    Handed to Ray tasks through the object store, so that the nodes of a cluster need the package but
    no copy of the sweep's mesh files.
    """
    from planner.meshes import reference_cabin_path

    out: dict[str, bytes] = {}
    for plan in plans:
        names = []
        s = plan.scenario
        if s.cabin is not None and reference_cabin_path(s.cabin.mesh) is None:
            names.append(s.cabin.mesh)
        if s.payload is not None and s.payload.mesh is not None:
            names.append(s.payload.mesh)
        for name in names:
            if name not in out:
                try:
                    out[name] = Path(name).read_bytes()
                except OSError as exc:
                    raise InvalidInput(
                        f"mesh {name}: cannot read ({exc.strerror})", field="cabin.mesh"
                    ) from None
    return out


def warm_task(plans: Sequence[SweepPlan], base_dir: Path | None = None) -> dict[str, Any] | None:
    """The warm-up task of a sweep: its first plan with the time limit capped at WARMUP_TIME_LIMIT_S."""
    if not plans:
        return None
    task = _task(plans[0], base_dir)
    options = task["scenario"].setdefault("options", {})
    options["time_limit_s"] = min(float(options.get("time_limit_s", 30.0)), WARMUP_TIME_LIMIT_S)
    return task


class InlineExecutor:
    """Plans in this process, one at a time, when polled (no isolation, no hard limit).

    For tests and small in-process runs (a campaign's tests count the cabin's cache builds across its
    cycles, which only an in-process run can see). A plan is never killed: ``hard_limit_s`` is not
    enforced, so use the process executors wherever a plan may hang.
    """

    writes_profiles = True
    workers = 1
    max_in_flight = 1

    def __init__(self, meshes: dict[str, Any] | None = None) -> None:
        self._meshes = meshes
        #: Tasks this executor ran, in order (tests read it).
        self.ran: list[dict[str, Any]] = []

    def submit(self, job: Job[Any]) -> None:
        """Queue the job (it runs at the next :meth:`poll`)."""
        job.handle = job
        job.started_at = time.monotonic()
        job.pid = os.getpid()

    def poll(self, jobs: Sequence[Job[Any]], timeout_s: float) -> list[tuple[Job[Any], dict[str, Any]]]:
        """Run the first submitted job now; its outcome."""
        if not jobs:
            return []
        job = jobs[0]
        job.started_at = time.monotonic()
        self.ran.append(job.task)
        return [(job, run_task(job.task, self._meshes))]

    def close(self) -> None:
        """Nothing to stop."""


#: Called with each finished job, its outcome and its wall time [s]; it may append jobs to ``pending``.
Finished = Callable[[Job[PlanT], dict[str, Any], float], None]


def drive(
    pending: deque[Job[PlanT]],
    executor: Executor,
    finished: Finished[PlanT],
    *,
    running_changed: Callable[[int], None] | None = None,
    poll_s: float = 0.2,
) -> int:
    """Run jobs on an executor until none is pending or running; every outcome goes to ``finished``.

    The one loop of every driver (a sweep's rows, a campaign's cycles): at most ``executor.max_in_flight``
    jobs are submitted at a time; a job whose process died without an outcome (:data:`CRASHED`) is
    submitted again, up to :data:`MAX_ATTEMPTS` times, before its crash is its outcome. ``finished`` may
    append new jobs to ``pending`` (a search deciding what to plan next from what it learned) or clear it
    (a campaign stopping at its first failure; jobs already running still finish and are reported).

    Returns:
        How many jobs were submitted again after a crash.
    """
    running: list[Job[PlanT]] = []
    retried = 0
    changed = running_changed or (lambda n: None)
    while pending or running:
        while pending and len(running) < executor.max_in_flight:
            job = pending.popleft()
            job.submitted_at = time.monotonic()
            executor.submit(job)
            running.append(job)
        changed(len(running))
        for job, outcome in executor.poll(running, poll_s):
            running.remove(job)
            if outcome.get("reason") == CRASHED and job.attempt < MAX_ATTEMPTS:
                _LOG.warning("plan %s: %s; submitted again", job.plan.name, outcome.get("message"))
                retried += 1
                pending.appendleft(Job(job.plan, job.task, job.hard_limit_s, job.attempt + 1))
                continue
            start = job.started_at if job.started_at is not None else job.submitted_at
            finished(job, outcome, time.monotonic() - start)
        changed(len(running))
    return retried


def run_sweep(
    plans: Sequence[SweepPlan],
    out_dir: Path,
    executor: Executor,
    limits: Limits,
    *,
    base_dir: Path | None = None,
    progress: Progress | None = None,
    poll_s: float = 0.2,
) -> Counts:
    """Run every plan without a row in ``out_dir`` and record the rows as they finish.

    Args:
        plans: The expanded sweep.
        out_dir: Output folder (journal, tables, scenario and profile files).
        executor: Where plans run; the caller closes it.
        limits: Wall-clock limits of each plan.
        base_dir: Folder that relative mesh paths in the scenarios refer to.
        progress: Called with the counts whenever they change.
        poll_s: Longest wait for outcomes before the progress is refreshed [s].

    Returns:
        The final counts. The tables (CSV, Parquet) are written at the end, also when interrupted.
    """
    journal = Journal(out_dir)
    counts = Counts(total=len(plans))
    pending: deque[Job[SweepPlan]] = deque()
    for plan in plans:
        journal.write_scenario(plan)
        if journal.done(plan.sha256):
            counts.skipped += 1
        else:
            task = _task(plan, base_dir)
            if getattr(executor, "writes_profiles", False):
                task["profile_path"] = str(journal.profile_path(plan))
            pending.append(Job(plan, task, hard_limit_s(plan, limits)))
    report = progress or (lambda c: None)
    report(counts)

    def finished(job: Job[SweepPlan], outcome: dict[str, Any], wall_time_s: float) -> None:
        row = make_row(job.plan, outcome, wall_time_s, job.attempt)
        if journal.record(job.plan, row, outcome.get("document")):
            if row["status"] == "succeeded":
                counts.succeeded += 1
            else:
                counts.failed += 1
            reason = row["reason"] or "succeeded"
            counts.reasons[reason] = counts.reasons.get(reason, 0) + 1

    def running_changed(n: int) -> None:
        counts.running = n
        report(counts)

    try:
        counts.retried += drive(pending, executor, finished, running_changed=running_changed, poll_s=poll_s)
    finally:
        write_tables(out_dir, journal.table(plans))
    return counts


__all__ = [
    "CRASHED",
    "DEFAULT_PLANS_PER_PROCESS",
    "MAX_ATTEMPTS",
    "RAY_LOOPBACK_ENV",
    "Counts",
    "EmbeddedExecutor",
    "Executor",
    "Finished",
    "InlineExecutor",
    "Job",
    "RayExecutor",
    "TaskKey",
    "drive",
    "hard_limit_s",
    "init_local_ray",
    "killed_outcome",
    "run_sweep",
    "sweep_meshes",
    "warm_task",
]
