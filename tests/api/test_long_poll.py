"""Long polling: ``GET /plans/{id}?wait_s=`` answers when the job ends, not after a client's polling loop.

The waiting request is woken by the runner when the job ends (:class:`api.waiters.JobWaiters`), by a
cancellation of a queued job, and answers after ``wait_s`` (capped by ``job_wait_max_s``) with the job
still active; an unknown job is a 404 at once.
"""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from api.waiters import RECHECK_S, JobWaiters
from tests.api.conftest import make_settings, scenario, start_idle_service, start_service


def test_a_waiting_read_answers_when_the_plan_ends(tmp_path: Path) -> None:
    for svc in start_service(make_settings(tmp_path)):
        job = svc.client.post("/api/v1/plans", json=scenario("aisle-transfer"), headers=svc.h()).json()
        reads = 0
        t0 = time.monotonic()
        while True:  # one request, or a few while the workers warm up (each waits at most 30 s)
            doc = svc.client.get(f"/api/v1/plans/{job['id']}?wait_s=30", headers=svc.h()).json()
            reads += 1
            if doc["status"] not in ("queued", "running"):
                break
        waited = time.monotonic() - t0
        assert doc["status"] == "succeeded" and doc["result"]["status"] == "succeeded"
        assert reads <= 10 and waited < 250.0
        # the answer came when the plan ended: within a dispatcher pass of its finish, not at 30 s
        ended_at = doc["finished_at"]
        assert time.time() - ended_at < 5.0, "the waiting read answered long after the plan ended"
        # a finished plan is answered at once, whatever wait_s
        t = time.monotonic()
        again = svc.client.get(f"/api/v1/plans/{job['id']}?wait_s=30", headers=svc.h())
        assert again.status_code == 200 and time.monotonic() - t < 2.0
        assert again.json()["result"] == doc["result"]


def test_the_wait_ends_at_wait_s_at_the_ceiling_on_cancellation_and_at_once_for_unknown_jobs(
    tmp_path: Path,
) -> None:
    for svc in start_idle_service(make_settings(tmp_path, job_wait_max_s=1.0)):
        c, h = svc.client, svc.h()
        queued = c.post("/api/v1/plans", json=scenario("aisle-transfer"), headers=h).json()["id"]
        url = f"/api/v1/plans/{queued}"
        t = time.monotonic()
        doc = c.get(f"{url}?wait_s=0.4", headers=h).json()
        assert doc["status"] == "queued" and 0.4 <= time.monotonic() - t < 0.4 + 1.5
        t = time.monotonic()  # wait_s above the service's ceiling (1 s here): the ceiling
        doc = c.get(f"{url}?wait_s=60", headers=h).json()
        assert doc["status"] == "queued" and 1.0 <= time.monotonic() - t < 1.0 + 1.5
        t = time.monotonic()
        r = c.get("/api/v1/plans/no-such-plan?wait_s=60", headers=h)
        assert r.status_code == 404 and time.monotonic() - t < 1.0
        other = c.get(f"{url}?wait_s=60", headers=svc.h("beta"))  # another tenant's: 404 as without it
        assert other.status_code == 404
        for bad in ("-1", "61", "soon"):
            r = c.get(f"{url}?wait_s={bad}", headers=h)
            assert r.status_code == 422 and "wait_s" in r.text, bad

        # a cancellation wakes the waiting read before its wait ends
        got: dict[str, Any] = {}
        reader = threading.Thread(target=_timed_read, args=(c, f"{url}?wait_s=60", h, got))
        reader.start()
        time.sleep(0.3)
        assert c.delete(url, headers=h).status_code == 200
        reader.join(timeout=10)
        assert got["doc"]["status"] == "cancelled" and got["s"] < 0.9, got["s"]


def _timed_read(client: Any, url: str, headers: dict[str, str], got: dict[str, Any]) -> None:
    t0 = time.monotonic()
    got["doc"] = client.get(url, headers=headers).json()
    got["s"] = time.monotonic() - t0


