"""Routes against the real app and a real SQLite file, with a runner that leaves jobs queued."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from api.db import Database
from tests.api.conftest import (
    ADMIN_KEY,
    Service,
    box_stl,
    free_transfer,
    make_settings,
    scenario,
    start_idle_service,
)

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def idle(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    settings = make_settings(
        tmp_path_factory.mktemp("idle"),
        tenant_max_active_jobs=3,
        max_body_bytes=64 * 1024,
        max_upload_bytes=16 * 1024,
        time_limit_ceiling_s=60.0,
    )
    yield from start_idle_service(settings)


def _problem(r, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert body["status"] == status and body["type"].startswith("urn:cabinplan:problem:")
    assert "Traceback" not in r.text
    return body


def test_health_and_ready_need_no_key(idle: Service) -> None:
    assert idle.client.get("/api/v1/health").json() == {"status": "ok"}
    ready = idle.client.get("/api/v1/ready").json()
    assert ready["status"] == "ready" and ready["database"] == "ok"
    assert "/api/v1/plans" in idle.client.get("/openapi.json").json()["paths"]


def test_sqlite_runs_in_wal_with_full_sync(tmp_path) -> None:
    db = Database(f"sqlite:///{tmp_path / 'x.db'}")
    with db.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert conn.exec_driver_sql("PRAGMA synchronous").scalar() == 2  # FULL
    db.dispose()


@pytest.mark.parametrize("headers", [{}, {"X-API-Key": "cpk_not-a-key"}])
def test_missing_or_unknown_key_is_401(idle: Service, headers: dict[str, str]) -> None:
    body = _problem(idle.client.get("/api/v1/plans", headers=headers), 401)
    assert "API key" in body["detail"]


def test_admin_manages_keys_and_tenants_cannot(idle: Service) -> None:
    _problem(idle.client.get("/api/v1/keys", headers=idle.h("alpha")), 403)
    _problem(idle.client.post("/api/v1/keys", json={"tenant": "gamma"}, headers=idle.h("alpha")), 403)
    r = idle.client.post(
        "/api/v1/keys", json={"tenant": "gamma", "name": "ui"}, headers={"X-API-Key": ADMIN_KEY}
    )
    assert r.status_code == 201
    created = r.json()
    gamma = {"X-API-Key": created["key"]}
    assert idle.client.get("/api/v1/plans", headers=gamma).json()["total"] == 0
    listed = idle.client.get("/api/v1/keys", headers={"X-API-Key": ADMIN_KEY}).json()["items"]
    assert created["id"] in {k["id"] for k in listed}
    assert all("key" not in k for k in listed)  # secrets are never listed (only hashes are stored)
    assert (
        idle.client.delete(f"/api/v1/keys/{created['id']}", headers={"X-API-Key": ADMIN_KEY}).status_code
        == 204
    )
    _problem(idle.client.get("/api/v1/plans", headers=gamma), 401)


def test_a_key_revoked_by_another_instance_is_refused_within_the_key_cache_ttl(idle: Service) -> None:
    """A revocation by another instance sharing the database is seen within the key cache's TTL.

    Written here straight into the table, as the other instance would; this instance's remembered key is
    trusted for at most :data:`api.keycache.KEY_CACHE_TTL_S`.
    """
    import time

    from api.db import ApiKey
    from api.keycache import KEY_CACHE_TTL_S

    admin = {"X-API-Key": ADMIN_KEY}
    created = idle.client.post("/api/v1/keys", json={"tenant": "delta", "name": "x"}, headers=admin).json()
    delta = {"X-API-Key": created["key"]}
    assert idle.client.get("/api/v1/plans", headers=delta).status_code == 200  # found valid: remembered
    ctx = idle.client.app.state.ctx  # type: ignore[attr-defined]
    with ctx.db.session() as s:  # what another instance's revocation writes
        s.get(ApiKey, created["id"]).revoked_at = time.time()
    t_revoked = time.monotonic()
    while True:  # each request timed from its start: a slow answer on a busy machine is not a late one
        started = time.monotonic()
        if idle.client.get("/api/v1/plans", headers=delta).status_code != 200:
            break
        assert started - t_revoked < KEY_CACHE_TTL_S  # no request started after the TTL is served
        time.sleep(0.05)
    assert started - t_revoked < KEY_CACHE_TTL_S + 0.5  # and the refusal came soon after it
    _problem(idle.client.get("/api/v1/plans", headers=delta), 401)


def test_the_key_cache_forgets_after_its_ttl_and_on_clear(monkeypatch: pytest.MonkeyPatch) -> None:
    from api import keycache

    now = [100.0]
    monkeypatch.setattr(keycache.time, "monotonic", lambda: now[0])
    cache = keycache.KeyCache(ttl_s=1.0)
    assert cache.get("d") is None
    cache.put("d", "alpha", "k1")
    now[0] = 100.999
    assert cache.get("d") == ("alpha", "k1")
    now[0] = 101.0
    assert cache.get("d") is None
    cache.put("d", "alpha", "k1")
    cache.clear()
    assert cache.get("d") is None
    for k in range(keycache.KEY_CACHE_MAX + 1):  # bounded: a flood of keys never grows it further
        cache.put(f"d{k}", "alpha", "k")
    assert len(cache._keys) <= keycache.KEY_CACHE_MAX


def test_robots_list_drives_units_and_limits(idle: Service) -> None:
    items = idle.client.get("/api/v1/robots", headers=idle.h()).json()["items"]
    cabin8 = next(r for r in items if r["name"] == "cabin8")
    assert [d["name"] for d in cabin8["drives"]] == [
        "d1",
        "x1",
        "x2",
        "x3",
        "theta3",
        "theta4",
        "d5",
        "theta6",
    ]
    assert all(d["lower"] < d["upper"] and d["v_max"] > 0 for d in cabin8["drives"])
    assert idle.client.get("/api/v1/robots/cabin8", headers=idle.h()).json() == cabin8
    _problem(idle.client.get("/api/v1/robots/nope", headers=idle.h()), 404)


def test_cabin_upload_by_content_hash_and_tenant_scoped(idle: Service) -> None:
    import hashlib

    data = box_stl()
    files = {"file": ("box.stl", data, "application/octet-stream")}
    r = idle.client.post("/api/v1/cabins", files=files, data={"units": "m", "name": "box"}, headers=idle.h())
    assert r.status_code == 201, r.text
    doc = r.json()
    assert doc["id"] == hashlib.sha256(data).hexdigest() and doc["n_faces"] == 12
    np.testing.assert_allclose(np.subtract(doc["bounds_max_m"], doc["bounds_min_m"]), [2.0, 2.0, 6.0])
    again = idle.client.post("/api/v1/cabins", files=files, data={"units": "m"}, headers=idle.h())
    assert again.status_code == 200 and again.json()["id"] == doc["id"]
    listing = idle.client.get("/api/v1/cabins", headers=idle.h()).json()
    assert {c["id"] for c in listing["references"]} >= {"cabin-aisle", "cabin-hatch"}
    assert [c["id"] for c in listing["items"]] == [doc["id"]]
    assert idle.client.get(f"/api/v1/cabins/{doc['id']}", headers=idle.h()).json()["name"] == "box"
    _problem(idle.client.get(f"/api/v1/cabins/{doc['id']}", headers=idle.h("beta")), 404)
    _problem(idle.client.delete(f"/api/v1/cabins/{doc['id']}", headers=idle.h("beta")), 404)
    _problem(idle.client.delete("/api/v1/cabins/cabin-aisle", headers=idle.h()), 409)
    # a scenario may name the uploaded cabin by id; the other tenant may not
    sc = {**free_transfer(), "cabin": {"mesh": doc["id"], "units": "m"}}
    job = idle.client.post("/api/v1/plans", json=sc, headers=idle.h())
    assert job.status_code == 202
    body = _problem(idle.client.post("/api/v1/plans", json=sc, headers=idle.h("beta")), 422)
    assert body["errors"][0]["field"] == "cabin.mesh"
    mm = {**sc, "cabin": {"mesh": doc["id"], "units": "mm"}}
    assert _problem(idle.client.post("/api/v1/plans", json=mm, headers=idle.h()), 422)["errors"][0][
        "field"
    ] == ("cabin.units")
    # The queued plan needs the cabin: it cannot be deleted under it (the job would fail), until cancelled.
    busy = _problem(idle.client.delete(f"/api/v1/cabins/{doc['id']}", headers=idle.h()), 409)
    assert busy["type"].endswith("cabin_in_use") and job.json()["id"] in busy["detail"]
    _cancel_all(idle)
    assert idle.client.delete(f"/api/v1/cabins/{doc['id']}", headers=idle.h()).status_code == 204
    _problem(idle.client.get(f"/api/v1/cabins/{doc['id']}", headers=idle.h()), 404)


@pytest.mark.parametrize(
    ("name", "data", "check"),
    [
        ("empty.stl", b"", "empty"),
        ("garbage.stl", b"solid x\nthis is not an stl\n" * 4, "no_faces"),
        ("box.xyz", b"abc", "name"),
    ],
)
def test_bad_mesh_is_422_with_the_loaders_reason(idle: Service, name: str, data: bytes, check: str) -> None:
    r = idle.client.post(
        "/api/v1/cabins", files={"file": (name, data)}, data={"units": "m"}, headers=idle.h()
    )
    body = _problem(r, 422)
    assert body["details"]["check"] == check
    assert body["errors"][0]["field"] == "file"


def test_mesh_in_mm_declared_as_m_is_refused_for_scale(idle: Service) -> None:
    data = box_stl((2000.0, 2000.0, 6000.0))
    body = _problem(
        idle.client.post("/api/v1/cabins", files={"file": ("b.stl", data)}, headers=idle.h()), 422
    )
    assert body["details"]["check"] == "scale"


def test_upload_and_body_size_limits_are_413(idle: Service) -> None:
    big = box_stl() + b"\0" * (20 * 1024)
    _problem(idle.client.post("/api/v1/cabins", files={"file": ("b.stl", big)}, headers=idle.h()), 413)
    padded = {**free_transfer(), "name": "x" * 10, "padding": "y" * (70 * 1024)}
    _problem(idle.client.post("/api/v1/plans", json=padded, headers=idle.h()), 413)

    def chunks():  # no Content-Length: the middleware counts the streamed bytes
        for _ in range(40):
            yield b" " * 4096

    r = idle.client.post(
        "/api/v1/plans", content=chunks(), headers={**idle.h(), "Content-Type": "application/json"}
    )
    _problem(r, 413)


def test_invalid_scenarios_name_the_field(idle: Service) -> None:
    bad = free_transfer(clearance_m=-1)
    body = _problem(idle.client.post("/api/v1/plans", json=bad, headers=idle.h()), 422)
    assert body["errors"][0]["field"] == "options.clearance_m"
    too_long = free_transfer(time_limit_s=90)
    body = _problem(idle.client.post("/api/v1/plans", json=too_long, headers=idle.h()), 422)
    assert body["errors"] == [{"field": "options.time_limit_s", "reason": "must be at most 60.0"}]
    typo = free_transfer()
    typo["start"] = {"drives": {**typo["start"]["drives"], "x9": 0.1}}
    body = _problem(idle.client.post("/api/v1/plans", json=typo, headers=idle.h()), 422)
    assert "start.drives" in body["detail"]
    path = {**free_transfer(), "cabin": {"mesh": "/etc/passwd", "units": "m"}}  # never a server file
    assert _problem(idle.client.post("/api/v1/plans", json=path, headers=idle.h()), 422)["errors"][0][
        "field"
    ] == ("cabin.mesh")
    malformed = _problem(idle.client.post("/api/v1/plans", content=b"{not json", headers=idle.h()), 400)
    assert (
        malformed["type"] == "urn:cabinplan:problem:malformed_body"
        and "line 1, column 2" in malformed["detail"]
    )


def _cancel_all(svc: Service) -> None:
    for tenant in ("alpha", "beta"):
        for job in svc.client.get("/api/v1/plans?status=queued&limit=100", headers=svc.h(tenant)).json()[
            "items"
        ]:
            assert svc.client.delete(f"/api/v1/plans/{job['id']}", headers=svc.h(tenant)).json()[
                "status"
            ] == ("cancelled")


def test_quota_is_429_with_retry_after_and_cancel_frees_it(idle: Service) -> None:
    _cancel_all(idle)
    ids = []
    for k in range(3):
        r = idle.client.post("/api/v1/plans", json=free_transfer(seed=k), headers=idle.h())
        assert r.status_code == 202
        assert r.headers["location"] == f"/api/v1/plans/{r.json()['id']}"
        ids.append(r.json()["id"])
    body = _problem(idle.client.post("/api/v1/plans", json=free_transfer(seed=9), headers=idle.h()), 429)
    assert body["active_jobs"] == 3
    r = idle.client.post("/api/v1/plans", json=free_transfer(seed=9), headers=idle.h())
    assert int(r.headers["retry-after"]) > 0
    # the quota is per tenant
    assert idle.client.post("/api/v1/plans", json=free_transfer(), headers=idle.h("beta")).status_code == 202
    # cancelling a queued job frees a slot
    cancelled = idle.client.delete(f"/api/v1/plans/{ids[0]}", headers=idle.h()).json()
    assert cancelled["status"] == "cancelled" and cancelled["finished_at"] is not None
    assert idle.client.post("/api/v1/plans", json=free_transfer(seed=9), headers=idle.h()).status_code == 202
    _problem(idle.client.get(f"/api/v1/plans/{ids[0]}/profile.csv", headers=idle.h()), 404)
    _problem(idle.client.get(f"/api/v1/plans/{ids[1]}/profile.csv", headers=idle.h()), 409)
    queued = idle.client.get("/api/v1/plans?status=queued", headers=idle.h()).json()
    assert queued["total"] == 3 and all(j["status"] == "queued" for j in queued["items"])
    assert idle.client.get("/api/v1/plans?status=cancelled", headers=idle.h()).json()["total"] >= 1
    _cancel_all(idle)


def test_idempotency_key_returns_the_same_job(idle: Service) -> None:
    _cancel_all(idle)
    h = {**idle.h(), "Idempotency-Key": "mes-order-42"}
    first = idle.client.post("/api/v1/plans", json=free_transfer(), headers=h)
    again = idle.client.post("/api/v1/plans", json=free_transfer(), headers=h)
    assert first.status_code == 202 and again.status_code == 200
    assert again.json()["id"] == first.json()["id"] and again.headers["location"] == first.headers["location"]
    assert idle.client.get("/api/v1/plans?status=queued", headers=idle.h()).json()["total"] == 1
    body = _problem(idle.client.post("/api/v1/plans", json=free_transfer(seed=5), headers=h), 422)
    assert body["plan_id"] == first.json()["id"]
    # another tenant's identical key is its own job
    other = idle.client.post(
        "/api/v1/plans", json=free_transfer(), headers={**idle.h("beta"), "Idempotency-Key": "mes-order-42"}
    )
    assert other.status_code == 202 and other.json()["id"] != first.json()["id"]
    _cancel_all(idle)


def test_plans_are_tenant_scoped_and_carry_provenance(idle: Service) -> None:
    r = idle.client.post("/api/v1/plans", json=scenario("aisle-transfer"), headers=idle.h())
    assert r.status_code == 202
    job = r.json()
    prov = job["provenance"]
    assert len(prov["scenario_sha256"]) == 64 and len(prov["robot_description_sha256"]) == 64
    assert prov["cabin_source"] == "cabin-aisle" and len(prov["cabin_mesh_sha256"]) == 64
    assert len(prov["code"]["source_sha256"]) == 64
    for method, suffix in (("get", ""), ("get", "/profile.csv"), ("get", "/plot.png"), ("delete", "")):
        _problem(
            getattr(idle.client, method)(f"/api/v1/plans/{job['id']}{suffix}", headers=idle.h("beta")), 404
        )
    assert job["id"] not in {
        j["id"] for j in idle.client.get("/api/v1/plans", headers=idle.h("beta")).json()["items"]
    }
    _cancel_all(idle)


def test_fk_ik_round_trip(idle: Service) -> None:
    drives = free_transfer()["start"]["drives"]
    fk = idle.client.post(
        "/api/v1/kinematics/fk", json={"robot": "cabin8", "drives": drives}, headers=idle.h()
    )
    assert fk.status_code == 200, fk.text
    out = fk.json()
    assert out["violations"] == []
    T = np.array(out["T_base_tool"]).reshape(4, 4)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    back = idle.client.post("/api/v1/kinematics/fk", json={"joints": out["joints"]}, headers=idle.h()).json()
    np.testing.assert_allclose(list(back["drives"].values()), list(drives.values()), atol=1e-9)
    ik = idle.client.post(
        "/api/v1/kinematics/ik", json={"pose": out["pose"], "near": drives}, headers=idle.h()
    )
    assert ik.status_code == 200, ik.text
    np.testing.assert_allclose(ik.json()["T_base_tool"], out["T_base_tool"], atol=1e-6)
    far = {"pose": {"position": [3.0, 0.8, 2.0]}}
    body = _problem(idle.client.post("/api/v1/kinematics/ik", json=far, headers=idle.h()), 422)
    assert body["reason"] == "goal_unreachable"
    both = {"drives": drives, "joints": out["joints"]}
    _problem(idle.client.post("/api/v1/kinematics/fk", json=both, headers=idle.h()), 422)
    body = _problem(
        idle.client.post("/api/v1/kinematics/fk", json={"robot": "r2d2", "drives": drives}, headers=idle.h()),
        422,
    )
    assert body["errors"][0]["field"] == "robot"


def test_unknown_route_and_method_are_problems(idle: Service) -> None:
    _problem(idle.client.get("/api/v1/nothing-here", headers=idle.h()), 404)
    _problem(idle.client.put("/api/v1/health"), 405)


def test_face_cap_of_uploads_is_the_loaders_face_count_check(tmp_path) -> None:
    for svc in start_idle_service(make_settings(tmp_path, max_mesh_faces=10)):
        r = svc.client.post("/api/v1/cabins", files={"file": ("box.stl", box_stl())}, headers=svc.h())
        assert _problem(r, 422)["details"]["check"] == "face_count"  # a box has 12 triangles


def test_settings_come_from_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    from api.settings import Settings

    monkeypatch.setenv("CABINPLAN_WORKERS", "3")
    monkeypatch.setenv("CABINPLAN_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("CABINPLAN_TIME_LIMIT_CEILING_S", "45")
    s = Settings()
    assert (s.workers, s.data_dir, s.time_limit_ceiling_s, s.host) == (3, tmp_path, 45.0, "127.0.0.1")
    assert s.resolved_database_url() == f"sqlite:///{(tmp_path / 'cabinplan.db').resolve()}"
    monkeypatch.setenv("CABINPLAN_WORKERS", "0")
    with pytest.raises(ValueError, match="workers"):
        Settings()


def test_the_local_default_key_works_from_loopback_only(idle: Service) -> None:
    from fastapi.testclient import TestClient

    from api.auth import LOCAL_TENANT, create_key

    app = idle.client.app
    _, key = create_key(app.state.ctx, LOCAL_TENANT, "local default key")
    h = {"X-API-Key": key}
    local = TestClient(app, client=("127.0.0.1", 50001), raise_server_exceptions=False)
    assert local.get("/api/v1/robots", headers=h).status_code == 200
    remote = TestClient(app, client=("192.0.2.7", 50002), raise_server_exceptions=False)
    body = _problem(remote.get("/api/v1/robots", headers=h), 401)
    assert "loopback" in body["detail"]
    # An ordinary tenant key is accepted from anywhere.
    assert remote.get("/api/v1/robots", headers=idle.h()).status_code == 200


def test_concurrent_submissions_never_exceed_the_quota(idle: Service) -> None:
    from concurrent.futures import ThreadPoolExecutor

    from api.auth import create_key

    _, key = create_key(idle.client.app.state.ctx, "gamma", "quota race")
    h = {"X-API-Key": key}
    limit = idle.client.app.state.ctx.settings.tenant_max_active_jobs
    with ThreadPoolExecutor(max_workers=8) as pool:
        codes = list(
            pool.map(lambda _: idle.client.post("/api/v1/plans", json=free_transfer(), headers=h), range(8))
        )
    statuses = [r.status_code for r in codes]
    assert statuses.count(202) == limit and statuses.count(429) == 8 - limit, statuses
    for r in codes:
        if r.status_code == 202:
            assert idle.client.delete(f"/api/v1/plans/{r.json()['id']}", headers=h).status_code in (200, 202)
