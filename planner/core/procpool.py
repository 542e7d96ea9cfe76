"""Warm, reused worker processes: a pool of forked processes that each serve tasks from a pipe.

One mechanism for every executor that runs planning work in processes of its own (a sweep's plans,
:class:`planner.sweep.run.EmbeddedExecutor`; the HTTP service's jobs, :mod:`api.jobs`):

* workers are forked from a multiprocessing context (a forkserver that imported and warmed up the
  planner once), so each starts with the imports, the compiled kernels and the warm-up cabin's collision
  geometry in place; a worker then keeps what it builds from content (parsed meshes, a cabin's BVH and
  clearance grid: caches keyed by the mesh's content hash) for its next tasks;
* a worker runs one task at a time (:func:`serve`) and is reused for up to ``tasks_per_process`` tasks,
  and only while its resident memory stays under ``max_rss_bytes`` (:meth:`WarmPool.release`): then it
  is retired and a fresh one takes its place, so a slow leak or a cache that grows with every new cabin
  never grows without bound;
* a worker whose task must stop (past its hard limit, cancelled) is killed with SIGKILL
  (:meth:`WarmPool.discard`) and one that died by itself is reaped the same way; a background thread
  keeps ``slots + spare`` processes forked (idle ones waiting), so a killed worker is replaced at once
  and the other workers go on.

The pool owns no task semantics: what a task is, what the worker sends back and when a task has
finished are the caller's (the worker's ``handle`` function and the caller's reading of the pipe).
"""

from __future__ import annotations

import logging
import os
import sys
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from typing import Any

_LOG = logging.getLogger(__name__)

#: Thread pools of numerical libraries in each worker: one thread (a task is one core's work, and a
#: forked child must not inherit a thread pool its parent started).
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}

#: ``handle(task, conn)``: run one task in the worker and send its messages (its outcome last) on ``conn``;
#: a module-level function (pickled by reference: the worker imports its module, so a module whose
#: heavy imports sit inside its functions keeps the pool's owner light).
Handler = Callable[[Any, Connection], None]


def serve(
    conn: Connection,
    handle: Handler,
    tasks: int,
    setup: Callable[..., None] | None = None,
    setup_args: tuple[Any, ...] = (),
) -> None:
    """Body of a worker process: ``setup(*setup_args)`` once, then ``handle`` each task received.

    Ends after ``tasks`` tasks (0: no limit), on a ``None`` task (retired) or when the pipe closes (the
    pool closed, or its owner died).
    """
    if setup is not None:
        setup(*setup_args)
    done = 0
    while tasks <= 0 or done < tasks:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        handle(task, conn)
        done += 1
    conn.close()


def rss_bytes(pid: int | None) -> int | None:
    """Resident set size of process ``pid`` [bytes] (``VmRSS`` of ``/proc/<pid>/status``); None if unknown.

    Linux only: elsewhere (or for a process that is gone) ``None``, and a pool then recycles by task
    count alone.
    """
    if pid is None or not sys.platform.startswith("linux"):
        return None
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


@dataclass
class Worker:
    """One worker process of a :class:`WarmPool` and the parent's end of its pipe."""

    process: BaseProcess
    conn: Connection
    #: Tasks this worker may still take (``None``: no limit).
    remaining: int | None
    #: Tasks handed to it so far.
    served: int = 0

    @property
    def pid(self) -> int | None:
        """Its process id."""
        return self.process.pid


