"""The job state machine (api.jobstore): its table, every store call checked against it, one place for SQL."""

from __future__ import annotations

import ast
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import select

from api.cycles import campaign_job, cycle_job
from api.db import ACTIVE_STATES, JOB_STATES, TERMINAL_STATES, Database, Job
from api.jobkinds import PLAN, JobKind, ResultFile, kind_of, kinds, register
from api.jobstore import (
    MAX_ATTEMPTS,
    TRANSITIONS,
    JobStore,
    QuotaExceeded,
    allowed,
    new_job,
)
from api.routes.jobroutes import job_document
from api.worker import plan_job, profile_csv

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------------ the table
def test_the_table_moves_between_known_states_and_terminal_states_only_leave_by_deletion() -> None:
    for event, move in TRANSITIONS.items():
        assert move.source <= set(JOB_STATES), event
        assert move.target is None or move.target in JOB_STATES, event
    leaving_terminal = {e for e, m in TRANSITIONS.items() if m.source & set(TERMINAL_STATES)}
    assert leaving_terminal == {"delete"}
    assert TRANSITIONS["delete"].source == set(TERMINAL_STATES) and TRANSITIONS["delete"].target is None
    # Every state is reachable from a submission, and every active state can end.
    reached, frontier = set(), {TRANSITIONS["submit"].target}
    while frontier:
        state = frontier.pop()
        reached.add(state)
        frontier |= {m.target for m in TRANSITIONS.values() if state in m.source and m.target} - reached
    assert reached == set(JOB_STATES)
    for state in ACTIVE_STATES:
        assert any(state in m.source and m.target in TERMINAL_STATES for m in TRANSITIONS.values()), state
    assert allowed("submit", None) and not allowed("claim", None)
    assert allowed("claim", "queued") and not allowed("claim", "running")
    assert not any(allowed(e, "succeeded") for e in TRANSITIONS if e != "delete")


# ------------------------------------------------------------------- every store call obeys the table
@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Iterator[JobStore]:
    db = Database(f"sqlite:///{tmp_path_factory.mktemp('jobstore') / 'jobs.db'}")
    db.create_all()
    yield JobStore(db)
    db.dispose()


def _add(store: JobStore, tenant: str, status: str, owner: str | None, attempts: int = 1) -> str:
    job = new_job(PLAN, tenant, {}, "x", "0" * 64, {}, {}, 5.0)
    job.status, job.owner, job.attempts = status, owner, attempts
    job.lease_expires_at = 0.0 if status == "running" else None  # lapsed: expire_leases acts on it
    with store.db.session() as s:
        s.add(job)
    return job.id


def _states(store: JobStore, tenant: str) -> dict[str, str]:
    with store.db.session() as s:
        return dict(s.execute(select(Job.id, Job.status).where(Job.tenant == tenant)).all())  # type: ignore[arg-type]


CALLS = ("cancel", "claim", "end", "requeue", "expire", "delete", "progress")


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(
    states=st.lists(st.sampled_from(JOB_STATES), min_size=1, max_size=5),
    calls=st.lists(
        st.tuples(st.sampled_from(CALLS), st.integers(0, 4), st.sampled_from(TERMINAL_STATES)), max_size=8
    ),
)
def test_every_store_call_moves_jobs_only_along_the_table(store: JobStore, states, calls) -> None:
    """Random calls of the store on jobs in random states: each status change is a move of the table."""
    tenant = uuid.uuid4().hex[:16]
    me = "me" + tenant[:8]
    ids = [_add(store, tenant, status, me if status == "running" else None) for status in states]
    pairs = {(s, m.target) for m in TRANSITIONS.values() for s in m.source}
    for call, k, outcome in calls:
        before = _states(store, tenant)
        job_id = ids[k % len(ids)]
        if call == "cancel":
            store.cancel([job_id], "test")
        elif call == "claim":
            store.claim(me, 15.0)
        elif call == "end":
            store.end(job_id, me, outcome, reason="r", message="m")
        elif call == "requeue":
            store.requeue(job_id, me)
        elif call == "expire":
            store.expire_leases()
        elif call == "delete":
            store.delete_finished([job_id])
        else:
            store.progress(job_id, me, "search", 0.5)
        after = _states(store, tenant)
        for j, status in before.items():
            new = after.get(j)
            assert new == status or (status, new) in pairs, (call, status, new)
        assert set(after) <= set(before)  # jobs of this tenant only ever disappear by deletion


def test_an_owner_writes_only_over_its_own_running_job(store: JobStore) -> None:
    tenant = uuid.uuid4().hex[:16]
    theirs = _add(store, tenant, "running", "other")
    assert not store.end(theirs, "me", "succeeded")
    store.requeue(theirs, "me")
    store.progress(theirs, "me", "search", 0.9)
    with store.db.session() as s:
        row = s.get(Job, theirs)
        assert row is not None and (row.status, row.owner, row.stage) == ("running", "other", None)


def test_kept_files_and_progress_detail_only_from_the_owner_and_gone_with_the_job(store: JobStore) -> None:
    """A campaign's finished cycles: kept by its owner while running, read by a relaunch, deleted with it."""
    tenant = uuid.uuid4().hex[:16]
    mine = _add(store, tenant, "running", "me")
    assert store.keep(mine, "me", "keep/a", b"cycle a")
    assert not store.keep(mine, "other", "keep/b", b"not mine")  # an instance that lost the lease
    assert store.keep(mine, "me", "keep/a", b"cycle a, again")  # the same name: replaced, no error
    store.store_file(mine, "plot.png", b"png")
    assert store.kept(mine, "keep/") == {"keep/a": b"cycle a, again"}
    store.progress(mine, "me", "unit A3", 0.5, {"units": [{"id": "A3", "status": "planning"}]})
    store.progress(mine, "me", "unit A3", 0.6)  # no detail: the last one stays
    store.progress(mine, "other", "x", 0.9, {"units": []})
    with store.db.session() as s:
        row = s.get(Job, mine)
        assert row is not None and row.progress_detail == {"units": [{"id": "A3", "status": "planning"}]}
        assert row.progress == 0.6
    store.expire_leases()  # its instance died: re-queued, the kept cycle stays for the next attempt
    assert store.kept(mine, "keep/") == {"keep/a": b"cycle a, again"}
    assert not store.keep(mine, "me", "keep/c", b"queued: nobody's")
    store.cancel([mine], "test")
    store.delete_finished([mine])
    assert store.kept(mine, "keep/") == {} and store.stored_file(mine, "plot.png") is None


