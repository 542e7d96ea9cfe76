"""POST /sweeps: the plans run as ordinary jobs under the tenant's quota; progress, summary and results."""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tests.api.conftest import Service, make_settings, scenario, start_service

QUOTA = 2


@pytest.fixture(scope="module")
def svc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    settings = make_settings(tmp_path_factory.mktemp("sweeps"), tenant_max_active_jobs=QUOTA)
    yield from start_service(settings)


def sweep_body() -> dict[str, Any]:
    """4 plans: the 100 kg aisle transfer (feasible) and 400 kg (refused at the start), 2 seeds each."""
    return {
        "name": "transfer-masses",
        "base": scenario("aisle-transfer"),
        "axes": {"payload_mass_kg": [100, 400], "seed": [1, 2]},
    }


def active_jobs(svc: Service) -> int:
    """Queued + running jobs of the tenant, from one listing (one snapshot of the table)."""
    items = svc.client.get("/api/v1/plans", params={"limit": 100}, headers=svc.h()).json()["items"]
    return sum(1 for job in items if job["status"] in ("queued", "running"))


def test_a_sweep_runs_as_jobs_under_the_quota_and_gives_its_results(svc: Service):
    r = svc.client.post("/api/v1/sweeps", json=sweep_body(), headers=svc.h())
    assert r.status_code == 202, r.text
    doc = r.json()
    assert r.headers["Location"] == f"/api/v1/sweeps/{doc['id']}"
    assert doc["total"] == 4 and doc["status"] == "running"
    most = 0
    deadline = time.monotonic() + 240
    while doc["status"] != "finished":
        assert time.monotonic() < deadline, doc
        most = max(most, active_jobs(svc))
        assert most <= QUOTA  # the sweep never holds more than the tenant's quota of jobs
        time.sleep(0.1)
        doc = svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).json()
    assert most >= 1
    assert doc["progress"]["done"] == 4 and doc["progress"]["waiting"] == 0
    assert doc["summary"] == {"succeeded": 2, "reasons": {"start_outside_limits": 2}}

    table = list(
        csv.DictReader(io.StringIO(svc.client.get(doc["links"]["results_csv"], headers=svc.h()).text))
    )
    assert [int(r["plan"]) for r in table] == [0, 1, 2, 3]
    for row in table:
        if float(row["payload_mass_kg"]) == 400:
            assert (row["status"], row["reason"]) == ("failed", "start_outside_limits")
        else:
            assert row["status"] == "succeeded"
            assert float(row["min_clearance_m"]) >= float(row["clearance_m"])
            assert float(row["lower_bound_ratio"]) >= 1.0
            plan = svc.client.get(row["profile_file"], headers=svc.h()).json()  # the plan's own job
            assert plan["result"]["duration_s"] == pytest.approx(float(row["duration_s"]))
    raw = svc.client.get(doc["links"]["results_parquet"], headers=svc.h()).content
    rows = pq.read_table(pa.BufferReader(raw)).to_pylist()
    assert [(r["scenario_sha256"], r["status"]) for r in rows] == [
        (r["scenario_sha256"], r["status"]) for r in table
    ]

    assert svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h("beta")).status_code == 404
    assert svc.client.delete(f"/api/v1/sweeps/{doc['id']}", headers=svc.h("beta")).status_code == 404

    # An ended sweep is deleted with its plans' jobs.
    assert svc.client.delete(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).status_code == 204
    assert svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).status_code == 404
    assert svc.client.get(table[0]["profile_file"], headers=svc.h()).status_code == 404