class WarmPool:
    """Warm worker processes, reused for up to ``tasks_per_process`` tasks (see the module docstring).

    Args:
        ctx: Multiprocessing context the workers are forked from (a forkserver context, preloaded).
        handle: What a worker runs for each task (:data:`Handler`).
        slots: Tasks running at the same time.
        tasks_per_process: Tasks one worker runs before it is replaced (0: no limit; 1: a fresh process
            per task, no reuse).
        max_rss_bytes: A worker whose resident memory exceeds this after a task is retired (``None``: no
            bound).
        setup: Run once in each worker before its first task (arm a parent-death signal, renice); a
            module-level function or its name, as ``handle``.
        setup_args: Its arguments (picklable).
        name: Process name of the workers.
        on_retire: Called with the cause each time a worker is retired (``tasks``, ``rss``, ``killed``,
            ``died``; a metrics counter).
    """

    def __init__(
        self,
        ctx: BaseContext,
        handle: Handler,
        *,
        slots: int,
        tasks_per_process: int,
        max_rss_bytes: int | None = None,
        setup: Callable[..., None] | None = None,
        setup_args: tuple[Any, ...] = (),
        name: str = "cabinplan-worker",
        on_retire: Callable[[str], None] | None = None,
    ) -> None:
        self.ctx = ctx
        self.handle = handle
        self.slots = int(slots)
        self.tasks_per_process = max(0, int(tasks_per_process))
        self.max_rss_bytes = max_rss_bytes
        self.setup = setup
        self.setup_args = setup_args
        self.name = name
        self.on_retire = on_retire
        #: Workers retired so far, by cause: ``tasks`` (used up), ``rss`` (memory), ``killed``, ``died``.
        self.retired: dict[str, int] = {"tasks": 0, "rss": 0, "killed": 0, "died": 0}
        self._idle: deque[Worker] = deque()
        self._busy: dict[int, Worker] = {}
        self._lock = threading.Lock()
        self._want = threading.Event()
        self._stopping = threading.Event()
        self._filler: threading.Thread | None = None

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Fork the idle workers now (blocks until the context's forkserver has warmed up), then keep them."""
        for name, value in SINGLE_THREAD_ENV.items():
            os.environ.setdefault(name, value)
        self._stopping.clear()
        with self._lock:
            n = self._target()
        for _ in range(n):
            worker = self._fork()
            with self._lock:
                self._idle.append(worker)
        self._filler = threading.Thread(target=self._fill, name=f"{self.name}-fork", daemon=True)
        self._filler.start()

    def close(self) -> None:
        """Kill every worker, idle and busy."""
        self._stopping.set()
        self._want.set()
        if self._filler is not None:
            self._filler.join(timeout=10.0)
        with self._lock:
            workers = [*self._busy.values(), *self._idle]
            self._busy.clear()
            self._idle.clear()
        for w in workers:
            if w.process.is_alive():
                w.process.kill()
        for w in workers:
            self._reap(w)

    # ------------------------------------------------------------------ tasks
    def take(self) -> Worker:
        """A warm idle worker for the next task (the most recently used first; forked now if none waits)."""
        with self._lock:
            worker = self._idle.popleft() if self._idle else None
        if worker is None:
            worker = self._fork()
        with self._lock:
            self._busy[id(worker)] = worker
        self._want.set()
        return worker

    def send(self, task: Any) -> Worker:
        """Hand ``task`` to an idle worker; a worker that died while idle is reaped and another one used.

        Raises:
            OSError: no worker could take it (a fresh one failed too).
        """
        worker = self.take()
        try:
            worker.conn.send(task)
        except (BrokenPipeError, OSError):
            self.discard(worker, died=True)
            worker = self.take()
            worker.conn.send(task)  # a fresh process: an error here is the caller's to report
        worker.served += 1
        if worker.remaining is not None:
            worker.remaining -= 1
        return worker

    def release(self, worker: Worker) -> bool:
        """The worker's task finished: keep it for the next one, or retire it; True when it is kept.

        Retired (killed: it is idle, its task's messages all read): its task budget is spent or its
        resident memory is over ``max_rss_bytes``.
        """
        why = None
        if not worker.process.is_alive():  # it died after its outcome was sent
            why = "died"
        elif worker.remaining is not None and worker.remaining <= 0:
            why = "tasks"
        elif self.max_rss_bytes is not None:
            rss = rss_bytes(worker.pid)
            if rss is not None and rss > self.max_rss_bytes:
                _LOG.info("worker %s retired: resident memory %.0f MB", worker.pid, rss / 1e6)
                why = "rss"
        with self._lock:
            self._busy.pop(id(worker), None)
            keep = why is None and not self._stopping.is_set()
            if keep:
                self._idle.appendleft(worker)  # warm: reused first
        self._want.set()
        if not keep:
            worker.process.kill()
            if why is None:
                self._reap(worker)
            else:
                self._retire(worker, why)
        return keep

    def discard(self, worker: Worker, *, died: bool = False) -> None:
        """Kill the worker (SIGKILL; a running task stops there) and reap it; a fresh one takes its slot."""
        with self._lock:
            self._busy.pop(id(worker), None)
        self._want.set()
        try:
            if worker.process.is_alive():
                worker.process.kill()
        except ValueError:  # already closed
            pass
        self._retire(worker, "died" if died else "killed")

    def idle(self) -> list[Worker]:
        """The idle workers now (most recently used first)."""
        with self._lock:
            return list(self._idle)

    # ------------------------------------------------------------------ internals
    def _target(self) -> int:
        """Processes to keep idle (call with the lock held).

        Without reuse a fresh one per slot; with reuse one per slot in all (busy ones included) plus one
        spare, so that a killed worker is replaced at once.
        """
        if self.tasks_per_process == 1:
            return self.slots
        return max(1, self.slots + 1 - len(self._busy))

    def _fork(self) -> Worker:
        parent, child = self.ctx.Pipe(duplex=True)
        proc = self.ctx.Process(  # type: ignore[attr-defined]
            target=serve,
            args=(child, self.handle, self.tasks_per_process, self.setup, self.setup_args),
            name=self.name,
            daemon=True,
        )
        try:
            proc.start()
        finally:
            child.close()
        return Worker(proc, parent, self.tasks_per_process or None)

    def _fill(self) -> None:
        """Background thread: keep :meth:`_target` processes forked and waiting."""
        while not self._stopping.is_set():
            self._want.wait(0.5)
            self._want.clear()
            while not self._stopping.is_set():
                with self._lock:
                    enough = len(self._idle) >= self._target()
                if enough:
                    break
                try:
                    worker = self._fork()
                except Exception:  # the forkserver is gone (shutting down): try again later
                    _LOG.exception("could not fork a spare worker")
                    break
                with self._lock:
                    stopping = self._stopping.is_set()
                    if not stopping:
                        self._idle.append(worker)
                if stopping:
                    worker.process.kill()
                    self._reap(worker)

    def _retire(self, worker: Worker, why: str) -> None:
        self.retired[why] = self.retired.get(why, 0) + 1
        self._reap(worker)
        if self.on_retire is not None:
            self.on_retire(why)

    @staticmethod
    def _reap(worker: Worker) -> None:
        try:
            worker.process.join(timeout=5.0)
        except ValueError:  # already closed
            pass
        worker.conn.close()
        try:
            worker.process.close()
        except ValueError:  # still running after the join's timeout: left to the daemon clean-up
            pass


__all__ = ["SINGLE_THREAD_ENV", "Handler", "WarmPool", "Worker", "rss_bytes", "serve"]
