"""Campaigns and cycles on a live server: per-unit progress, a SIGKILL mid-campaign, the operator page.

One server process per module; the heaviest scenario runs once: a two-unit campaign (A3 then A5 in the
aisle cabin's rack) is submitted, its units' statuses are recorded as it runs, the server is SIGKILLed once
the first cycle is finished, restarted, and the campaign completes from the kept cycle (only A5 is planned
again). A cycle job planned after the restart and the campaign are then shown on the operator page in
Debian's Chromium (software WebGL), the unit's drawn pose compared with the planner's model.
"""

from __future__ import annotations

import io
import os
import shutil
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from api.examples import aisle_campaign, aisle_cycle
from planner.task.campaign import cycle_document
from planner.task.campaign_schema import campaign_from_dict
from planner.task.legs import LEGS, leg_world
from planner.task.resolve import resolve_cycle
from planner.task.schema import cycle_from_dict
from planner.timing.profile import DriveProfile
from tests.api.conftest import Server

CHROMIUM = os.environ.get("CABINPLAN_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-first-run"]


class Live:
    """The server, its key, and what the module's scenario left behind."""

    def __init__(self, server: Server) -> None:
        self.server = server
        self.key = (server.data_dir / "local-api-key").read_text().strip()
        self.h = {"X-API-Key": self.key}
        self.seen: list[list[tuple[str, str]]] = []
        self.campaign: dict[str, Any] = {}
        self.cycle: dict[str, Any] = {}
        self.killed_state: dict[str, Any] = {}

    def url(self, path: str) -> str:
        return f"{self.server.url}/api/v1{path}"

    def post(self, path: str, body: dict[str, Any]) -> str:
        r = httpx.post(self.url(path), json=body, headers=self.h, timeout=60)
        assert r.status_code == 202, r.text
        return str(r.json()["id"])

    def get(self, path: str) -> dict[str, Any]:
        doc: dict[str, Any] = httpx.get(self.url(path), headers=self.h, timeout=60).json()
        return doc

    def wait(self, path: str, timeout_s: float = 400.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            doc = self.get(path)
            self.record(doc)
            if doc["status"] not in ("queued", "running"):
                return doc
            assert time.monotonic() < deadline, f"{path} still {doc['status']}"
            time.sleep(0.2)

    def record(self, doc: dict[str, Any]) -> None:
        if doc.get("units"):
            now = [(u["id"], u["status"]) for u in doc["units"]]
            if not self.seen or self.seen[-1] != now:
                self.seen.append(now)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    data = tmp_path_factory.mktemp("live") / "data"
    server = Server(data, CABINPLAN_HOST="127.0.0.1", CABINPLAN_WORKERS="2", CABINPLAN_JOB_LEASE_S="3")
    server.start(timeout_s=300)
    lv = Live(server)
    try:
        campaign_id = lv.post("/campaigns", aisle_campaign())
        deadline = time.monotonic() + 300
        while True:  # until the first cycle is finished (kept) and the second one runs
            doc = lv.get(f"/campaigns/{campaign_id}")
            lv.record(doc)
            units = {u["id"]: u["status"] for u in doc.get("units") or []}
            if units.get("A3") == "planned":
                lv.killed_state["progress"] = doc["progress"]
                break
            assert doc["status"] in ("queued", "running"), doc
            assert time.monotonic() < deadline, doc
            time.sleep(0.1)
        server.kill()
        con = sqlite3.connect(data / "cabinplan.db")  # what the crash left behind
        lv.killed_state |= {
            "status": con.execute("SELECT status FROM jobs WHERE id = ?", (campaign_id,)).fetchone()[0],
            "kept": [
                n
                for (n,) in con.execute(
                    "SELECT name FROM job_files WHERE job_id = ?", (campaign_id,)
                ).fetchall()
            ],
        }
        con.close()
        server.start(timeout_s=300)
        cycle_id = lv.post("/cycles", aisle_cycle())
        lv.campaign = lv.wait(f"/campaigns/{campaign_id}")
        lv.cycle = lv.wait(f"/cycles/{cycle_id}")
        yield lv
    finally:
        server.stop()


def test_campaign_reports_each_unit_and_resumes_after_sigkill(live: Live) -> None:
    assert live.killed_state["status"] == "running"
    assert live.killed_state["progress"] == 0.5  # one unit of two done
    assert len(live.killed_state["kept"]) == 1 and live.killed_state["kept"][0].startswith("keep/")
    # Per-unit progress as it ran: A3 planning with A5 waiting, then A3 planned; after the restart A5
    # planned from the cabin A3 left.
    assert [("A3", "planning"), ("A5", "waiting")] in live.seen, live.seen
    assert live.seen.index([("A3", "planning"), ("A5", "waiting")]) < min(
        k for k, s in enumerate(live.seen) if ("A3", "planned") in s
    )
    doc = live.campaign
    assert doc["status"] == "succeeded", (doc["reason"], doc["message"])
    assert doc["attempts"] == 2  # killed once, resumed once
    result = doc["result"]
    assert result["order"] == ["A3", "A5"]
    # The finished cycle was kept: the second attempt planned only A5.
    assert result["cycles_cached"] == 1 and result["cycles_planned"] == 1
    by_id = {u["id"]: u for u in result["units"]}
    assert by_id["A3"]["cycles_cached"] == 1 and by_id["A5"]["cycles_planned"] == 1
    assert doc["units"] == [
        {k: v for k, v in u.items() if k in ("id", "status", "cycles_planned", "cycles_cached", "message")}
        for u in doc["units"]
    ]
    assert [u["status"] for u in doc["units"]] == ["planned", "planned"]
    assert [c["status"] for c in result["cycles"]] == ["succeeded", "succeeded"]
    assert result["campaign_duration_s"] == pytest.approx(
        sum(c["duration_s"] for c in result["cycles"]), abs=1e-9
    )
    # The cabin filled up: no sample of A5's cycle comes within the clearance of unit A3, installed before,
    # measured exactly (FCL) in each leg's world at every 5th sample.
    campaign = campaign_from_dict(aisle_campaign())
    cyc = resolve_cycle(cycle_from_dict(cycle_document(campaign, "A5", ["A3"])))
    assert "unit A3" in [o.name for o in cyc.installed]
    a5 = result["cycles"][1]
    q = DriveProfile.from_dict(a5, cyc.robot).joints
    leg = np.asarray(a5["leg"])
    worlds = {k: leg_world(cyc, LEGS[k]) for k in range(len(LEGS))}
    nearest = min(
        worlds[int(leg[s])]
        .obstacle_distance(worlds[int(leg[s])].flat_poses(q[s]), obstacle="unit A3")
        .distance_m
        for s in range(0, len(q), 5)
    )
    assert nearest >= campaign.options.clearance_m - 1e-9, nearest
    # Files of a finished campaign.
    units_csv = httpx.get(live.url(f"/campaigns/{doc['id']}/units.csv"), headers=live.h, timeout=60)
    assert units_csv.status_code == 200 and units_csv.text.splitlines()[1].startswith("1,A3,planned,")
    listed = live.get("/campaigns?status=running")
    assert listed["total"] == 0


# ------------------------------------------------------------------------------------------ the page
@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright (Python package) is not installed"
    )
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"no Chromium at {CHROMIUM}: install Debian's chromium to run the browser tests")
    with sync_api.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield b
        b.close()


