"""Assembly cycles and campaigns over HTTP: the served cycle is the planner's, bad input names its field.

One cycle (the example file ``tests/cycles/aisle-install-A3.yaml``, sent as YAML as it is) is planned by
the service once per module and compared, array for array, with the same file planned in this process.
Campaign runs (per-unit progress, a server killed mid-way) are in ``test_cycle_live.py``.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from api.examples import aisle_campaign, aisle_cycle
from planner.task.cycle import CycleResult, plan_cycle
from planner.task.legs import LEG_NAMES
from planner.task.resolve import ResolvedCycle, load_cycle
from tests.api.conftest import Service, box_stl, make_settings, start_idle_service, start_service

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "tests" / "cycles" / "aisle-install-A3.yaml"


def _wait(svc: Service, collection: str, job_id: str, timeout_s: float = 300.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        doc: dict[str, Any] = svc.client.get(f"/api/v1/{collection}/{job_id}", headers=svc.h()).json()
        if doc["status"] not in ("queued", "running"):
            return doc
        assert time.monotonic() < deadline, f"{collection} {job_id} still {doc['status']}"
        time.sleep(0.1)


class Planned:
    def __init__(self, svc: Service, job: dict[str, Any], cyc: ResolvedCycle, local: CycleResult) -> None:
        self.svc = svc
        self.job = job
        self.cyc = cyc
        self.local = local


@pytest.fixture(scope="module")
def svc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_service(make_settings(tmp_path_factory.mktemp("cycles")))


@pytest.fixture(scope="module")
def planned(svc: Service) -> Planned:
    """The example file planned by the service (as YAML, verbatim) and, meanwhile, in this process."""
    r = svc.client.post(
        "/api/v1/cycles",
        content=EXAMPLE.read_bytes(),
        headers={**svc.h(), "Content-Type": "application/yaml"},
    )
    assert r.status_code == 202, r.text
    assert r.headers["Location"] == f"/api/v1/cycles/{r.json()['id']}"
    cyc = load_cycle(EXAMPLE)
    local = plan_cycle(cyc)
    job = _wait(svc, "cycles", r.json()["id"])
    assert job["status"] == "succeeded", (job["reason"], job["message"])
    return Planned(svc, job, cyc, local)


def test_served_cycle_is_the_in_process_plan_of_the_same_file(planned: Planned) -> None:
    doc, local, cyc = planned.job["result"], planned.local, planned.cyc
    assert planned.job["cycle"] == {"name": "aisle-install-A3", "sha256": cyc.sha256}
    assert doc["kind"] == "cycle" and doc["cycle"]["sha256"] == cyc.sha256
    for key, ours in (
        ("t", local.profile.t),
        ("position", local.profile.position),
        ("velocity", local.profile.velocity),
        ("acceleration", local.profile.acceleration),
        ("effort", local.profile.effort),
    ):
        served = np.asarray(doc[key], dtype=float)
        assert served.shape == np.shape(ours), key
        assert np.array_equal(served, np.asarray(ours)), f"{key}: max |diff| {np.max(np.abs(served - ours))}"
    assert doc["leg"] == local.leg_of.tolist()
    assert doc["legs"] == [x.to_dict() for x in local.legs]
    assert [e["springback_m"] for e in doc["events"]] == [e.springback_m for e in local.events]
    # The contract: the legs in order, contiguous, each sample's leg index inside its leg's range.
    assert [x["name"] for x in doc["legs"]] == list(LEG_NAMES)
    leg = np.asarray(doc["leg"])
    for k, x in enumerate(doc["legs"]):
        assert np.all(leg[x["sample_start"] : x["sample_end"]] == k)
        if k:
            assert x["sample_start"] == doc["legs"][k - 1]["sample_end"]
    assert doc["legs"][-1]["sample_end"] == len(doc["t"])
    assert [(e["kind"], e["leg"], e["unit"]) for e in doc["events"]] == [
        ("attach", "grasp", "A3"),
        ("detach", "release", "A3"),
    ]
    # At rest through each dwell: zero velocity on every drive.
    for name in ("grasp", "release"):
        x = next(x for x in doc["legs"] if x["name"] == name)
        v = np.asarray(doc["velocity"])[x["sample_start"] : x["sample_end"]]
        assert np.all(v == 0.0), name
    assert doc["report"]["gate"]["passed"] is True
    assert doc["min_clearance_m"] >= cyc.base.options.clearance_m - 1e-12
    assert planned.job["progress"] == 1.0


def test_cycle_csv_plot_and_scene_follow_the_document(planned: Planned) -> None:
    svc, job, cyc = planned.svc, planned.job, planned.cyc
    doc = job["result"]
    links = job["links"]
    r = svc.client.get(links["profile_csv"], headers=svc.h())
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    rows = list(csv.reader(io.StringIO(r.text)))
    header, body = rows[0], rows[1:]
    assert header[:3] == ["t_s", "leg", "d1_pos_m"]
    assert len(body) == len(doc["t"])
    names = [x["name"] for x in doc["legs"]]
    for k in (0, len(body) // 3, len(body) // 2, len(body) - 1):
        assert abs(float(body[k][0]) - doc["t"][k]) <= 1e-9 * max(1.0, doc["t"][k])
        assert body[k][1] == names[doc["leg"][k]]
        assert abs(float(body[k][2]) - doc["position"][k][0]) <= 1e-8
    png = svc.client.get(links["plot_png"], headers=svc.h())
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"

    scene = svc.client.get(f"/api/v1/cycles/{job['id']}/scene", headers=svc.h()).json()
    assert scene["kind"] == "cycle" and len(scene["cycles"]) == 1
    assert [x["name"] for x in scene["cycles"][0]["legs"]] == names
    frames = scene["frames"]
    q = np.asarray(planned.local.profile.joints)
    T_unit_box = np.linalg.inv(cyc.T_base_unit_dock) @ cyc.dock_unit.T_base_obstacle
    release = next(x for x in doc["legs"] if x["name"] == "release")
    grasp = next(x for x in doc["legs"] if x["name"] == "grasp")
    held = after = before = 0
    for i, s in enumerate(frames["sample"]):
        pose = frames["unit_pose"][i]
        p, R = np.asarray(pose["position"]), np.asarray(pose["rotation"])
        if grasp["sample_start"] <= s < release["sample_start"]:  # held: where the tool's grasp puts it
            T = cyc.robot.fk(q[s]) @ cyc.T_tool_unit @ T_unit_box
            held += 1
            assert frames["unit_held"][i] is True
        elif s >= release["sample_start"]:  # released: fixed at its bay, whatever the robot does
            T = cyc.bay_unit.T_base_obstacle
            after += 1
        else:
            T = cyc.dock_unit.T_base_obstacle
            before += 1
        assert np.max(np.abs(p - T[:3, 3])) < 1e-9 and np.max(np.abs(R - T[:3, :3])) < 1e-9, (i, s)
        assert frames["leg"][i] == doc["leg"][s]
    assert held > 50 and after > 20 and before > 20
    # The drawn unit at the release equals the unit held at the end of the insertion to the spring-back:
    # the held unit's last frame is within the detach event's jump (plus the frame spacing's motion: none,
    # the robot rests) of the bay pose.
    last_held = max(i for i, s in enumerate(frames["sample"]) if s < release["sample_start"])
    jump = np.linalg.norm(
        np.asarray(frames["unit_pose"][last_held]["position"]) - cyc.bay_unit.T_base_obstacle[:3, 3]
    )
    assert jump < 0.005
    assert [u["name"] for u in scene["installed"]] == ["unit A2", "unit A4"]
    assert min(d for d in scene["clearance"]["distance_m"] if d is not None) >= 0.0


def _problem(r: Any, field: str) -> dict[str, Any]:
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    body: dict[str, Any] = r.json()
    assert field in [e["field"] for e in body["errors"]], body
    return body


def test_bad_cycles_and_campaigns_are_422_naming_the_field(svc: Service, planned: Planned) -> None:
    c, h = svc.client, svc.h()  # ``planned``: the one cycle job the counts below must find
    overlap = aisle_cycle()
    a2 = overlap["installed"][0]
    shifted = {**a2["pose"], "position": [a2["pose"]["position"][0], 0.7, a2["pose"]["position"][2] + 0.1]}
    overlap["installed"].append({"id": "B7", "box": [0.24, 0.35, 0.45], "pose": shifted})
    body = _problem(c.post("/api/v1/cycles", json=overlap, headers=h), "installed")
    assert "unit A2" in body["detail"] and "unit B7" in body["detail"], body["detail"]

    occupied = aisle_cycle()
    occupied["installed"].append({"id": "B7", "box": [0.24, 0.35, 0.45], "pose": occupied["bay"]["pose"]})
    body = _problem(c.post("/api/v1/cycles", json=occupied, headers=h), "bay.pose")
    assert "unit B7" in body["detail"]

    no_mass = aisle_cycle()
    no_mass["unit"]["mass"] = -1
    _problem(c.post("/api/v1/cycles", json=no_mass, headers=h), "unit.mass")

    server_file = aisle_cycle()
    server_file["unit"] = {**server_file["unit"], "box": None, "mesh": "/etc/hostname"}
    server_file["unit"].pop("box")
    body = _problem(c.post("/api/v1/cycles", json=server_file, headers=h), "unit.mesh")
    assert "uploaded mesh" in body["detail"]

    slow = aisle_cycle()
    slow["options"]["time_limit_s"] = 10_000
    _problem(c.post("/api/v1/cycles", json=slow, headers=h), "options.time_limit_s")

    same_bay = aisle_campaign()
    same_bay["units"][1]["bay"] = same_bay["units"][0]["bay"]
    body = _problem(c.post("/api/v1/campaigns", json=same_bay, headers=h), "units")
    assert "unit A3 (units[0])" in body["detail"] and "unit A5 (units[1])" in body["detail"], body["detail"]
    assert sorted(body["details"]["units"]) == ["unit A3", "unit A5"]

    on_fixture = aisle_campaign()
    on_fixture["units"][1]["dock"]["pose"]["position"] = on_fixture["units"][1]["dock"]["fixture"]["pose"][
        "position"
    ]
    _problem(c.post("/api/v1/campaigns", json=on_fixture, headers=h), "units[1].dock.pose")

    twice = aisle_campaign()
    twice["units"][1]["unit"]["id"] = "A3"
    _problem(c.post("/api/v1/campaigns", json=twice, headers=h), "units[1].unit.id")
    assert c.get("/api/v1/cycles", headers=h).json()["total"] >= 1  # the planned one only: none queued
    assert c.get("/api/v1/campaigns", headers=h).json()["total"] == 0


def test_cancel_a_running_cycle(svc: Service, planned: Planned) -> None:
    c, h = svc.client, svc.h()
    r = c.post("/api/v1/cycles", json=aisle_cycle(), headers=h)
    assert r.status_code == 202
    job_id = r.json()["id"]
    deadline = time.monotonic() + 60
    while c.get(f"/api/v1/cycles/{job_id}", headers=h).json()["status"] != "running":
        assert time.monotonic() < deadline
        time.sleep(0.05)
    gone = c.delete(f"/api/v1/cycles/{job_id}", headers=h)
    assert gone.status_code == 200 and gone.json()["status"] == "cancelled"
    assert c.get(f"/api/v1/cycles/{job_id}/profile.csv", headers=h).status_code == 404
    assert c.delete(f"/api/v1/cycles/{job_id}", headers=h).status_code == 204
    assert c.get(f"/api/v1/cycles/{job_id}", headers=h).status_code == 404
    # A plan's id is not a cycle and the other tenant sees nothing of alpha's cycles.
    assert c.get(f"/api/v1/plans/{planned.job['id']}", headers=h).status_code == 404
    assert c.get(f"/api/v1/cycles/{planned.job['id']}", headers=svc.h("beta")).status_code == 404


def test_idempotency_quota_and_cancel_of_queued_jobs(tmp_path: Path) -> None:
    for svc in start_idle_service(make_settings(tmp_path, tenant_max_active_jobs=3)):
        c, h = svc.client, svc.h()
        first = c.post("/api/v1/campaigns", json=aisle_campaign(), headers={**h, "Idempotency-Key": "k1"})
        assert first.status_code == 202
        again = c.post("/api/v1/campaigns", json=aisle_campaign(), headers={**h, "Idempotency-Key": "k1"})
        assert again.status_code == 200 and again.headers["Idempotent-Replayed"] == "true"
        assert again.json()["id"] == first.json()["id"]
        other = aisle_campaign()
        other["order"] = "find"
        reused = c.post("/api/v1/campaigns", json=other, headers={**h, "Idempotency-Key": "k1"})
        assert reused.status_code == 422 and reused.json()["errors"][0]["field"] == "Idempotency-Key"
        cyc = c.post(
            "/api/v1/cycles",
            content=yaml.safe_dump(aisle_cycle()),
            headers={**h, "Content-Type": "application/yaml"},
        )
        assert cyc.status_code == 202 and cyc.json()["cycle"]["name"] == "aisle-install-A3"
        # The job's hard limit: three searched legs (pre-grasp, transit, park) of 30 s; a campaign's
        # is that for each of its cycles.
        assert cyc.json()["time_limit_s"] == 90.0 and first.json()["time_limit_s"] == 180.0
        third = c.post("/api/v1/cycles", json=aisle_cycle(), headers=h)
        assert third.status_code == 202
        over = c.post("/api/v1/cycles", json=aisle_cycle(), headers=h)  # plans, cycles, campaigns: one quota
        assert over.status_code == 429 and int(over.headers["Retry-After"]) > 0
        assert over.json()["limit"] == 3 and over.json()["active_jobs"] == 3
        assert c.post("/api/v1/cycles", json=aisle_cycle(), headers=svc.h("beta")).status_code == 202
        cancelled = c.delete(f"/api/v1/campaigns/{first.json()['id']}", headers=h)
        assert cancelled.status_code == 200 and cancelled.json()["status"] == "cancelled"
        assert c.post("/api/v1/cycles", json=aisle_cycle(), headers=h).status_code == 202  # room again
        listed = c.get("/api/v1/campaigns?status=cancelled", headers=h).json()
        assert [j["id"] for j in listed["items"]] == [first.json()["id"]]
        assert listed["items"][0]["campaign"]["name"] == "aisle-A3-A5"


def test_openapi_publishes_the_cycle_and_campaign_schemas(svc: Service) -> None:
    doc = svc.client.get("/openapi.json").json()
    schemas = doc["components"]["schemas"]
    assert {"unit", "dock", "bay", "park", "retract"} <= set(schemas["Cycle"]["properties"])
    assert {"units", "order", "installed"} <= set(schemas["Campaign"]["properties"])
    for path, name in (("/api/v1/cycles", "Cycle"), ("/api/v1/campaigns", "Campaign")):
        body = doc["paths"][path]["post"]["requestBody"]["content"]
        assert body["application/yaml"]["schema"] == {"$ref": f"#/components/schemas/{name}"}
    for path in ("/api/v1/cycles/{job_id}/profile.csv", "/api/v1/campaigns/{job_id}/units.csv"):
        assert "get" in doc["paths"][path]


def test_meshes_of_a_cycle_resolve_through_the_tenants_store(tmp_path: Path) -> None:
    """An installed unit given as an uploaded mesh: accepted by its id, refused by another tenant or unit."""
    for svc in start_idle_service(make_settings(tmp_path)):
        c, h = svc.client, svc.h()
        files = {"file": ("A9.stl", box_stl((0.24, 0.35, 0.45)), "model/stl")}
        up = c.post("/api/v1/cabins", files=files, data={"units": "m", "name": "A9"}, headers=h)
        assert up.status_code == 201, up.text
        mesh_id = up.json()["id"]
        body = aisle_cycle()
        a4 = body["installed"][1]
        body["installed"][1] = {"id": "A9", "mesh": mesh_id, "units": "m", "pose": a4["pose"]}
        ok = c.post("/api/v1/cycles", json=body, headers=h)
        assert ok.status_code == 202, ok.text
        job = c.app.state.ctx.jobs.get("alpha", ok.json()["id"])  # type: ignore[attr-defined]
        assert list(job.meshes) == [mesh_id]
        # Not this tenant's mesh: the field named, nothing read from the server's disk.
        _problem(c.post("/api/v1/cycles", json=body, headers=svc.h("beta")), "installed[1].mesh")
        body["installed"][1]["units"] = "mm"
        _problem(c.post("/api/v1/cycles", json=body, headers=h), "installed[1].units")
