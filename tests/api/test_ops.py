"""What an operations team needs of the service (real server process where it matters).

Warm-up before /ready, metrics, access logs, progress, limits on abuse, a typed API with one problem
type per kind of error, retention and compact storage.
"""

from __future__ import annotations

import json
import socket
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import yaml
from sqlalchemy import select

from api import results
from api.compact import document_json, pack_document, pack_value, unpack_document, unpack_json, unpack_text
from api.db import Database, Job, now_s
from api.jobs import purge_expired
from api.settings import Settings
from tests.api.conftest import (
    ADMIN_KEY,
    SCENARIOS,
    Server,
    Service,
    free_transfer,
    make_settings,
    scenario,
    start_idle_service,
    start_service,
    stuck,
    wait_for,
)

PROBLEM = "application/problem+json"


def _problem(r: httpx.Response, status: int, code: str) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body: dict[str, Any] = r.json()
    assert body["type"] == f"urn:cabinplan:problem:{code}" and body["status"] == status, body
    return body


def _read_response(sock: socket.socket) -> str:
    """One HTTP response (head and Content-Length body) from a socket, as text."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            return data.decode("latin-1")
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        (
            int(ln.split(b":", 1)[1])
            for ln in head.split(b"\r\n")
            if ln.lower().startswith(b"content-length:")
        ),
        0,
    )
    while len(body) < length:
        chunk = sock.recv(4096)
        if not chunk:
            break
        body += chunk
    return (head + b"\r\n\r\n" + body).decode("latin-1")


@pytest.fixture(scope="module")
def idle(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_idle_service(make_settings(tmp_path_factory.mktemp("ops-idle")))


# ----------------------------------------------------------------------------- a real server process


def test_warm_up_ready_progress_metrics_access_log_and_body_timeout(tmp_path: Path) -> None:
    srv = Server(tmp_path / "data", CABINPLAN_BODY_TIMEOUT_S="1")
    srv.start(wait="health")
    try:
        key = (srv.data_dir / "local-api-key").read_text().strip()
        h = {"X-API-Key": key, "X-Request-ID": "ops-test-1"}
        # The forkserver is still warming up: not ready, and a queued job says why it waits.
        warming = _problem(httpx.get(f"{srv.url}/api/v1/ready", timeout=10), 503, "not_ready")
        assert warming["stage"] == "compiling kernels" and warming["database"] is True
        first = httpx.post(f"{srv.url}/api/v1/plans", json=free_transfer(), headers=h, timeout=30)
        assert first.status_code == 202 and first.headers["x-request-id"] == "ops-test-1"
        doc = httpx.get(f"{srv.url}/api/v1/plans/{first.json()['id']}", headers=h, timeout=10).json()
        assert doc["status"] == "queued" and doc["stage"] == "compiling kernels"
        deadline = time.monotonic() + 300
        while httpx.get(f"{srv.url}/api/v1/ready", timeout=10).status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        ready = httpx.get(f"{srv.url}/api/v1/ready", timeout=10).json()
        assert set(ready["queue"]) == {"queued", "running"} and ready["queue"]["queued"] <= 1

        # Progress moves with the search (a search that runs to its 8 s limit).
        hopeless = httpx.post(f"{srv.url}/api/v1/plans", json=stuck(12, 8.0), headers=h, timeout=30).json()
        seen: list[float] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            d = httpx.get(f"{srv.url}/api/v1/plans/{hopeless['id']}", headers=h, timeout=10).json()
            if d["status"] not in ("queued", "running"):
                break
            if d["stage"] == "search":
                seen.append(d["progress"])
            time.sleep(0.25)
        # Whichever ends the hopeless search first, the refusal says which it was.
        ended_by = {"no_path_within_time_limit": "time_limit", "no_path_within_budget": "work_budget"}
        assert d["status"] == "failed" and d["reason"] in ended_by, d
        assert d["result"]["details"]["ended_by"] == ended_by[d["reason"]]
        # Progress never goes back, and it moves while the search runs (ticks at least twice a second
        # from the search's checks): seen for 2 s or more (8 polls), it took more than one value.
        assert seen and seen == sorted(seen) and min(seen) >= 0.15, seen
        assert len(seen) < 8 or len(set(seen)) >= 3, seen
        assert httpx.get(f"{srv.url}/api/v1/plans/{first.json()['id']}", headers=h).json()["status"] == (
            "succeeded"
        )

        # A request that declares a body and stalls is answered 408 after the body timeout (1 s here).
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as sock:
            sock.sendall(
                f"POST /api/v1/plans HTTP/1.1\r\nHost: x\r\nX-API-Key: {key}\r\n"
                'Content-Type: application/json\r\nContent-Length: 400\r\n\r\n{"name":'.encode()
            )
            t0 = time.monotonic()
            answer = _read_response(sock)
            waited = time.monotonic() - t0
        assert answer.startswith("HTTP/1.1 408"), answer
        assert "urn:cabinplan:problem:body_timeout" in answer and 0.8 < waited < 5.0

        metrics = httpx.get(f"{srv.url}/metrics", timeout=10)
        assert metrics.status_code == 200 and metrics.headers["content-type"].startswith("text/plain")
        text = metrics.text
        assert 'cabinplan_jobs_finished_total{reason="",status="succeeded"} 1.0' in text
        assert f'cabinplan_jobs_finished_total{{reason="{d["reason"]}",status="failed"}} 1.0' in text
        assert 'cabinplan_job_duration_seconds_count{status="succeeded"} 1.0' in text
        assert "cabinplan_jobs_queued 0.0" in text and "cabinplan_instance_jobs_running 0.0" in text
        assert "cabinplan_warming_up 0.0" in text
        warmup = [ln for ln in text.splitlines() if ln.startswith("cabinplan_warmup_seconds ")]
        assert len(warmup) == 1 and float(warmup[0].split()[1]) > 0.0
        assert 'route="/api/v1/plans/{plan_id}"' in text  # route templates, not raw paths
    finally:
        srv.stop()
    lines = [json.loads(ln) for ln in srv.log.read_text().splitlines() if ln.startswith('{"time"')]
    polls = [e for e in lines if e["route"] == "/api/v1/plans/{plan_id}" and e["method"] == "GET"]
    assert polls and all(e["tenant"] == "local" and e["status"] == 200 for e in polls)
    assert all(e["latency_ms"] >= 0 and len(e["request_id"]) > 0 for e in lines)
    tagged = [e for e in lines if e["request_id"] == "ops-test-1"]
    assert {e["route"] for e in tagged} >= {"/api/v1/plans", "/api/v1/plans/{plan_id}"}
    assert any(e["route"] == "/api/v1/ready" and e["status"] == 503 and e["tenant"] is None for e in lines)


# ----------------------------------------------------------------------------- typed API


def test_yaml_bodies_plan_the_same_scenario_as_json(idle: Service) -> None:
    text = (SCENARIOS / "aisle-bay-insert.yaml").read_text()
    as_yaml = idle.client.post(
        "/api/v1/plans", content=text, headers={**idle.h(), "Content-Type": "application/yaml"}
    )
    as_json = idle.client.post("/api/v1/plans", json=yaml.safe_load(text), headers=idle.h())
    assert as_yaml.status_code == as_json.status_code == 202, as_yaml.text
    assert as_yaml.json()["provenance"]["scenario_sha256"] == as_json.json()["provenance"]["scenario_sha256"]
    bad = _problem(
        idle.client.post(
            "/api/v1/plans", content="name: [x\n", headers={**idle.h(), "Content-Type": "application/yaml"}
        ),
        400,
        "malformed_body",
    )
    assert "invalid YAML at line" in bad["detail"]
    bomb = "a: &a [1, 2]\nb: [*a, *a]\n"
    refused = _problem(
        idle.client.post("/api/v1/plans", content=bomb, headers={**idle.h(), "Content-Type": "text/yaml"}),
        400,
        "malformed_body",
    )
    assert "line 2, column 5: aliases are not accepted" in refused["detail"], refused["detail"]
    twice = _problem(
        idle.client.post(
            "/api/v1/plans", content="name: a\nname: b\n", headers={**idle.h(), "Content-Type": "text/yaml"}
        ),
        400,
        "malformed_body",
    )
    assert "duplicate key 'name'" in twice["detail"], twice["detail"]
    _problem(
        idle.client.post("/api/v1/plans", content=text, headers={**idle.h(), "Content-Type": "text/csv"}),
        415,
        "unsupported_media_type",
    )
    for r in (as_yaml, as_json):
        assert idle.client.delete(f"/api/v1/plans/{r.json()['id']}", headers=idle.h()).status_code == 200


def test_one_problem_type_per_kind_of_error(idle: Service) -> None:
    h = {**idle.h(), "Content-Type": "application/json"}
    for path in ("/api/v1/plans", "/api/v1/kinematics/fk"):
        _problem(idle.client.post(path, content=b'{"a": ', headers=h), 400, "malformed_body")
        _problem(idle.client.post(path, content=b'{"name": "\xff\xfe"}', headers=h), 400, "malformed_body")
    limit = make_settings(Path("/nonexistent")).max_body_bytes
    declared = idle.client.post("/api/v1/plans", content=b"x" * (limit + 1), headers=h)
    _problem(declared, 413, "payload_too_large")

    def chunks() -> Iterator[bytes]:
        for _ in range(limit // 65536 + 2):
            yield b" " * 65536

    streamed = idle.client.post("/api/v1/plans", content=chunks(), headers=h)
    _problem(streamed, 413, "payload_too_large")


def test_absurd_values_and_seeds_are_invalid_input_naming_the_field(idle: Service) -> None:
    heavy = scenario("aisle-bay-insert")
    heavy["payload"]["mass"] = 1e308
    body = _problem(idle.client.post("/api/v1/plans", json=heavy, headers=idle.h()), 422, "invalid_input")
    assert body["errors"][0]["field"] == "payload.mass"
    huge = scenario("aisle-bay-insert")
    huge["payload"]["box"] = [1e300, 0.3, 0.3]
    body = _problem(idle.client.post("/api/v1/plans", json=huge, headers=idle.h()), 422, "invalid_input")
    assert body["errors"][0]["field"] == "payload.box[0]"
    seeds = {"/api/v1/plans": ("options.seed", free_transfer(seed=2**31))}
    pose = {"position": [1.0, 0.5, 1.5], "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}}
    seeds["/api/v1/kinematics/ik"] = ("seed", {"robot": "cabin8", "pose": pose, "seed": 2**31})
    for path, (field, data) in seeds.items():
        body = _problem(idle.client.post(path, json=data, headers=idle.h()), 422, "invalid_input")
        assert [e["field"] for e in body["errors"]] == [field], body
    ok = free_transfer(seed=2**31 - 1)  # the same largest seed everywhere
    r = idle.client.post("/api/v1/plans", json=ok, headers=idle.h())
    assert r.status_code == 202, r.text
    assert idle.client.delete(f"/api/v1/plans/{r.json()['id']}", headers=idle.h()).status_code == 200


def test_openapi_publishes_the_scenario_schema_and_every_problem_status(idle: Service) -> None:
    doc = idle.client.get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    assert {"robot", "start", "goal", "options", "payload", "cabin"} <= set(schemas["Scenario"]["properties"])
    mass = schemas["scenario.PayloadSpec"]["properties"]["mass"]
    assert mass["maximum"] == 10_000.0
    body = doc["paths"]["/api/v1/plans"]["post"]["requestBody"]["content"]
    assert set(body) == {"application/json", "application/yaml"}
    assert all(v["schema"] == {"$ref": "#/components/schemas/Scenario"} for v in body.values())
    text = json.dumps(doc)
    for ref in set(part.split('"')[0] for part in text.split('"$ref": "#/components/schemas/')[1:]):
        assert ref in schemas, ref  # every reference resolves
    for path, item in doc["paths"].items():
        for method, op in item.items():
            responses = op["responses"]
            codes = set(responses)
            assert {"422", "500"} <= codes, (path, method)
            if op.get("security"):
                assert {"401", "429"} <= codes, (path, method)
            if "{" in path:
                assert "404" in codes, (path, method)
            for code, entry in responses.items():
                if code[0] in "45":
                    assert set(entry["content"]) == {PROBLEM}, (path, method, code)
    assert "409" in doc["paths"]["/api/v1/plans/{plan_id}"]["delete"]["responses"]
    assert "403" in doc["paths"]["/api/v1/keys"]["post"]["responses"]
    assert "503" in doc["paths"]["/api/v1/ready"]["get"]["responses"]


# ----------------------------------------------------------------------------- abuse limits


def test_rate_limit_is_per_tenant_with_retry_after(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, rate_limit="5 per 2 seconds")
    for svc in start_idle_service(settings):
        answers = [svc.client.get("/api/v1/robots", headers=svc.h()).status_code for _ in range(5)]
        assert answers == [200] * 5
        limited = svc.client.get("/api/v1/robots", headers=svc.h())
        body = _problem(limited, 429, "rate_limited")
        wait_s = int(limited.headers["retry-after"])
        assert 1 <= wait_s <= 2 and "5 per 2 seconds" in body["detail"]
        assert svc.client.get("/api/v1/robots", headers=svc.h("beta")).status_code == 200  # per tenant
        time.sleep(wait_s + 0.1)
        assert svc.client.get("/api/v1/robots", headers=svc.h()).status_code == 200
        metrics = svc.client.get("/metrics").text
        assert "cabinplan_rate_limited_requests_total 1.0" in metrics


def test_admin_keys_cannot_be_made_for_the_local_or_admin_tenant(idle: Service) -> None:
    admin = {"X-API-Key": ADMIN_KEY}
    for tenant in ("local", "admin"):
        body = _problem(
            idle.client.post("/api/v1/keys", json={"tenant": tenant}, headers=admin), 422, "invalid_input"
        )
        assert body["errors"] == [{"field": "tenant", "reason": "reserved"}]
    assert idle.client.post("/api/v1/keys", json={"tenant": "gamma"}, headers=admin).status_code == 201


# ----------------------------------------------------------------------------- retention and storage


def _job(status: str, finished_days_ago: float | None) -> Job:
    t = now_s()
    return Job(
        id=uuid.uuid4().hex,
        tenant="t",
        status=status,
        scenario={},
        scenario_name="x",
        request_sha256="0" * 64,
        meshes={},
        provenance={},
        time_limit_s=1.0,
        created_at=t - 40 * 86400,
        finished_at=None if finished_days_ago is None else t - finished_days_ago * 86400,
    )


def test_retention_deletes_only_finished_plans_older_than_the_setting(tmp_path: Path) -> None:
    assert Settings(data_dir=tmp_path).retention_days == 30.0
    db = Database(f"sqlite:///{tmp_path / 'r.db'}")
    db.create_all()
    rows = {
        "old_succeeded": _job("succeeded", 31),
        "old_failed": _job("failed", 45),
        "recent": _job("succeeded", 29),
        "queued": _job("queued", None),
        "running": _job("running", None),
    }
    with db.session() as s:
        s.add_all(rows.values())
    assert purge_expired(db, 30 * 86400.0) == 2
    with db.session() as s:
        left = set(s.scalars(select(Job.id)))
    assert left == {rows[k].id for k in ("recent", "queued", "running")}
    db.dispose()


def test_compact_documents_round_trip_exactly() -> None:
    doc = {
        "t": [0.004 * k for k in range(40)],
        "position": [[float(k) / 3, -1e-300, 1e300, 0.1] for k in range(20)],
        "ints": list(range(30)),
        "mixed": [1.5] * 20 + [2],
        "short": [0.1, 0.2],
        "ragged": [[0.5] * 10, [0.5] * 9],
        "nan": [float("nan")] * 20,
        "nested": {"a": [True, None, "x"], "b": [[1.0, 2.0]] * 10},
        "empty": [],
    }
    text = json.dumps(doc)
    for blob in (pack_document(text), pack_value(doc)):
        back = unpack_document(blob)
        assert json.dumps(back) == text  # every float bit for bit, ints as ints, NaN as NaN
        assert back["ints"] == doc["ints"] and type(back["ints"][0]) is int and back["mixed"][-1] == 2
        served = json.loads(unpack_text(blob))  # compact JSON: the same values, NaN written as null
        assert served == {**json.loads(text), "nan": [None] * 20}
        assert all(a == b for a, b in zip(served["t"], doc["t"], strict=True))


def test_numpy_arrays_pack_as_their_lists_and_the_worker_text_is_the_served_text() -> None:
    rng = np.random.default_rng(3)
    arrays = {
        "t": np.cumsum(rng.random(300)),
        "position": rng.normal(size=(300, 8)) * 1e3,
        "single": rng.random(40).astype(np.float32),  # packed as float64, as its tolist() would be
        "short": rng.random(5),  # below MIN_PACKED_FLOATS: stays in the skeleton, as its list would
        "narrow": rng.random((3, 2)),
        "ints": np.arange(30),  # not floats: a list of ints
        "empty": np.zeros((0, 8)),
        "view": rng.random((50, 8))[:, ::2],  # not contiguous
        "nested": {"deep": [rng.random(20), {"x": rng.random((4, 4))}]},
    }

    def as_lists(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: as_lists(x) for k, x in v.items()}
        if isinstance(v, list):
            return [as_lists(x) for x in v]
        return v.tolist() if isinstance(v, np.ndarray) else v

    doc = {"status": "succeeded", "n": 3, "duration_s": 1.25, **arrays}
    lists = as_lists(doc)
    assert pack_value(doc) == pack_value(lists)  # the same blob, whichever form the document had
    text = unpack_json(pack_value(doc))
    assert document_json(doc) == document_json(lists) == text  # what the worker sends is what is served
    assert unpack_text(pack_value(doc)) == text.decode()
    assert json.loads(text) == json.loads(json.dumps(lists))
    assert document_json({"big": 2**70}) is None  # orjson cannot: the server unpacks the blob instead
    assert json.loads(unpack_json(pack_value({"big": 2**70}))) == {"big": 2**70}  # and writes its JSON


def test_packed_documents_of_earlier_formats_are_still_read() -> None:
    import lzma
    import zlib

    import zstandard

    doc = {"t": [0.004 * k for k in range(40)], "name": "x", "q": [[0.5 * k, -k / 7] for k in range(20)]}
    blob = pack_value(doc)
    assert blob[:4] == b"CPD3"
    body = zstandard.ZstdDecompressor().decompress(blob[8:])
    for magic, compress in ((b"CPD2", zlib.compress), (b"CPD1", lzma.compress)):
        old = magic + blob[4:8] + compress(body)
        assert unpack_document(old) == doc and unpack_text(old) == unpack_text(blob)
    with pytest.raises(ValueError, match="not a packed"):
        unpack_document(b"CPD9" + blob[4:])


def test_finished_plans_are_stored_compact_served_as_json_and_csv_and_deleted(tmp_path: Path) -> None:
    for svc in start_service(make_settings(tmp_path)):
        r = svc.client.post("/api/v1/plans", json=scenario("aisle-bay-insert"), headers=svc.h())
        doc = wait_for(svc.client, svc.h(), r.json()["id"], timeout_s=300)
        assert doc["status"] == "succeeded", doc["message"]
        text = svc.client.get(f"/api/v1/plans/{doc['id']}", headers=svc.h()).text
        result = json.loads(text)["result"]
        csv = svc.client.get(f"/api/v1/plans/{doc['id']}/profile.csv", headers=svc.h())
        png = svc.client.get(f"/api/v1/plans/{doc['id']}/plot.png", headers=svc.h())
        assert csv.status_code == png.status_code == 200
        rows = [line.split(",") for line in csv.text.strip().splitlines()]
        table = np.array(rows[1:], dtype=float)
        assert rows[0][0] == "t_s" and table.shape == (
            len(result["t"]),
            1 + 5 * 8,
        )  # t; pos, vel, acc, jerk, effort
        for k, name in enumerate(("position", "velocity", "acceleration", "jerk", "effort")):
            got = table[:, 1 + 8 * k : 9 + 8 * k]
            np.testing.assert_allclose(got, np.array(result[name]), rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(table[:, 0], result["t"], rtol=1e-8, atol=1e-12)
        # Stored: the packed document and the plot (made on its first request, then kept). Served: the
        # JSON text, the CSV (made from the document) and the plot.
        ctx = svc.client.app.state.ctx  # type: ignore[attr-defined]
        plot = ctx.jobs.stored_file(doc["id"], "plot.png")
        assert plot == png.content and ctx.jobs.stored_file(doc["id"], "profile.csv") is None
        with ctx.db.session() as s:
            row = s.get(Job, doc["id"])
            stored = len(row.result_packed) + len(plot)
            assert row.result_json is None and row.profile_csv is None and row.plot_png is None
            # the worker's text, kept by the runner, served on the first read: the stored blob's text
            assert results.recall(doc["id"]) == unpack_json(row.result_packed)
            assert text.endswith(f',"result":{unpack_text(row.result_packed)}}}')
            results.forget(doc["id"])  # and a read after a restart (unpacked from storage): the same text
            assert svc.client.get(f"/api/v1/plans/{doc['id']}", headers=svc.h()).text == text
        as_text = len(json.dumps(result).encode()) + len(csv.content) + len(png.content)
        assert as_text / stored >= 5.0, (as_text, stored)
        # DELETE of a finished plan deletes it.
        assert svc.client.delete(f"/api/v1/plans/{doc['id']}", headers=svc.h()).status_code == 204
        _problem(svc.client.get(f"/api/v1/plans/{doc['id']}", headers=svc.h()), 404, "not_found")
        _problem(svc.client.delete(f"/api/v1/plans/{doc['id']}", headers=svc.h()), 404, "not_found")