def test_expired_leases_requeue_then_fail_and_a_requested_cancel_wins(store: JobStore) -> None:
    tenant = uuid.uuid4().hex[:16]
    first = _add(store, tenant, "running", "dead", attempts=1)
    last = _add(store, tenant, "running", "dead", attempts=MAX_ATTEMPTS)
    asked = _add(store, tenant, "running", "dead", attempts=1)
    store.cancel([asked], "test")
    store.expire_leases()
    assert _states(store, tenant) == {first: "queued", last: "failed", asked: "cancelled"}


def test_the_quota_counts_every_active_job_of_the_tenant(store: JobStore) -> None:
    tenant = uuid.uuid4().hex[:16]
    _add(store, tenant, "running", "x")
    _add(store, tenant, "succeeded", None)
    job = new_job(PLAN, tenant, {}, "x", "1" * 64, {}, {}, 5.0)
    assert not store.submit(job, max_active=2).replayed
    with pytest.raises(QuotaExceeded) as info:
        store.submit(new_job(PLAN, tenant, {}, "x", "2" * 64, {}, {}, 5.0), max_active=2)
    assert (info.value.active, info.value.limit) == (2, 2)


# ------------------------------------------------------------------------------------ job kinds
def test_kinds_are_one_entry_each_and_a_new_kind_gets_the_shared_job_document(monkeypatch) -> None:
    assert kind_of(None) is PLAN and kind_of("plan") is PLAN and PLAN in kinds()
    assert {f.name for f in PLAN.files} == {"profile.csv", "plot.png"}
    assert PLAN.runner is plan_job and PLAN.file("profile.csv").maker is profile_csv  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="clashes"):
        register(JobKind("plan2", "plans", "plan", plan_job))
    import api.jobkinds as jobkinds

    monkeypatch.setattr(jobkinds, "_KINDS", dict(jobkinds._KINDS))
    inspection = register(
        JobKind(
            "inspection",
            "inspections",
            "inspection",
            plan_job,
            input_key="inspection",
            files=(ResultFile("profile.csv", "profile_csv", "text/csv", profile_csv),),
        )
    )
    row = new_job(inspection, "t", {}, "dock-to-bay", "0" * 64, {}, {"inspection_sha256": "ab"}, 5.0)
    row.status = "succeeded"
    doc = job_document(inspection, row)
    assert row.kind == "inspection" and kind_of(row.kind) is inspection
    assert doc["inspection"] == {"name": "dock-to-bay", "sha256": "ab"} and "scenario" not in doc
    assert doc["links"] == {
        "self": f"/api/v1/inspections/{row.id}",
        "profile_csv": f"/api/v1/inspections/{row.id}/profile.csv",
    }
    # The cycle and campaign kinds are entries of the same registry.
    assert kind_of("cycle").collection == "cycles" and kind_of("campaign").collection == "campaigns"
    assert kind_of("cycle").runner is cycle_job and kind_of("campaign").runner is campaign_job


def test_a_kind_lists_only_its_own_jobs_and_rows_without_a_kind_are_plans(
    store: JobStore, monkeypatch
) -> None:
    import api.jobkinds as jobkinds

    monkeypatch.setattr(jobkinds, "_KINDS", dict(jobkinds._KINDS))
    other = register(JobKind("inspection", "inspections", "inspection", plan_job))
    tenant = uuid.uuid4().hex[:16]
    legacy = _add(store, tenant, "queued", None)
    with store.db.session() as s:
        row = s.get(Job, legacy)
        assert row is not None
        row.kind = None  # written before kinds existed
    store.submit(new_job(other, tenant, {}, "c", "3" * 64, {}, {}, 5.0), max_active=10)
    plans, n_plans = store.page(tenant, PLAN, None, 10, 0)
    campaigns, n_campaigns = store.page(tenant, other, None, 10, 0)
    assert [r.id for r in plans] == [legacy] and n_plans == 1
    assert n_campaigns == 1 and campaigns[0].kind == "inspection"
    assert store.get(tenant, legacy, other) is None and store.get(tenant, legacy, PLAN) is not None


# ------------------------------------------------------------------------- SQL in one place only
def _imports_and_job_updates(path: Path) -> tuple[set[str], int]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    modules = {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    modules |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    updates = sum(
        1
        for n in ast.walk(tree)
        if isinstance(n, ast.Call)
        and isinstance(n.func, ast.Name)
        and n.func.id in ("update", "delete")
        and n.args
        and isinstance(n.args[0], ast.Name)
        and n.args[0].id == "Job"
    )
    return modules, updates


def test_routes_write_no_sql_and_only_the_job_store_changes_jobs() -> None:
    for path in sorted((ROOT / "api" / "routes").glob("*.py")):
        modules, _ = _imports_and_job_updates(path)
        assert not any(m.startswith("sqlalchemy") for m in modules), path.name
    writers = [p.name for p in sorted((ROOT / "api").rglob("*.py")) if _imports_and_job_updates(p)[1]]
    assert writers == ["jobstore.py"]
