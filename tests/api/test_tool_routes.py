"""The robot tool routes: pprs6 kinematics, workspace and drive profiles; cabin8 stiffness."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from planner.robots import load_robot
from tests.api.conftest import Service, make_settings, start_idle_service

PROBLEM = "application/problem+json"
PNG = b"\x89PNG\r\n\x1a\n"
POSE = {"x": -0.03, "y": -0.03, "z": 0.19, "phi": 0.0, "theta": 0.0, "psi": 0.2}
HOME = {"d1": 1.0, "x1": -0.46, "x2": 0.46, "x3": -0.09, "theta3": 1.2, "theta4": -0.8, "d5": -0.25}


@pytest.fixture(scope="module")
def svc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_idle_service(make_settings(tmp_path_factory.mktemp("tools")))


def _problem(r, status: int, field: str | None = None) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert "Traceback" not in r.text
    if field is not None:
        assert field in {e["field"] for e in body.get("errors", [])} or field in body["detail"], body
    return body


def test_pprs6_ik_then_fk_closes_the_loop(svc: Service) -> None:
    ik = svc.client.post("/api/v1/kinematics/ik", json={"robot": "pprs6", "pose": POSE}, headers=svc.h())
    assert ik.status_code == 200, ik.text
    drives = ik.json()["drives"]
    assert list(drives) == list(load_robot("pprs6").drive_names)
    # From a guess near the pose, FK returns that assembly mode: the round trip closes to 1e-9.
    guess = {**POSE, "x": POSE["x"] + 0.003, "psi": POSE["psi"] - 0.02}
    body = {"robot": "pprs6", "drives": drives, "guess": guess}
    fk = svc.client.post("/api/v1/kinematics/fk", json=body, headers=svc.h())
    assert fk.status_code == 200, fk.text
    pose = fk.json()["pose"]
    np.testing.assert_allclose([pose[k] for k in POSE], list(POSE.values()), atol=1e-9)
    # Without a guess it may be another assembly mode, but always one with these drives.
    other = svc.client.post(
        "/api/v1/kinematics/fk", json={"robot": "pprs6", "drives": drives}, headers=svc.h()
    )
    assert other.status_code == 200, other.text
    again = svc.client.post(
        "/api/v1/kinematics/ik", json={"robot": "pprs6", "pose": other.json()["pose"]}, headers=svc.h()
    ).json()["drives"]
    np.testing.assert_allclose(list(again.values()), list(drives.values()), atol=1e-9)
    cabin8 = {"robot": "cabin8", "drives": {**HOME, "theta6": 0.0}, "guess": POSE}
    _problem(svc.client.post("/api/v1/kinematics/fk", json=cabin8, headers=svc.h()), 422, "guess")


def test_pprs6_kinematics_refuse_what_does_not_fit_the_robot(svc: Service) -> None:
    tool_pose = {"position": [0.5, 0.8, 2.0]}
    _problem(
        svc.client.post("/api/v1/kinematics/ik", json={"robot": "pprs6", "pose": tool_pose}, headers=svc.h()),
        422,
        "pose",
    )
    _problem(
        svc.client.post("/api/v1/kinematics/ik", json={"robot": "cabin8", "pose": POSE}, headers=svc.h()),
        422,
        "pose",
    )
    near = {"robot": "pprs6", "pose": POSE, "near": {"w1": 0.1}}
    _problem(svc.client.post("/api/v1/kinematics/ik", json=near, headers=svc.h()), 422, "near")
    joints = {"robot": "pprs6", "joints": {"x": 0.0}}
    _problem(svc.client.post("/api/v1/kinematics/fk", json=joints, headers=svc.h()), 422, "joints")
    far = {"robot": "pprs6", "pose": {**POSE, "z": 0.6}}
    body = _problem(svc.client.post("/api/v1/kinematics/ik", json=far, headers=svc.h()), 422)
    assert body["reason"] == "outside_workspace"


def test_pprs6_workspace_json_and_png(svc: Service) -> None:
    body = {"orientation": {"phi": 0.0, "theta": 0.0, "psi": 0.0}, "step_m": 0.01}
    r = svc.client.post("/api/v1/robots/pprs6/workspace", json=body, headers=svc.h())
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["robot"] == "pprs6" and doc["volume_m3"] > 0
    r = svc.client.post("/api/v1/robots/pprs6/workspace?format=png", json=body, headers=svc.h())
    assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content.startswith(PNG)
    _problem(
        svc.client.post("/api/v1/robots/pprs6/workspace", json={"step_m": 0.001}, headers=svc.h()),
        422,
        "step_m",
    )
    assert svc.client.post("/api/v1/robots/pprs6/workspace", json=body).status_code == 401
    # Nothing reachable at a 1 rad yaw: a volume of 0 (extents null) and an empty picture, never a 500.
    empty = {"orientation": {"phi": 1.0}, "step_m": 0.01}
    r = svc.client.post("/api/v1/robots/pprs6/workspace", json=empty, headers=svc.h())
    assert r.status_code == 200, r.text
    assert r.json()["volume_m3"] == 0.0 and r.json()["extents_m"]["x"] == [None, None]
    r = svc.client.post("/api/v1/robots/pprs6/workspace?format=png", json=empty, headers=svc.h())
    assert r.status_code == 200 and r.content.startswith(PNG)


def test_pprs6_profile_of_the_paper_path_is_within_limits(svc: Service) -> None:
    r = svc.client.post("/api/v1/robots/pprs6/profiles", json={}, headers=svc.h())
    assert r.status_code == 200, r.text
    doc = r.json()
    lim = load_robot("pprs6").limits
    u, v, a = (np.array(doc[k]) for k in ("position", "velocity", "acceleration"))
    assert np.all(u >= lim.lower - 1e-9) and np.all(u <= lim.upper + 1e-9)
    assert np.all(np.abs(v) <= 1.01 * lim.v_max) and np.all(np.abs(a) <= 1.01 * lim.a_max)
    assert np.array_equal(v[0], np.zeros(6)) and np.array_equal(v[-1], np.zeros(6))
    png = svc.client.post("/api/v1/robots/pprs6/profiles?format=png", json={}, headers=svc.h())
    assert png.status_code == 200 and png.content.startswith(PNG)


def test_pprs6_profile_refuses_a_path_out_of_the_workspace(svc: Service) -> None:
    path = {"waypoints": [POSE, {**POSE, "z": 0.6}]}
    body = _problem(
        svc.client.post("/api/v1/robots/pprs6/profiles", json={"path": path}, headers=svc.h()), 422
    )
    assert body["reason"] == "outside_workspace"
    many = {"waypoints": [POSE] * 101}
    _problem(
        svc.client.post("/api/v1/robots/pprs6/profiles", json={"path": many}, headers=svc.h()),
        422,
        "path.waypoints",
    )


def test_stiffness_is_symmetric_positive_definite_and_sags_under_payload(svc: Service) -> None:
    body = {"drives": {**HOME, "theta6": 0.0}, "payload": {"mass": 60.0, "box": [0.45, 0.35, 0.3]}}
    r = svc.client.post("/api/v1/stiffness", json=body, headers=svc.h())
    assert r.status_code == 200, r.text
    doc = r.json()
    K, C = np.array(doc["stiffness"]), np.array(doc["compliance"])
    np.testing.assert_allclose(K, K.T, rtol=1e-9, atol=1e-9 * np.abs(K).max())
    assert np.linalg.eigvalsh(K).min() > 0
    np.testing.assert_allclose(K @ C, np.eye(6), atol=1e-6)
    sag = doc["deflection"]["gravity"]["translation_m"]
    assert sag[1] < 0  # gravity is -y: the payload sags downwards
    wrench = {**body, "wrench": {"force": [0.0, -500.0, 0.0]}}
    more = svc.client.post("/api/v1/stiffness", json=wrench, headers=svc.h()).json()
    assert more["deflection"]["total"]["translation_m"][1] < sag[1]
    _problem(
        svc.client.post("/api/v1/stiffness", json={**body, "frame": "flange"}, headers=svc.h()), 422, "frame"
    )
    _problem(
        svc.client.post(
            "/api/v1/stiffness", json={"drives": {**HOME, "theta6": 0.0, "x1": 5.0}}, headers=svc.h()
        ),
        422,
    )
