"""Nothing submitted is lost: SIGKILL the real server (uvicorn subprocess) mid-run, restart, all finish."""

from __future__ import annotations

import sqlite3
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.db import Database, Job, now_s
from api.jobs import MAX_ATTEMPTS, recover_jobs
from tests.api.conftest import Server, free_transfer, scenario

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Server]:
    srv = Server(tmp_path / "data", CABINPLAN_JOB_LEASE_S="3")
    yield srv
    srv.stop()


def _poll(
    url: str, headers: dict[str, str], job_id: str, until: set[str], timeout_s: float
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        doc: dict[str, Any] = httpx.get(f"{url}/api/v1/plans/{job_id}", headers=headers, timeout=10).json()
        if doc["status"] in until or time.monotonic() > deadline:
            return doc
        time.sleep(0.1)


def test_sigkill_mid_run_then_restart_loses_nothing(server: Server) -> None:
    server.start()
    key = (server.data_dir / "local-api-key").read_text().strip()
    assert key in server.log.read_text()  # the local default key is printed at start-up
    h = {"X-API-Key": key}
    # The hatch pass without the transit posture (plain OMPL): a few seconds, long enough to be caught
    # running however fast the other scenarios plan.
    slow = scenario("hatch-pass", simplify=False, seed=11, time_limit_s=60)  # room for a loaded machine
    running = httpx.post(f"{server.url}/api/v1/plans", json=slow, headers=h, timeout=30)
    queued = httpx.post(f"{server.url}/api/v1/plans", json=free_transfer(), headers=h, timeout=30)
    assert running.status_code == queued.status_code == 202
    a, b = running.json()["id"], queued.json()["id"]
    assert _poll(server.url, h, a, {"running"}, 30)["status"] == "running"
    server.kill()

    con = sqlite3.connect(server.data_dir / "cabinplan.db")  # what the crash left behind
    states = dict(con.execute("SELECT id, status FROM jobs").fetchall())
    con.close()
    assert states == {a: "running", b: "queued"}

    server.start()
    done_a = _poll(server.url, h, a, {"succeeded", "failed", "cancelled"}, 240)
    done_b = _poll(server.url, h, b, {"succeeded", "failed", "cancelled"}, 120)
    assert done_a["status"] == "succeeded" and done_a["attempts"] == 2, (
        done_a["reason"],
        done_a["message"],
        done_a["attempts"],
    )
    assert done_b["status"] == "succeeded" and done_b["attempts"] == 1, done_b
    assert done_a["result"]["report"]["gate"]["passed"] is True
    listed = httpx.get(f"{server.url}/api/v1/plans?status=running", headers=h, timeout=10).json()
    assert listed["total"] == 0


def test_recovery_requeues_once_then_fails_with_interrupted(tmp_path: Path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'r.db'}")
    db.create_all()
    rows = {}
    for attempts in (1, MAX_ATTEMPTS):
        job_id = uuid.uuid4().hex
        rows[attempts] = job_id
        with db.session() as s:
            s.add(
                Job(
                    id=job_id,
                    tenant="t",
                    status="running",
                    scenario=free_transfer(),
                    scenario_name="free-transfer",
                    request_sha256="0" * 64,
                    meshes={},
                    provenance={},
                    time_limit_s=20.0,
                    attempts=attempts,
                    created_at=now_s(),
                    started_at=now_s(),
                )
            )
    assert recover_jobs(db) == {"requeued": 1, "failed": 1}
    with db.session() as s:
        retried, given_up = s.get(Job, rows[1]), s.get(Job, rows[MAX_ATTEMPTS])
        assert retried is not None and given_up is not None
        assert retried.status == "queued" and retried.started_at is None
        assert given_up.status == "failed" and given_up.reason == "interrupted"
    assert recover_jobs(db) == {"requeued": 0, "failed": 0}
    db.dispose()