def test_deleting_a_running_sweep_cancels_it_and_a_second_delete_removes_it(svc: Service):
    body = sweep_body()
    body["axes"] = {"payload_mass_kg": [100], "seed": list(range(1, 9))}  # 8 feasible plans, quota 2
    doc = svc.client.post("/api/v1/sweeps", json=body, headers=svc.h()).json()
    r = svc.client.delete(f"/api/v1/sweeps/{doc['id']}", headers=svc.h())
    assert r.status_code in (200, 202), r.text
    cancelled = r.json()
    assert cancelled["status"] == "cancelled"
    deadline = time.monotonic() + 60
    while active_jobs(svc):  # queued jobs cancelled at once, running ones killed
        assert time.monotonic() < deadline
        time.sleep(0.1)
    doc = svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).json()
    progress = doc["progress"]
    assert doc["status"] == "cancelled" and progress["queued"] == progress["running"] == 0
    assert progress["waiting"] + progress["done"] == 8 and progress["waiting"] >= 8 - 2 * QUOTA
    time.sleep(0.5)  # the feeder never queues a cancelled sweep's waiting plans
    assert svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).json()["progress"] == progress
    assert svc.client.delete(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).status_code == 204
    assert svc.client.get(f"/api/v1/sweeps/{doc['id']}", headers=svc.h()).status_code == 404


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"axes": {"payload_mass_kg": [-5]}}, "axes.payload_mass_kg[0]"),
        ({"base": "aisle-transfer.yaml"}, "base"),
        ({"bays": {"manifest": "cabins.json"}}, "bays.manifest"),
        ({"axes": {"goal": {"bays": ["A1"]}}}, "axes.goal.bays[0]"),
    ],
)
def test_invalid_sweeps_are_422_naming_the_field(svc: Service, change: dict[str, Any], field: str):
    r = svc.client.post("/api/v1/sweeps", json={**sweep_body(), **change}, headers=svc.h())
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert r.json()["detail"].startswith(field)


def test_the_feeder_feeds_when_a_sweep_arrives_or_a_job_ends_not_at_its_poll(tmp_path: Path) -> None:
    """With a poll of a minute, a sweep's first plans and the next plan after a job's end are queued at once.

    The route wakes the feeder when a sweep is submitted, and the runner when one of its jobs ends.
    """
    from api.db import Database
    from api.jobstore import JobStore
    from api.sweeps import SweepFeeder, SweepStore, new_sweep
    from tests.api.conftest import IdleRunner

    class Runner(IdleRunner):
        def __init__(self) -> None:
            super().__init__()
            self.listeners: list[Callable[[str], None]] = []

        def on_job_end(self, listener: Callable[[str], None]) -> None:
            self.listeners.append(listener)

    settings = make_settings(tmp_path, tenant_max_active_jobs=2)
    settings.data_dir.mkdir(parents=True)
    db = Database(settings.resolved_database_url(), settings.database_schema)
    db.create_all()
    runner = Runner()
    feeder = SweepFeeder(db, settings, runner, poll_s=60.0)
    assert runner.listeners == [feeder.job_ended]
    feeder.start()
    try:
        feeder.wake()  # its first pass, over nothing, done before the sweep exists
        time.sleep(0.2)
        sc = scenario("aisle-transfer")
        plans = [{"index": k, "sha256": f"{k:064x}", "scenario": sc, "labels": {}} for k in range(3)]
        row = new_sweep("alpha", "three", {}, plans, {"meshes": {}, "provenance": {}})
        SweepStore(db).add(row)
        jobs = JobStore(db)

        def linked() -> list[str]:
            return SweepStore(db).job_ids(row.id)

        feeder.wake()  # what POST /sweeps does (ctx.sweep_submitted)
        deadline = time.monotonic() + 5.0
        while len(linked()) < 2:
            assert time.monotonic() < deadline, "the submitted sweep was not fed when woken"
            time.sleep(0.02)
        time.sleep(0.3)
        assert len(linked()) == 2  # the quota: the third plan waits
        ended = linked()[0]
        jobs.cancel([ended], "ended")  # one job ends ...
        for listener in runner.listeners:  # ... and the runner says so
            listener(ended)
        deadline = time.monotonic() + 5.0
        while len(linked()) < 3:
            assert time.monotonic() < deadline, "the waiting plan was not fed when a job ended"
            time.sleep(0.02)
    finally:
        feeder.stop()
        db.dispose()
