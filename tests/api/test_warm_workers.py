"""Warm, reused job workers: reuse gives the fresh process's results, recycling, kills replace the worker.

One service with a single worker slot (so consecutive jobs meet the same worker) that recycles a worker
after three jobs, and no grace (a job's hard limit is its ``time_limit_s``); the pool itself
(:class:`planner.core.procpool.WarmPool`) with a worker that leaks memory on purpose.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Iterator
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from api.jobs import ProcessJobRunner
from planner.core.procpool import WarmPool, rss_bytes
from tests.api.conftest import Service, free_transfer, make_settings, scenario, start_service, stuck, wait_for

MAX_JOBS = 3


@pytest.fixture(scope="module")
def one(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    settings = make_settings(
        tmp_path_factory.mktemp("warm"), workers=1, worker_max_jobs=MAX_JOBS, job_grace_s=0.0
    )
    yield from start_service(settings)


def _runner(svc: Service) -> ProcessJobRunner:
    runner = svc.client.app.state.ctx.runner  # type: ignore[attr-defined]
    assert isinstance(runner, ProcessJobRunner)
    return runner


def _gone(pid: int) -> bool:
    status = Path(f"/proc/{pid}/status")
    return not status.exists() or "zombie" in status.read_text()


def _run(svc: Service, body: dict[str, Any], timeout_s: float = 240.0) -> dict[str, Any]:
    r = svc.client.post("/api/v1/plans", json=body, headers=svc.h())
    assert r.status_code == 202, r.text
    return wait_for(svc.client, svc.h(), r.json()["id"], timeout_s=timeout_s)


def _same_plan(a: dict[str, Any], b: dict[str, Any]) -> None:
    """Two result documents describe the same motion, sample for sample (bit for bit)."""
    ra, rb = a["result"], b["result"]
    for key in ("t", "position", "velocity", "acceleration", "effort", "joints"):
        assert np.array_equal(np.asarray(ra[key]), np.asarray(rb[key])), key
    assert ra["duration_s"] == rb["duration_s"]
    assert ra["min_clearance_m"] == rb["min_clearance_m"]


def test_a_worker_is_reused_plans_what_a_fresh_one_plans_and_is_recycled_after_its_jobs(one: Service) -> None:
    """Jobs 1-3 run in one process; the third (a reused worker, after another cabin) equals the first.

    The hatch pass plans in the hatch cabin (not the forkserver's warm-up cabin): the first job builds
    its collision geometry, the third reuses it; the plan must not change by a bit. The fourth job runs
    in a fresh worker: the first was retired after its three jobs and its process is gone.
    """
    runner = _runner(one)
    hatch = scenario("hatch-pass")
    docs, ran = [], []
    for body in (hatch, free_transfer(d1_goal=1.3), hatch, free_transfer(d1_goal=1.4)):
        doc = _run(one, body)
        assert doc["status"] == "succeeded", doc
        assert doc["result"]["report"]["gate"]["passed"] is True
        docs.append(doc)
        ran.append(runner.ran_on[doc["id"]])
    (pid, nth), second, third, fourth = ran
    assert nth == 1 and second == (pid, 2) and third == (pid, 3)  # one process, its 1st to 3rd job
    _same_plan(docs[0], docs[2])  # a fresh worker's plan and a reused worker's plan: identical
    assert fourth[0] != pid and fourth[1] == 1  # recycled: a fresh worker took the fourth job
    assert _gone(pid)
    assert _runner(one)._pool.retired["tasks"] >= 1
    metrics = one.client.get("/metrics").text
    assert 'cabinplan_job_workers_replaced_total{cause="tasks"} 1.0' in metrics


def _started(svc: Service, runner: ProcessJobRunner, body: dict[str, Any]) -> tuple[str, int]:
    """Submit ``body``; its id and its worker's pid once a worker has it."""
    job_id = svc.client.post("/api/v1/plans", json=body, headers=svc.h()).json()["id"]
    deadline = time.monotonic() + 60
    while job_id not in runner.ran_on and time.monotonic() < deadline:
        time.sleep(0.02)
    return job_id, runner.ran_on[job_id][0]


def test_a_job_past_its_hard_limit_kills_its_worker_and_a_fresh_one_runs_the_next(one: Service) -> None:
    """A worker that hangs (stopped: it never reaches the planner's own time check) is killed at the limit."""
    runner = _runner(one)
    job_id, pid = _started(one, runner, stuck(11, time_limit_s=3.0))
    os.kill(pid, signal.SIGSTOP)  # hung in native code, say: only the hard limit ends it
    killed = wait_for(one.client, one.h(), job_id, timeout_s=60)
    assert killed["status"] == "failed" and killed["reason"] == "time_limit_exceeded", killed
    assert 3.0 <= killed["finished_at"] - killed["started_at"] < 3.0 + 2.0
    assert _gone(pid)  # SIGKILLed and reaped
    nxt = _run(one, free_transfer(d1_goal=1.2))
    assert nxt["status"] == "succeeded", nxt
    assert runner.ran_on[nxt["id"]][0] != pid


def test_cancel_kills_the_running_jobs_worker_and_a_fresh_one_runs_the_next(one: Service) -> None:
    runner = _runner(one)
    job_id, pid = _started(one, runner, stuck(12, time_limit_s=30.0))
    doc = one.client.delete(f"/api/v1/plans/{job_id}", headers=one.h()).json()
    assert doc["status"] == "cancelled", doc
    deadline = time.monotonic() + 10
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)
    nxt = _run(one, free_transfer(d1_goal=1.25))
    assert nxt["status"] == "succeeded" and runner.ran_on[nxt["id"]][0] != pid, nxt


