"""Long polling: requests that wait for a job to end (``GET /plans/{id}?wait_s=``), woken when it does.

A client that wants a job's outcome asks for its document with ``wait_s``: the answer comes as soon as
the job ends (or after ``wait_s`` with the job still active), instead of the client polling every few
hundred milliseconds -- each poll a request the server parses, authenticates and answers while the job
workers want the same CPU. The job runner calls :meth:`JobWaiters.notify` (from its own thread) when a
job of this instance ends, and so does a cancellation of a queued job; a waiting request also re-reads
its job every :data:`RECHECK_S`, for jobs that end on another instance sharing the database.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable
from typing import TypeVar

#: A waiting request re-reads its job at least this often [s] (jobs ending on another instance).
RECHECK_S = 1.0

T = TypeVar("T")


class JobWaiters:
    """Requests waiting on jobs, by job id; woken from any thread (see the module docstring)."""

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._events: dict[str, set[asyncio.Event]] = {}
        self._lock = threading.Lock()
        self._closing = False

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """The event loop the waiting requests run on (the app's lifespan binds it)."""
        self._loop = loop

    def notify(self, job_id: str) -> None:
        """Job ``job_id`` ended (or changed state): wake the requests waiting on it. Any thread."""
        with self._lock:
            waiting = bool(self._events.get(job_id))
        if waiting:
            self._on_loop(self._set, job_id)

    def close(self) -> None:
        """The service is shutting down: every waiting request answers now, and later ones do not wait.

        Called from the server's exit handler (a signal handler: any thread, any moment), so that a
        graceful shutdown does not wait out the long polls; the events are set on the loop's own thread.
        """
        self._closing = True
        if self._loop is None:  # never bound: no loop thread to hand it to
            self._release_all()
        else:
            self._on_loop(self._release_all)

    def _on_loop(self, fn: Callable[..., None], *args: str) -> None:
        """Run ``fn(*args)`` on the bound loop's thread (waking its select); nothing once it is closed."""
        loop = self._loop
        if loop is None or loop.is_closed():  # no loop, or it is gone (shutdown): nobody waits any more
            return
        try:
            loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:  # the loop closed in between
            pass

    def _release_all(self) -> None:
        with self._lock:
            events = [e for es in self._events.values() for e in es]
        for event in events:
            event.set()

    def _set(self, job_id: str) -> None:
        with self._lock:
            events = list(self._events.get(job_id, ()))
        for event in events:
            event.set()

    async def until(
        self, job_id: str, wait_s: float, read: Callable[[], Awaitable[T]], done: Callable[[T], bool]
    ) -> T:
        """``read()`` again each time job ``job_id`` may have changed, until ``done`` or ``wait_s`` passed.

        The waiter is registered before the first read, so an end between that read and the wait is not
        missed. Returns the last value read (``done`` or not: the caller answers with it either way).
        """
        loop = asyncio.get_running_loop()
        deadline = loop.time() + max(0.0, wait_s)
        event = asyncio.Event()
        with self._lock:
            self._events.setdefault(job_id, set()).add(event)
        try:
            while True:
                event.clear()
                value = await read()
                left = deadline - loop.time()
                if done(value) or left <= 0.0 or self._closing:
                    return value
                try:
                    await asyncio.wait_for(event.wait(), timeout=min(left, RECHECK_S))
                except TimeoutError:
                    pass
        finally:
            with self._lock:
                events = self._events.get(job_id)
                if events is not None:
                    events.discard(event)
                    if not events:
                        del self._events[job_id]

    def waiting(self) -> int:
        """Requests waiting now (metrics, tests)."""
        with self._lock:
            return sum(len(e) for e in self._events.values())


__all__ = ["RECHECK_S", "JobWaiters"]