def test_waiters_wake_on_notify_from_another_thread_and_release_on_close() -> None:
    async def scenario_run() -> None:
        waiters = JobWaiters()
        waiters.bind(asyncio.get_running_loop())
        state = {"status": "running", "reads": 0}

        async def read() -> str:
            state["reads"] += 1  # type: ignore[operator]
            return str(state["status"])

        def end_later() -> None:
            time.sleep(0.2)
            state["status"] = "succeeded"
            waiters.notify("j1")

        threading.Thread(target=end_later).start()
        t = time.monotonic()
        value = await waiters.until("j1", 30.0, read, lambda s: s != "running")
        assert value == "succeeded" and time.monotonic() - t < RECHECK_S
        assert waiters.waiting() == 0  # unregistered after the answer

        # without a notification (another instance ended it), the periodic re-read finds the end
        state["status"] = "running"
        loop = asyncio.get_running_loop()
        loop.call_later(0.1, lambda: state.update(status="failed"))
        t = time.monotonic()
        assert await waiters.until("j2", 30.0, read, lambda s: s != "running") == "failed"
        assert time.monotonic() - t < RECHECK_S + 0.5

        # closing (the server's exit signal) answers every waiting request now, and later ones at once
        state["status"] = "running"
        task = asyncio.create_task(waiters.until("j3", 30.0, read, lambda s: s != "running"))
        await asyncio.sleep(0.05)
        assert waiters.waiting() == 1
        waiters.close()
        assert await asyncio.wait_for(task, 1.0) == "running"
        t = time.monotonic()
        assert await waiters.until("j4", 30.0, read, lambda s: s != "running") == "running"
        assert time.monotonic() - t < 0.1

    asyncio.run(scenario_run())


@pytest.mark.parametrize(
    "path", ["/api/v1/plans/{id}", "/api/v1/cycles/{job_id}", "/api/v1/campaigns/{job_id}"]
)
def test_the_openapi_document_declares_wait_s(tmp_path: Path, path: str) -> None:
    for svc in start_idle_service(make_settings(tmp_path)):
        spec = svc.client.get("/openapi.json").json()
        key = path.replace("{id}", "{plan_id}")
        params = {p["name"]: p for p in spec["paths"][key]["get"]["parameters"]}
        schema = params["wait_s"]["schema"]
        assert params["wait_s"]["in"] == "query" and schema["minimum"] == 0 and schema["maximum"] == 60


def test_a_clean_shutdown_answers_the_waiting_reads_at_once(tmp_path: Path) -> None:
    """SIGTERM: uvicorn waits for open requests before it stops; a long poll must not hold it for wait_s."""
    import os
    import signal

    import httpx

    from tests.api.conftest import ADMIN_KEY, Server, stuck

    srv = Server(tmp_path / "data")
    srv.start(wait="health")  # jobs stay queued while the workers warm up; the stuck plan runs long after
    try:
        h = {"X-API-Key": ADMIN_KEY}
        key = httpx.post(f"{srv.url}/api/v1/keys", json={"tenant": "alpha"}, headers=h, timeout=30)
        h = {"X-API-Key": key.json()["key"]}
        job = httpx.post(f"{srv.url}/api/v1/plans", json=stuck(11, 20.0), headers=h, timeout=30).json()
        got: dict[str, Any] = {}
        reader = threading.Thread(
            target=_timed_read,
            args=(httpx.Client(timeout=60), f"{srv.url}/api/v1/plans/{job['id']}?wait_s=60", h, got),
        )
        reader.start()
        time.sleep(1.0)
        assert "doc" not in got  # still waiting: the plan is queued or running
        assert srv.proc is not None
        t = time.monotonic()
        os.kill(srv.proc.pid, signal.SIGTERM)
        reader.join(timeout=20)
        assert got["doc"]["status"] in ("queued", "running") and got["s"] < 1.0 + 5.0, got
        srv.proc.wait(timeout=30)
        assert time.monotonic() - t < 25.0  # not the 60 s the request asked to wait
    finally:
        srv.stop()
