"""``cabinplan campaign``: exit codes and one-line errors, SIGKILL mid-way and resume, Ray's same result."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from planner.cli import app
from tests.campaign.conftest import Searched, deep_front
from tests.processes import session_processes


def invoke(*args: str | Path) -> Any:
    return CliRunner().invoke(app, [str(a) for a in args])


def write(folder: Path, data: dict[str, Any], name: str = "campaign.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _lines(result: Any) -> list[str]:
    return [x for x in result.stderr.splitlines() if x.strip()]


def test_bad_campaigns_exit_2_with_one_line_naming_the_field(tmp_path: Path) -> None:
    data = deep_front()
    data["units"][1]["unit"]["id"] = "F"
    result = invoke("campaign", write(tmp_path, data), "-o", tmp_path / "out")
    assert result.exit_code == 2
    (line,) = _lines(result)
    assert "units[1].unit.id: 'F' is used twice (units[0] and units[1])" in line

    data = deep_front()  # F mounted where D goes: no order installs both
    data["units"][0]["bay"]["pose"]["position"] = [0.86, 0.675, 2.7]
    result = invoke("campaign", write(tmp_path, data), "-o", tmp_path / "out")
    assert result.exit_code == 2
    (line,) = _lines(result)
    assert "units: unit" in line and "unit D (units[1])" in line and "unit F (units[0])" in line
    assert "overlap at their installed poses" in line

    data = deep_front()  # D's dock inside its fixture
    data["units"][1]["dock"]["pose"]["position"] = [0.70, 0.45, 0.60]
    result = invoke("campaign", write(tmp_path, data), "-o", tmp_path / "out")
    assert result.exit_code == 2
    (line,) = _lines(result)
    assert "units[1].dock.pose" in line and "fixture" in line and "(unit D)" in line
    assert not (tmp_path / "out" / "summary.json").exists()


@pytest.mark.slow
def test_a_campaign_killed_midway_keeps_its_cycles_and_resumes(tmp_path: Path, searched: Searched) -> None:
    """SIGKILL of the CLI alone after the first cycle: its workers end with it; the rerun plans the rest."""
    spec = write(tmp_path, {**deep_front(order="given"), "units": list(reversed(deep_front()["units"]))})
    out = tmp_path / "out"
    journal = out / "cycles" / "results.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "planner.cli", "campaign", str(spec), "-o", str(out), "--workers", "1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.exists() and journal.read_text().count("\n") >= 1:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the campaign ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)  # the CLI only, as kill -9 or the OOM killer would
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10  # its forkserver and plan processes notice and end
        while time.monotonic() < deadline and session_processes(proc.pid):
            time.sleep(0.1)
        assert not session_processes(proc.pid), "processes of the killed campaign still run"
    finally:
        if session_processes(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    before = [json.loads(x) for x in journal.read_text().splitlines()]
    assert len(before) == 1 and before[0]["unit"] == "D" and before[0]["status"] == "succeeded"
    assert not (out / "summary.json").exists()  # killed: no summary yet

    result = invoke("campaign", spec, "-o", out, "--workers", "1")
    assert result.exit_code == 0, result.stderr
    assert "1 cycles planned, 1 already done" in result.stderr
    rows = [json.loads(x) for x in journal.read_text().splitlines()]
    assert [r["unit"] for r in rows] == ["D", "F"]
    assert rows[0] == before[0]  # kept as it was: not planned again
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["status"] == "succeeded" and summary["order"] == ["D", "F"]
    assert [u["cycles_cached"] for u in summary["units"]] == [1, 0]
    # The same cycles as the in-process search: same hashes, same durations.
    by_key = {r["scenario_sha256"]: r for r in searched.run.journal.rows.values()}
    for row in rows:
        assert row["duration_s"] == pytest.approx(by_key[row["scenario_sha256"]]["duration_s"], abs=1e-9)


@pytest.mark.slow
def test_find_on_a_local_ray_gives_the_same_result(tmp_path: Path, searched: Searched) -> None:
    pytest.importorskip("ray", reason="ray is not installed (the [ray] extra: pip install 'cabinplan[ray]')")
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    spec = write(tmp_path, deep_front(order="find"))
    out = tmp_path / "out"
    result = invoke("campaign", spec, "-o", out, "--ray", "--workers", "2")
    assert result.exit_code == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["order"] == ["D", "F"]
    assert summary["search"]["constraints"] == [{"unit": "D", "before_one_of": ["F"]}]
    assert summary["search"]["cycles_asked"] == 4
    for a, b in zip(summary["units"], searched.result.units, strict=True):
        assert a["cycle_sha256"] == b["cycle_sha256"]
        assert a["duration_s"] == pytest.approx(b["duration_s"], abs=1e-9)