def _page(browser: Any, key: str) -> Any:
    context = browser.new_context(viewport={"width": 1400, "height": 1200})
    context.add_init_script(f"sessionStorage.setItem('cabinplan.apiKey', {key!r});")
    page = context.new_page()
    page.set_default_timeout(60_000)
    return page


def _ready(page: Any) -> dict[str, Any]:
    page.wait_for_function("window.cabinplanViewer && window.cabinplanViewer.state().ready", timeout=120_000)
    out: dict[str, Any] = page.evaluate("window.cabinplanViewer.state()")
    return out


def _scrub(page: Any, t: float) -> dict[str, Any]:
    page.eval_on_selector(
        "#scrub", "(el, t) => { el.value = String(t); el.dispatchEvent(new Event('input')); }", t
    )
    out: dict[str, Any] = page.evaluate("window.cabinplanViewer.state()")
    return out


def _canvas_variance(page: Any, path: Path) -> float:
    from PIL import Image

    box = page.locator("#scene-canvas").bounding_box()
    png = page.screenshot(path=str(path), clip=box)
    return float(np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float).var(axis=(0, 1)).sum())


def _mid(doc: dict[str, Any], name: str, offset_s: float = 0.0) -> float:
    leg = next(x for x in doc["legs"] if x["name"] == name)
    return offset_s + 0.5 * (leg["t_start_s"] + leg["t_end_s"])


