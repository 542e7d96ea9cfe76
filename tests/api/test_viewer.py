"""The operator page in a real browser: Debian's Chromium (software WebGL) against a live ``python -m api``.

The server runs as ``make serve`` does (its own process on a free loopback port, the local key it prints),
with a planned job (the reference bay insertion) and a refused one (goal in collision). The page is driven
through its controls; its read-only hook ``window.cabinplanViewer.state()`` reports what is drawn, and the
test compares that with the planner's own model evaluated here (FK, exact distances). Screenshots go to the
test's temporary folder.

Skipped, with the reason, where Playwright or Chromium is missing (``.ci/run`` installs both).
"""

from __future__ import annotations

import io
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.gate.checks import clearance_probe_indices
from planner.scenario import load_scenario
from planner.timing.profile import DriveProfile
from tests.api.conftest import Server, scenario

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("CABINPLAN_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
#: Software WebGL through ANGLE's SwiftShader (``--use-gl=swiftshader`` breaks WebGL in Chromium 156).
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (Python package) is not installed")
if not Path(CHROMIUM).is_file():
    pytest.skip(
        f"no Chromium at {CHROMIUM}: install Debian's chromium (apt-get install chromium) to run the browser "
        "tests (.ci/run does)",
        allow_module_level=True,
    )


class LiveServer(Server):
    """``python -m api`` as ``make serve`` runs it (loopback, two workers), with the local key it prints."""

    def __init__(self, data_dir: Path) -> None:
        super().__init__(data_dir, CABINPLAN_HOST="127.0.0.1", CABINPLAN_WORKERS="2")
        self.start(timeout_s=90)
        self.key = (data_dir / "local-api-key").read_text().strip()
        assert self.key in self.log.read_text()  # printed at start-up, as make serve shows it
        assert f"{self.url}/viewer/" in self.log.read_text()

    @property
    def h(self) -> dict[str, str]:
        return {"X-API-Key": self.key}

    def submit(self, body: dict[str, Any]) -> str:
        r = httpx.post(f"{self.url}/api/v1/plans", json=body, headers=self.h, timeout=30)
        assert r.status_code == 202, r.text
        return str(r.json()["id"])

    def wait(self, job_id: str, timeout_s: float = 240.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            doc: dict[str, Any] = httpx.get(
                f"{self.url}/api/v1/plans/{job_id}", headers=self.h, timeout=30
            ).json()
            if doc["status"] not in ("queued", "running"):
                return doc
            assert time.monotonic() < deadline, f"plan {job_id} still {doc['status']}"
            time.sleep(0.2)

    def stop(self) -> None:
        """SIGTERM (a clean shutdown), then SIGKILL if it has not stopped within 20 s."""
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)


class Plans:
    def __init__(self, server: LiveServer, planned: dict[str, Any], refused: dict[str, Any]) -> None:
        self.server = server
        self.planned = planned
        self.refused = refused


@pytest.fixture(scope="module")
def plans(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plans]:
    server = LiveServer(tmp_path_factory.mktemp("viewer") / "data")
    try:
        ok = server.submit(scenario("aisle-bay-insert"))
        refused = server.submit(scenario("refuse-goal-in-collision"))
        planned_doc, refused_doc = server.wait(ok), server.wait(refused)
        assert planned_doc["status"] == "succeeded", planned_doc["message"]
        assert refused_doc["status"] == "failed" and refused_doc["reason"] == "goal_in_collision"
        yield Plans(server, planned_doc, refused_doc)
    finally:
        server.stop()


@pytest.fixture(scope="module")
def playwright() -> Iterator[Any]:
    with sync_api.sync_playwright() as pw:
        yield pw


@pytest.fixture(scope="module")
def browser(playwright: Any) -> Iterator[Any]:
    b = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
    yield b
    b.close()


def _page(browser: Any, key: str | None, width: int = 1400, height: int = 1100) -> Any:
    context = browser.new_context(viewport={"width": width, "height": height})
    if key is not None:  # the key as the page keeps it: in this tab's sessionStorage
        context.add_init_script(f"sessionStorage.setItem('cabinplan.apiKey', {key!r});")
    page = context.new_page()
    page.set_default_timeout(30_000)
    return page


def _state(page: Any) -> dict[str, Any]:
    out: dict[str, Any] = page.evaluate("window.cabinplanViewer.state()")
    return out


def _wait_ready(page: Any) -> dict[str, Any]:
    page.wait_for_function("window.cabinplanViewer && window.cabinplanViewer.state().ready", timeout=60_000)
    return _state(page)


def _scrub(page: Any, t: float) -> dict[str, Any]:
    page.eval_on_selector(
        "#scrub", "(el, t) => { el.value = String(t); el.dispatchEvent(new Event('input')); }", t
    )
    return _state(page)


def _canvas_variance(page: Any, path: Path) -> float:
    from PIL import Image

    # A page screenshot clipped to the canvas (what is on screen; an element screenshot waits for the page's
    # animation loop to settle, seconds under software rendering).
    box = page.locator("#scene-canvas").bounding_box()
    png = page.screenshot(path=str(path), clip=box)
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    return float(pixels.var(axis=(0, 1)).sum())


def _resolved() -> Any:
    return load_scenario(ROOT / "tests" / "scenarios" / "aisle-bay-insert.yaml")


def test_plan_scene_follows_the_planners_model(plans: Plans, browser: Any, tmp_path: Path) -> None:
    page = _page(browser, plans.server.key)
    page.goto(f"{plans.server.url}/viewer/")
    page.locator(f"#plan-table tr[data-plan='{plans.planned['id']}']").click()  # open it from the list
    state = _wait_ready(page)
    assert state["mode"] == "plan" and state["webgl"] is True, state
    # The cabin is in the scene as GLB; the canvas shows something (not one flat colour).
    page.wait_for_function("window.cabinplanViewer.state().renderedFrames > 2")
    assert _canvas_variance(page, tmp_path / "plan-canvas.png") > 100.0

    sc = _resolved()
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    assert state["bodies"] == len(world.names) == 9
    assert state["bodyNames"] == list(world.names)

    result = plans.planned["result"]
    prof = DriveProfile.from_dict(result, sc.robot)
    scene = httpx.get(f"{plans.server.url}/api/v1/plans/{plans.planned['id']}/scene", headers=plans.server.h)
    frames = scene.json()["frames"]
    spacing = float(np.max(np.diff(frames["t_s"])))
    for fraction in (0.0, 0.37, 0.81, 1.0):
        t = fraction * prof.duration_s
        state = _scrub(page, t)
        k = state["sample"]
        assert abs(state["frameTime"] - prof.t[k]) < 1e-12
        assert abs(state["frameTime"] - t) <= spacing / 2 + 1e-9
        # The payload drawn where the planner's FK puts it: FK(q(t_k)) T_tool_box, to 1e-6 m.
        assert sc.payload is not None
        T = sc.robot.fk(prof.joints[k]) @ sc.payload.T_tool_box
        drawn = state["payload"]
        assert np.max(np.abs(np.asarray(drawn["position"]) - T[:3, 3])) < 1e-6, (t, drawn, T[:3, 3])
        assert np.max(np.abs(np.asarray(drawn["rotation"]) - T[:3, :3])) < 1e-6
        # The clearance cursor: at the frame's time, the exact distance of the planner's world there.
        d = world.min_distance(np.ascontiguousarray(prof.joints[k]))
        cursor = state["clearanceCursor"]
        assert abs(cursor["t"] - prof.t[k]) < 1e-12
        assert abs(cursor["distance_m"] - d.distance_m) < 1e-9
        assert cursor["pair"] == list(d.bodies)
        assert f"{1000 * d.distance_m:.1f} mm" in cursor["text"]
        assert set(state["highlighted"]) == set(d.bodies) & (set(world.names) | {"cabin"})
    # The report's minimum clearance (exact over every sample) is on the curve, at its closest sample, and
    # no frame is closer by more than the gate's tolerance.
    at = result["report"]["gate"]["min_clearance_at"]
    dist = scene.json()["clearance"]["distance_m"]
    assert at["sample"] in frames["sample"]
    at_frame = dist[frames["sample"].index(at["sample"])]
    assert abs(at_frame - result["min_clearance_m"]) <= at["tolerance_m"]
    assert min(dist) >= result["min_clearance_m"] - at["tolerance_m"]
    probes = set(clearance_probe_indices(len(prof.t)).tolist())
    assert probes <= set(frames["sample"])
    # The approach line ends at the goal, and the last frames ride on it.
    doc = scene.json()
    end = np.asarray(doc["approach"]["to_m"])
    assert np.allclose(end, sc.T_base_payload_goal[:3, 3])  # type: ignore[index]
    figures = page.locator("#figures").inner_text()
    assert f"{result['duration_s']:.3f} s" in figures and "passed" in figures
    # The page shows the report's figures: exact minimum, certified bound, and where.
    assert f"{1000 * result['min_clearance_m']:.1f} mm" in figures
    assert f"{1000 * result['report']['gate']['min_clearance_bound_m']:.1f} mm" in figures
    assert " – ".join(at["bodies"]) in figures
    assert result["provenance"]["cabin_mesh_sha256"] in page.locator("#provenance").inner_text()
    _scrub(page, 0.6 * prof.duration_s)
    page.screenshot(path=str(tmp_path / "plan-page.png"), full_page=True)


def test_refusal_shows_reason_and_offending_configuration(plans: Plans, browser: Any, tmp_path: Path) -> None:
    page = _page(browser, plans.server.key)
    page.goto(f"{plans.server.url}/viewer/#/plan/{plans.refused['id']}")
    state = _wait_ready(page)
    assert state["mode"] == "refusal"
    assert page.locator("#refusal").is_visible()
    assert page.locator("#refusal-reason").inner_text() == "goal in collision"
    assert plans.refused["message"] in page.locator("#refusal-message").inner_text()
    assert "family_points" in page.locator("#refusal-details").inner_text()  # the evidence
    # The configuration (the planner's IK solution of the goal pose) with the offending pair highlighted.
    contacts = page.locator("#refusal-contacts").inner_text()
    assert "payload" in contacts
    assert "payload" in state["highlighted"] and "cabin" in state["highlighted"]
    assert state["bodies"] == 9
    assert _canvas_variance(page, tmp_path / "refusal-canvas.png") > 100.0
    page.screenshot(path=str(tmp_path / "refusal-page.png"), full_page=True)


def test_missing_or_wrong_key_says_so(plans: Plans, browser: Any, tmp_path: Path) -> None:
    page = _page(browser, None)
    page.goto(f"{plans.server.url}/viewer/")
    banner = page.locator("#auth-message")
    banner.wait_for(state="visible")
    assert "No API key" in banner.inner_text()
    page.fill("#api-key", "cpk_not-a-key")
    page.click("#key-form button[type=submit]")
    page.wait_for_function("(document.querySelector('#auth-message').textContent || '').includes('refused')")
    text = banner.inner_text()
    assert "The API key was refused" in text and "invalid or revoked API key" in text
    assert page.locator("#plan-table tbody tr").count() == 0
    page.screenshot(path=str(tmp_path / "wrong-key.png"))
    # The right key opens the list (kept in this tab's sessionStorage).
    page.fill("#api-key", plans.server.key)
    page.click("#key-form button[type=submit]")
    page.locator(f"#plan-table tr[data-plan='{plans.planned['id']}']").wait_for()
    assert not banner.is_visible()
    assert page.evaluate("sessionStorage.getItem('cabinplan.apiKey')") == plans.server.key
    page.screenshot(path=str(tmp_path / "plan-list.png"))
    # The form offers the reference scenarios, and takes a scenario file with its own cabin mesh: the
    # mesh is uploaded (POST /cabins), the scenario names it, the plan is queued and its page opens.
    options = page.locator("#submit-example option").all_inner_texts()
    assert any(o.startswith("aisle-bay-insert") for o in options) and len(options) == 5
    page.set_input_files("#submit-file", str(ROOT / "tests" / "scenarios" / "refuse-goal-in-collision.yaml"))
    page.set_input_files("#submit-mesh", str(ROOT / "planner" / "meshes" / "cabin-aisle.stl"))
    page.click("#submit-form button[type=submit]")
    page.wait_for_url("**/viewer/#/plan/*")
    state = _wait_ready(page)
    assert state["mode"] == "refusal" and page.locator("#refusal-reason").inner_text() == "goal in collision"
    job = httpx.get(f"{plans.server.url}/api/v1/plans/{state['planId']}", headers=plans.server.h).json()
    cabins = httpx.get(f"{plans.server.url}/api/v1/cabins", headers=plans.server.h).json()
    uploaded = [c for c in cabins["items"] if not c["reference"]]
    assert [c["filename"] for c in uploaded] == ["cabin-aisle.stl"]
    assert job["provenance"]["cabin_mesh_sha256"] == uploaded[0]["id"]


def test_pprs6_path_and_workspace(plans: Plans, browser: Any, tmp_path: Path) -> None:
    from planner.tools import pprs6 as pprs6_tools

    page = _page(browser, plans.server.key)
    page.goto(f"{plans.server.url}/viewer/#/pprs6")
    page.click("#pprs6-form button[type=submit]")
    state = _wait_ready(page)
    assert state["mode"] == "pprs6"
    profile = pprs6_tools.profile_document(None)
    state = _scrub(page, 0.4 * profile["duration_s"])
    k = state["sample"]
    assert (
        np.max(np.abs(np.asarray(state["payload"]["position"]) - np.asarray(profile["pose"][k][:3]))) < 1e-9
    )
    assert _canvas_variance(page, tmp_path / "pprs6-canvas.png") > 100.0
    assert "workspace boundary" in page.locator("#pprs6-result").inner_text()
    page.screenshot(path=str(tmp_path / "pprs6-page.png"), full_page=True)


def test_without_webgl_the_page_says_so(plans: Plans, playwright: Any, tmp_path: Path) -> None:
    args = [*CHROMIUM_ARGS, "--disable-webgl", "--disable-3d-apis"]
    b = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=args)
    try:
        page = _page(b, plans.server.key)
        page.goto(f"{plans.server.url}/viewer/#/plan/{plans.planned['id']}")
        state = _wait_ready(page)
        assert state["webgl"] is False and state["bodies"] == 0
        message = page.locator("#webgl-message")
        assert message.is_visible() and "WebGL is not available" in message.inner_text()
        # Everything else still works: figures, curves and their cursor.
        assert "passed" in page.locator("#figures").inner_text()
        state = _scrub(page, 1.0)
        assert state["clearanceCursor"]["distance_m"] is not None
        page.screenshot(path=str(tmp_path / "no-webgl.png"), full_page=True)
    finally:
        b.close()