def test_a_worker_that_dies_fails_only_its_job(one: Service) -> None:
    runner = _runner(one)
    job_id, pid = _started(one, runner, stuck(13, time_limit_s=30.0))
    os.kill(pid, signal.SIGKILL)  # a crash (the OOM killer, a segfault in a native library)
    doc = wait_for(one.client, one.h(), job_id, timeout_s=30)
    assert doc["status"] == "failed" and doc["reason"] == "worker_crashed", doc
    nxt = _run(one, free_transfer(d1_goal=1.35))
    assert nxt["status"] == "succeeded" and runner.ran_on[nxt["id"]][0] != pid, nxt


# ----------------------------------------------------------------- the pool, with a leaking worker
_LEAK: list[bytes] = []


def _leak(mb: int, conn: Connection) -> None:
    """A task that keeps ``mb`` MB alive in the worker (touched, so resident); sends its pid and RSS."""
    _LEAK.append(os.urandom(mb << 20))
    conn.send((os.getpid(), rss_bytes(os.getpid())))


def _pool(**kwargs: Any) -> WarmPool:
    return WarmPool(multiprocessing.get_context("forkserver"), _leak, slots=1, name="test-leak", **kwargs)


def test_a_worker_whose_memory_grows_past_the_bound_is_replaced_by_a_fresh_one() -> None:
    """A worker that keeps 40 MB per task: retired once its resident set passes base + 100 MB."""
    probe = _pool(tasks_per_process=0)
    probe.start()
    try:
        w = probe.send(0)
        _, base = w.conn.recv()
        probe.release(w)
    finally:
        probe.close()
    assert base is not None
    pool = _pool(tasks_per_process=0, max_rss_bytes=base + (100 << 20))
    pool.start()
    try:
        seen = []
        for _ in range(5):
            w = pool.send(40)
            pid, rss = w.conn.recv()
            kept = pool.release(w)
            seen.append((pid, rss, kept))
        # 40, 80 MB kept: reused; 120 MB: over the bound, retired; the next task starts afresh
        assert [k for _, _, k in seen] == [True, True, False, True, True], seen
        assert len({p for p, _, _ in seen[:3]}) == 1 and seen[3][0] != seen[0][0]
        assert seen[3][1] < seen[2][1] - (60 << 20)  # the fresh worker holds none of the leak
        assert pool.retired["rss"] == 1 and _gone(seen[0][0])
    finally:
        pool.close()
    assert all(_gone(p) for p, _, _ in seen)


def test_tasks_per_process_of_one_gives_a_fresh_process_per_task() -> None:
    pool = _pool(tasks_per_process=1)
    pool.start()
    try:
        pids = []
        for _ in range(3):
            w = pool.send(0)
            pids.append(w.conn.recv()[0])
            assert pool.release(w) is False
        assert len(set(pids)) == 3 and pool.retired["tasks"] == 3
    finally:
        pool.close()
