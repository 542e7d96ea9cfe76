"""The PostgreSQL path for real (psycopg 3), in a schema of its own that is dropped afterwards."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
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


HOLD_S = 1.5


@contextmanager
def _held_by_another_process(schema: str, body: str) -> Iterator[None]:
    """Another process (another instance) holds a lock for :data:`HOLD_S` while the block runs.

    ``body`` opens the transaction that takes it (Python, ``db`` its Database).
    """
    code = (
        "import time\n"
        "from api.db import Database\n"
        "from api.store import _lock_blob\n"
        f"db = Database({PG_URL!r}, {schema!r})\n"
        f"{body}\n"
        "    print('locked', flush=True)\n"
        f"    time.sleep({HOLD_S})\n"
    )
    root = Path(__file__).resolve().parents[2]
    other = subprocess.Popen([sys.executable, "-c", code], cwd=root, stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout is not None and other.stdout.readline().strip() == "locked"
        yield
    finally:
        assert other.wait(timeout=30) == 0


def test_tenant_quota_lock_is_shared_by_every_instance_on_the_database(pg: tuple[Service, str]) -> None:
    """Another process (another instance) holding a tenant's quota lock makes this one wait for it.

    The count and the insert of a submission run under the lock, so two instances cannot both pass a
    tenant's quota; another tenant's lock is independent.
    """
    _, schema = pg
    with _held_by_another_process(schema, "with db.tenant_quota_session('alpha'):"):
        db = Database(PG_URL, schema)
        try:
            t0 = time.monotonic()
            with db.tenant_quota_session("beta"):  # another tenant: no wait
                pass
            assert time.monotonic() - t0 < 0.5 * HOLD_S
            with db.tenant_quota_session("alpha"):
                waited = time.monotonic() - t0
            assert waited > 0.5 * HOLD_S, waited
        finally:
            db.dispose()


def test_a_mesh_uploaded_on_one_instance_plans_on_another(pg: tuple[Service, str], tmp_path: Path) -> None:
    """Instances keep their own data directories; the mesh bytes travel through the shared database."""
    from api.store import MeshStore
    from planner.meshio import MeshLimits

    _, schema = pg
    db = Database(PG_URL, schema)
    try:
        here, there = MeshStore(db, tmp_path / "a", MeshLimits()), MeshStore(db, tmp_path / "b", MeshLimits())
        data = box_stl((2.0, 3.0, 7.0))  # bytes no other test of the module stores
        row, created = here.add("gamma", data, "box.stl", "m", "box")
        assert created and here.path_of(row).read_bytes() == data
        assert not there.path_of(row).exists()
        job_meshes = {row.sha256: str(here.path_of(row))}  # what a job submitted to "here" records
        local = there.local_files(job_meshes)[row.sha256]
        assert Path(local).parent == tmp_path / "b" and Path(local).read_bytes() == data
        assert there.local_path(row) == Path(local)  # now from its own disk
        assert here.delete("gamma", row.sha256)  # the last reference: the bytes go from the database too
        Path(local).unlink()
        with pytest.raises(FileNotFoundError, match="neither on this instance nor in the database"):
            there.local_files(job_meshes)
    finally:
        db.dispose()


def test_an_upload_waits_for_a_delete_of_the_same_bytes_on_another_instance(
    pg: tuple[Service, str], tmp_path: Path
) -> None:
    """Upload and delete of the same bytes take the bytes' row lock.

    So a delete that counted no other reference cannot remove the bytes under an upload that is adding
    one (which would leave a mesh listed but unplannable).
    """
    from api.store import MeshStore
    from planner.meshio import MeshLimits

    _, schema = pg
    db = Database(PG_URL, schema)
    try:
        here = MeshStore(db, tmp_path / "a", MeshLimits())
        data = box_stl((2.5, 3.0, 7.0))
        row, _ = here.add("delta", data, "box.stl", "m", "box")
        with _held_by_another_process(
            schema, f"with db.session() as s:\n    assert _lock_blob(s, {row.sha256!r})"
        ):
            t0 = time.monotonic()
            there = MeshStore(db, tmp_path / "b", MeshLimits())
            _, created = there.add("epsilon", data, "box.stl", "m", "box")
            assert created and time.monotonic() - t0 > 0.5 * HOLD_S
        assert here.delete("delta", row.sha256)  # epsilon still refers to the bytes: they stay
        assert Path(there.local_files({row.sha256: str(here.path_of(row))})[row.sha256]).read_bytes() == data
    finally:
        db.dispose()
