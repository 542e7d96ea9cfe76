"""Real server processes: job processes die with a SIGKILLed server; two instances share one PostgreSQL.

Each server is ``python -m api`` in a session of its own (so its process group is everything it
started: forkserver and job processes) on a free loopback port.
"""

from __future__ import annotations

import os
import signal
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.db import Database
from tests.api.conftest import Server, free_transfer, scenario, stuck
from tests.api.test_postgres import PG_URL, _reachable
from tests.api.test_restart import _poll

FINISHED = {"succeeded", "failed", "cancelled"}


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of a process group, from /proc."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        state, pgrp = fields[0], int(fields[2])
        if pgrp == pgid and state not in ("Z", "X"):
            out.append(int(entry.name))
    return out


def _wait_group_gone(pgid: int, timeout_s: float) -> tuple[float, list[int]]:
    """Seconds until no process of the group is left (or the timeout), and who is left."""
    t0 = time.monotonic()
    left = _group_members(pgid)
    while left and time.monotonic() - t0 < timeout_s:
        time.sleep(0.05)
        left = _group_members(pgid)
    return time.monotonic() - t0, left


def _kill_server_only(server: Server) -> int:
    """SIGKILL the server process alone (not its group): what a crash or the OOM killer does."""
    assert server.proc is not None
    pid = server.proc.pid
    os.kill(pid, signal.SIGKILL)
    server.proc.wait(timeout=10)
    return pid


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except ProcessLookupError:
        pass


@pytest.mark.slow
def test_job_processes_die_with_a_sigkilled_server(tmp_path: Path) -> None:
    server = Server(tmp_path / "data", CABINPLAN_WORKERS="2")
    server.start()
    pgid = server.proc.pid if server.proc else 0
    try:
        key = (server.data_dir / "local-api-key").read_text().strip()
        h = {"X-API-Key": key}
        ids = []
        for seed in (11, 12):
            r = httpx.post(f"{server.url}/api/v1/plans", json=stuck(seed, 30.0), headers=h, timeout=30)
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        for job_id in ids:
            assert _poll(server.url, h, job_id, {"running"}, 60)["status"] == "running"
        deadline = time.monotonic() + 30  # both job processes are up (besides the server and forkserver)
        while len(_group_members(pgid)) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)
        before = _group_members(pgid)
        assert len(before) >= 4, before
        _kill_server_only(server)
        took, left = _wait_group_gone(pgid, 10.0)
        assert not left, f"still running {took:.1f} s after the server's SIGKILL: {left}"
        assert took < 3.0, took
        assert "BrokenPipeError" not in server.log.read_text()
    finally:
        _kill_group(pgid)


@pytest.fixture
def pg_schema() -> Iterator[str]:
    why = _reachable(PG_URL)
    if why is not None:
        pytest.skip(f"no PostgreSQL server at {PG_URL} ({why})")
    schema = f"cabinplan_inst_{uuid.uuid4().hex[:12]}"
    try:
        yield schema
    finally:
        db = Database(PG_URL, schema)
        db.drop_schema()
        db.dispose()


def _owners(schema: str) -> dict[str, tuple[str, str | None, int]]:
    db = Database(PG_URL, schema)
    try:
        with db.engine.connect() as conn:
            rows = conn.exec_driver_sql(f'SELECT id, status, owner, attempts FROM "{schema}".jobs').all()
    finally:
        db.dispose()
    return {r[0]: (r[1], r[2], int(r[3])) for r in rows}


@pytest.mark.slow
def test_two_instances_share_postgres_a_killed_ones_job_finishes_on_the_other(
    tmp_path: Path, pg_schema: str
) -> None:
    env = {
        "CABINPLAN_DATABASE_URL": PG_URL,
        "CABINPLAN_DATABASE_SCHEMA": pg_schema,
        "CABINPLAN_JOB_LEASE_S": "2",
    }
    a = Server(tmp_path / "a", **env)
    b = Server(tmp_path / "b", **env)
    a.start()
    b.start()
    groups = [s.proc.pid for s in (a, b) if s.proc is not None]
    try:
        by_instance = {a.ready()["instance"]: a, b.ready()["instance"]: b}
        assert len(by_instance) == 2
        key = (a.data_dir / "local-api-key").read_text().strip()  # a key in the shared database
        h = {"X-API-Key": key}

        def submit(srv: Server, body: dict[str, Any]) -> str:
            r = httpx.post(f"{srv.url}/api/v1/plans", json=body, headers=h, timeout=30)
            assert r.status_code == 202, r.text
            job_id: str = r.json()["id"]
            return job_id

        # One job on each instance (one worker each): a search that runs to its limit, and a real plan of a
        # few seconds (the hatch pass without its transit posture).
        held = submit(a, stuck(11, 60.0))
        assert _poll(a.url, h, held, {"running"}, 60)["status"] == "running"
        real = submit(a, scenario("hatch-pass", simplify=False, seed=11, time_limit_s=60))
        assert _poll(a.url, h, real, {"running"}, 60)["status"] == "running"
        owners = _owners(pg_schema)
        assert owners[held][1] != owners[real][1] and {owners[held][1], owners[real][1]} == set(by_instance)
        runs_held, runs_real = by_instance[owners[held][1] or ""], by_instance[owners[real][1] or ""]

        # A cancellation sent to the other instance reaches the job.
        t0 = time.monotonic()
        r = httpx.delete(f"{runs_real.url}/api/v1/plans/{held}", headers=h, timeout=30)
        assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
        assert time.monotonic() - t0 < 5.0
        quick = submit(runs_real, free_transfer())  # the freed worker takes it

        # SIGKILL the instance that runs the real plan (alone, not its group: its children must follow).
        _kill_server_only(runs_real)
        took, left = _wait_group_gone(runs_real.proc.pid if runs_real.proc else 0, 10.0)
        assert not left, f"{left} left {took:.1f} s after the SIGKILL"

        survivor = runs_held
        done = {j: _poll(survivor.url, h, j, FINISHED, 240) for j in (real, quick)}
        assert done[real]["status"] == "succeeded", (done[real]["reason"], done[real]["message"])
        assert done[real]["attempts"] == 2  # run once on the killed instance, once on the survivor
        assert done[real]["result"]["report"]["gate"]["passed"] is True
        assert done[quick]["status"] == "succeeded" and done[quick]["attempts"] == 1
        final = _owners(pg_schema)
        assert set(final) == {held, real, quick}  # nothing lost, nothing duplicated
        assert final[held][0] == "cancelled" and final[held][2] == 1
        assert {final[j][1] for j in (real, quick)} == {survivor.ready()["instance"]}
        listed = httpx.get(f"{survivor.url}/api/v1/plans?limit=100", headers=h, timeout=10).json()
        assert listed["total"] == 3
    finally:
        for pgid in groups:
            _kill_group(pgid)
