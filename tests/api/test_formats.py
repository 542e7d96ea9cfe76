"""The service end to end with the factory's files: a STEP cabin uploaded, planned in, exported.

A STEP cabin (an assembly in mm, written by the test) goes through ``POST /cabins``; bad STEP uploads are
422 naming the file and the reason while the service keeps serving; a plan in the STEP cabin succeeds
with the tessellation's deviation added to its clearance; ``GET /plans/{id}/trajectory`` serves the
FollowJointTrajectory goal and the MCAP file, read back and compared number by number with the plan.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from tests.api.conftest import Service, free_transfer, make_settings, start_service, wait_for
from tests.meshio.step_text import box_cabin_parts, step_text


@pytest.fixture(scope="module")
def svc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_service(make_settings(tmp_path_factory.mktemp("formats"), workers=1))


@pytest.fixture(scope="module")
def step_cabin(svc: Service) -> dict[str, Any]:
    data = step_text(box_cabin_parts(), "mm", assembly="cabin").encode()
    r = svc.client.post("/api/v1/cabins", files={"file": ("cabin.step", data)}, headers=svc.h())
    assert r.status_code == 201, r.text
    return r.json()


@pytest.fixture(scope="module")
def planned(svc: Service, step_cabin: dict[str, Any]) -> dict[str, Any]:
    body = free_transfer(d1_goal=2.2)
    body["cabin"] = {"mesh": step_cabin["id"]}
    r = svc.client.post("/api/v1/plans", json=body, headers=svc.h())
    assert r.status_code == 202, r.text
    doc = wait_for(svc.client, svc.h(), r.json()["id"], timeout_s=240)
    assert doc["status"] == "succeeded", doc
    return doc


def test_step_upload_is_tessellated_with_its_units_and_placements(step_cabin: dict[str, Any]) -> None:
    np.testing.assert_allclose(step_cabin["bounds_min_m"], [-1.24, -0.2, -0.54], atol=1e-6)
    np.testing.assert_allclose(step_cabin["bounds_max_m"], [1.24, 1.84, 6.54], atol=1e-6)
    assert step_cabin["format"] == "step" and step_cabin["file_units"] == "mm"
    assert 1e-4 <= step_cabin["surface_deviation_m"] < 1.01e-4


@pytest.mark.parametrize(
    ("data", "check"),
    [
        (step_text(box_cabin_parts(), "mm", assembly="cabin").encode()[:-300], "truncated"),
        (b"not a step file at all\n", "content"),
        (b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n", "empty"),
        (
            re.sub(
                rb"#(\d+)=ORIENTED_EDGE\('',\*,\*,#\d+,",
                rb"#\1=ORIENTED_EDGE('',*,*,#\1,",
                step_text(box_cabin_parts()[:1], "mm").encode(),
                count=1,
            ),
            "self_reference",
        ),
    ],
    ids=["truncated", "not-step", "empty", "self-reference"],
)
def test_bad_step_uploads_are_422_naming_file_and_reason(svc: Service, data: bytes, check: str) -> None:
    r = svc.client.post("/api/v1/cabins", files={"file": ("bad.stp", data)}, headers=svc.h())
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["details"]["check"] == check and "bad.stp" in body["detail"]
    assert svc.client.get("/api/v1/health", headers=svc.h()).status_code == 200


def test_plan_in_a_step_cabin_adds_the_tessellation_to_the_clearance(planned: dict[str, Any]) -> None:
    result = planned["result"]
    clearance = result["report"]["clearance"]
    dev = clearance["surface_deviation_m"]
    assert 1e-4 <= dev < 1.01e-4  # the default tolerance plus float32 rounding of a 7 m cabin
    assert clearance["certified_m"] == pytest.approx(clearance["requested_m"] + dev, abs=1e-15)
    assert result["min_clearance_m"] >= clearance["certified_m"]
    mesh = result["provenance"]["cabin_mesh"]
    assert (
        mesh["format"] == "step"
        and mesh["units"] == "mm"
        and mesh["sha256"] == planned["provenance"]["cabin_mesh_sha256"]
    )


def test_trajectory_exports_read_back_equal_to_the_plan(
    svc: Service, planned: dict[str, Any], tmp_path: Path
) -> None:
    result = planned["result"]
    url = f"/api/v1/plans/{planned['id']}/trajectory"
    as_json = svc.client.get(url, params={"format": "ros2-json"}, headers=svc.h())
    as_yaml = svc.client.get(url, params={"format": "ros2-yaml", "spacing_s": 0.1}, headers=svc.h())
    assert as_json.status_code == 200 and as_yaml.status_code == 200
    goal = as_json.json()
    points = goal["trajectory"]["points"]
    assert goal["trajectory"]["joint_names"] == result["drives"] and len(points) == len(result["t"])
    np.testing.assert_allclose([p["positions"] for p in points], result["position"], rtol=0, atol=1e-12)
    ns = np.array([p["time_from_start"]["sec"] * 10**9 + p["time_from_start"]["nanosec"] for p in points])
    assert np.all(np.abs(ns - (np.asarray(result["t"]) - result["t"][0]) * 1e9) <= 0.5)
    thinned = yaml.safe_load(as_yaml.content)["trajectory"]["points"]
    assert 2 <= len(thinned) < len(points) / 10
    mcap = svc.client.get(url, params={"format": "mcap"}, headers=svc.h())
    assert mcap.status_code == 200 and mcap.headers["content-type"] == "application/x-mcap"
    assert mcap.content[:8] == b"\x89MCAP0\r\n"  # the MCAP magic
    bad = svc.client.get(url, params={"format": "bag"}, headers=svc.h())
    assert bad.status_code == 422
    assert json.loads(svc.client.get("/api/v1/plans/nope/trajectory", headers=svc.h()).text)["status"] == 404