def test_cycle_page_shows_legs_events_and_the_unit_released_in_its_bay(
    live: Live, browser: Any, tmp_path: Path
) -> None:
    doc = live.cycle["result"]
    assert live.cycle["status"] == "succeeded"
    cyc = resolve_cycle(cycle_from_dict(aisle_cycle()))
    q = DriveProfile.from_dict(doc, cyc.robot).joints
    T_unit_box = np.linalg.inv(cyc.T_base_unit_dock) @ cyc.dock_unit.T_base_obstacle
    page = _page(browser, live.key)
    page.goto(f"{live.server.url}/viewer/")
    page.locator(f"#task-table tr[data-job='{live.cycle['id']}']").click()  # opened from the list
    state = _ready(page)
    assert state["mode"] == "cycle" and state["webgl"] is True, state
    assert state["legBands"] == 9 and state["eventMarkers"] == 2
    assert "gripper" in state["bodyNames"]
    expected = {
        "pre_grasp": "dock",
        "transit": "held",
        "insertion": "held",
        "retract": "installed",
        "park": "installed",
    }
    for name, where in expected.items():
        state = _scrub(page, _mid(doc, name))
        assert state["leg"] == name, (name, state["leg"])
        unit = state["units"]["A3"]
        assert unit["visible"] and unit["state"] == where, (name, unit)
        s = state["sample"]
        if where == "held":  # at the tool: the planner's FK of the sample's joints and the grasp
            T = cyc.robot.fk(q[s]) @ cyc.T_tool_unit @ T_unit_box
        elif where == "installed":
            T = cyc.bay_unit.T_base_obstacle
        else:
            T = cyc.dock_unit.T_base_obstacle
        assert np.max(np.abs(np.asarray(unit["position"]) - T[:3, 3])) < 1e-6, (
            name,
            unit["position"],
            T[:3, 3],
        )
        assert np.max(np.abs(np.asarray(unit["rotation"]) - T[:3, :3])) < 1e-6
    text = page.locator("#leg-readout").inner_text()
    assert "leg park" in text and "unit A3" in text
    figures = page.locator("#figures").inner_text()
    assert (
        "attach A3 spring-back" in figures and f"{1e3 * doc['events'][1]['springback_m']:.3f} mm" in figures
    )
    state = _scrub(page, _mid(doc, "insertion"))
    page.wait_for_function("window.cabinplanViewer.state().renderedFrames > 3")
    assert _canvas_variance(page, tmp_path / "cycle-canvas.png") > 100.0
    page.screenshot(path=str(tmp_path / "cycle-page.png"), full_page=True)


def test_campaign_page_lists_units_and_fills_the_cabin(live: Live, browser: Any, tmp_path: Path) -> None:
    result = live.campaign["result"]
    first, second = result["cycles"]
    page = _page(browser, live.key)
    page.goto(f"{live.server.url}/viewer/#/campaign/{live.campaign['id']}")
    state = _ready(page)
    assert state["mode"] == "campaign"
    assert [(r["id"], r["status"]) for r in state["unitRows"]] == [("A3", "planned"), ("A5", "planned")]
    assert state["legBands"] == 18 and state["eventMarkers"] == 4
    offset = first["duration_s"]
    # Scrubbing through the units: first A3 on its way with A5 not yet in the cabin, then A3 in its bay
    # while A5 is carried, then both installed.
    state = _scrub(page, _mid(first, "transit"))
    assert (
        state["cycle"] == 0
        and state["units"]["A3"]["state"] == "held"
        and not state["units"]["A5"]["visible"]
    )
    assert [r["current"] for r in state["unitRows"]] == [True, False]
    state = _scrub(page, _mid(second, "transit", offset))
    assert state["cycle"] == 1 and state["leg"] == "transit"
    assert state["units"]["A3"]["state"] == "installed" and state["units"]["A5"]["state"] == "held"
    assert [r["current"] for r in state["unitRows"]] == [False, True]
    campaign = campaign_from_dict(aisle_campaign())
    a3 = resolve_cycle(cycle_from_dict(cycle_document(campaign, "A3", [])))
    assert (
        np.max(np.abs(np.asarray(state["units"]["A3"]["position"]) - a3.bay_unit.T_base_obstacle[:3, 3]))
        < 1e-6
    )
    assert _canvas_variance(page, tmp_path / "campaign-canvas.png") > 100.0
    page.screenshot(path=str(tmp_path / "campaign-page.png"), full_page=True)
    state = _scrub(page, _mid(second, "park", offset))
    assert {u["state"] for u in state["units"].values()} == {"installed"}
