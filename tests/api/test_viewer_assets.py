"""The viewer's static files and scene routes without a browser: served by the app, pinned, no CDN."""

from __future__ import annotations

import hashlib
import io
import json
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import trimesh

from api.app import VIEWER_DIR
from planner.robots.pprs6 import Pprs6
from planner.scenario import load_scenario
from tests.api.conftest import Service, free_transfer, make_settings, scenario, start_idle_service

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def idle(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_idle_service(make_settings(tmp_path_factory.mktemp("viewer-idle")))


def test_vendored_files_are_the_pinned_ones() -> None:
    manifest = (VIEWER_DIR / "vendor" / "VENDOR.md").read_text(encoding="utf-8")
    listed = dict(
        (path, digest) for digest, path in re.findall(r"^([0-9a-f]{64})  \./(\S+)$", manifest, flags=re.M)
    )
    on_disk = {
        str(p.relative_to(VIEWER_DIR / "vendor")): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in (VIEWER_DIR / "vendor").rglob("*")
        if p.is_file() and p.name != "VENDOR.md"
    }
    assert listed == on_disk
    assert "three.module.js" in " ".join(listed) and "uPlot.esm.js" in " ".join(listed)
    for pkg in ("three", "uplot", "js-yaml"):
        assert (
            (VIEWER_DIR / "vendor" / pkg / "LICENSE")
            .read_text(encoding="utf-8")
            .lstrip()
            .startswith(("The MIT License", "MIT License", "(The MIT License)"))
        )
    assert "| three | 0.187.0 | MIT" in manifest and "| uplot | 1.6.32 | MIT" in manifest


def test_reference_examples_are_the_suites_scenarios() -> None:
    index = json.loads((VIEWER_DIR / "examples" / "index.json").read_text(encoding="utf-8"))
    assert len(index["examples"]) >= 3
    for item in index["examples"]:
        ours = (VIEWER_DIR / "examples" / item["file"]).read_bytes()
        assert ours == (ROOT / "tests" / "scenarios" / item["file"]).read_bytes(), item["file"]


def test_page_is_served_with_an_import_map_and_nothing_from_elsewhere(idle: Service) -> None:
    c = idle.client
    r = c.get("/viewer/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html, re.S).group(1))[
        "imports"
    ]  # type: ignore[union-attr]
    for target in imports.values():
        assert target.startswith("./vendor/")
        if not target.endswith("/"):
            served = c.get(f"/viewer/{target[2:]}")
            assert served.status_code == 200 and "javascript" in served.headers["content-type"]
    # Our own files load nothing from the internet (the vendored ones only mention URLs in comments).
    for own in ("index.html", "app.js", "scene3d.js", "charts.js", "style.css"):
        text = (VIEWER_DIR / own).read_text(encoding="utf-8")
        assert not re.search(r"(src|href)\s*=\s*[\"']https?://", text) and "import(" not in text, own
        assert not re.search(r"from\s+['\"]https?://", text), own
    assert c.get("/viewer").status_code in (200, 307)  # without the slash: redirected to the page
    assert c.get("/viewer/examples/index.json").status_code == 200


def test_scene_routes_refuse_what_they_cannot_show(idle: Service) -> None:
    c, h = idle.client, idle.h()
    queued = c.post("/api/v1/plans", json=scenario("aisle-bay-insert"), headers=h).json()["id"]
    r = c.get(f"/api/v1/plans/{queued}/scene", headers=h)
    assert r.status_code == 409 and r.json()["type"].endswith("not_finished")
    assert c.get(f"/api/v1/plans/{queued}/scene", headers=idle.h("beta")).status_code == 404
    assert c.get(f"/api/v1/plans/{queued}/scene").status_code == 401
    assert c.get(f"/api/v1/plans/{queued}/cabin.glb", headers=idle.h("beta")).status_code == 404
    free = c.post("/api/v1/plans", json=free_transfer(), headers=h).json()["id"]
    r = c.get(f"/api/v1/plans/{free}/cabin.glb", headers=h)
    assert r.status_code == 404 and "free space" in r.json()["detail"]


def test_cabin_glb_is_the_planners_cabin_in_the_base_frame(idle: Service) -> None:
    c, h = idle.client, idle.h()
    job = c.post("/api/v1/plans", json=scenario("hatch-pass"), headers=h).json()["id"]
    r = c.get(f"/api/v1/plans/{job}/cabin.glb", headers=h)
    assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
    glb = trimesh.load(io.BytesIO(r.content), file_type="glb", force="mesh", process=False)
    sc = load_scenario(ROOT / "tests" / "scenarios" / "hatch-pass.yaml")
    assert sc.cabin is not None
    assert glb.vertices.shape == sc.cabin.vertices.shape and len(glb.faces) == len(sc.cabin.faces)
    assert np.max(np.abs(glb.vertices - sc.cabin.vertices)) < 1e-6  # float32 in the file
    assert np.array_equal(glb.faces, sc.cabin.faces)


def test_pprs6_scene_route(idle: Service) -> None:
    c, h = idle.client, idle.h()
    r = c.post("/api/v1/robots/pprs6/scene", json={"workspace_step_m": 0.02}, headers=h)
    assert r.status_code == 200, r.text
    doc = r.json()
    scene, profile = doc["scene"], doc["profile"]
    idx = scene["frames"]["sample"]
    assert scene["frames"]["pose"] == [profile["pose"][k] for k in idx]
    robot = Pprs6()
    C, D = np.asarray(scene["frames"]["C_m"]), np.asarray(scene["frames"]["D_m"])
    assert np.max(np.abs(np.linalg.norm(C - D, axis=2) - np.asarray(robot.geometry.L))) < 1e-9
    pts = np.asarray(scene["workspace"]["points_m"])
    assert len(pts) > 20
    x = np.column_stack([pts, np.tile(profile["pose"][0][3:], (len(pts), 1))])
    assert np.all(robot.admissible(x))  # every shown point is reachable at that orientation
    bad = {"path": {"waypoints": [{"x": 0, "y": 0, "z": 0.18}, {"x": 0.5, "y": 0, "z": 0.18}]}}
    r = c.post("/api/v1/robots/pprs6/scene", json=bad, headers=h)
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
