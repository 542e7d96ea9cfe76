"""The PostgreSQL path for real (psycopg 3), in a schema of its own that is dropped afterwards."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from api.db import Database
from api.jobs import recover_jobs
from tests.api.conftest import Service, box_stl, free_transfer, make_settings, start_service, wait_for

PG_URL = os.environ.get("CABINPLAN_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _reachable(url: str) -> str | None:
    """``None`` when the server answers, else why not."""
    db = Database(url)
    try:
        with db.engine.connect() as conn:
            conn.exec_driver_sql("SELECT 1")
    except Exception as exc:
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    finally:
        db.dispose()
    return None


@pytest.fixture(scope="module")
def pg(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Service, str]]:
    why = _reachable(PG_URL)
    if why is not None:
        pytest.skip(f"no PostgreSQL server at {PG_URL} ({why})")
    schema = f"cabinplan_test_{uuid.uuid4().hex[:12]}"
    settings = make_settings(
        Path(tmp_path_factory.mktemp("pg")), database_url=PG_URL, database_schema=schema, job_grace_s=20.0
    )
    try:
        yield from ((svc, schema) for svc in start_service(settings))
    finally:
        db = Database(PG_URL, schema)
        db.drop_schema()
        db.dispose()


def test_jobs_keys_and_meshes_live_in_postgres(pg: tuple[Service, str]) -> None:
    svc, schema = pg
    r = svc.client.post("/api/v1/plans", json=free_transfer(d1_goal=1.3), headers=svc.h())
    assert r.status_code == 202
    doc = wait_for(svc.client, svc.h(), r.json()["id"])
    assert doc["status"] == "succeeded" and doc["result"]["report"]["gate"]["passed"] is True
    up = svc.client.post("/api/v1/cabins", files={"file": ("box.stl", box_stl())}, headers=svc.h())
    assert up.status_code == 201
    assert svc.client.get(f"/api/v1/cabins/{up.json()['id']}", headers=svc.h("beta")).status_code == 404
    db = Database(PG_URL, schema)
    with db.engine.connect() as conn:  # the rows are really in that schema of the server
        tables = {
            r[0]
            for r in conn.exec_driver_sql(
                "SELECT table_name FROM information_schema.tables WHERE table_schema = %(s)s", {"s": schema}
            )
        }
        assert {"jobs", "api_keys", "meshes"} <= tables
        status = conn.exec_driver_sql(
            f'SELECT status FROM "{schema}".jobs WHERE id = %(i)s', {"i": doc["id"]}
        ).scalar()
    assert status == "succeeded"
    assert recover_jobs(db) == {"requeued": 0, "failed": 0}
    db.dispose()
