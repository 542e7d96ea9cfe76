"""Embedded sweeps: the result table against the plans' physics, re-runnable scenarios, resume, hard kill."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from planner.sweep.expand import expand_sweep
from planner.sweep.results import COLUMN_NAMES, JOURNAL, read_parquet
from planner.sweep.run import Counts, EmbeddedExecutor, run_sweep, warm_task
from planner.sweep.spec import sweep_from_dict
from tests.processes import session_processes
from tests.sweep.conftest import SCENARIOS, bay_sweep, invoke, stuck_base, write_spec

PNG = b"\x89PNG\r\n\x1a\n"


def test_rows_hold_what_each_plan_gives(embedded_run):
    out, rows = embedded_run
    assert sorted(r["plan"] for r in rows) == list(range(12))
    with (out / "results.csv").open(newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [c for c in table[0]] == list(COLUMN_NAMES)
    assert [(r["scenario_sha256"], r["status"]) for r in table] == [
        (r["scenario_sha256"], r["status"]) for r in rows
    ]
    for row in rows:
        profile = json.loads((out / row["profile_file"]).read_text())
        assert (out / row["scenario_file"]).is_file()
        if row["payload_mass_kg"] == 400:
            # 400 kg cannot be held at the start: refused there, with the force ratio as evidence.
            assert (row["status"], row["reason"]) == ("failed", "start_outside_limits")
            assert json.loads(row["evidence"])["static_force_ratio"] > 1.0
            assert row["duration_s"] is None and profile["reason"] == "start_outside_limits"
        else:
            assert row["status"] == "succeeded", row["message"]
            assert row["min_clearance_m"] >= row["clearance_m"]
            assert row["lower_bound_ratio"] >= 1.0  # no trajectory beats the single-drive bound
            assert 0.0 < row["peak_force_ratio"] <= 1.0
            assert profile["duration_s"] == pytest.approx(row["duration_s"])
            assert profile["t"][-1] == pytest.approx(row["duration_s"])
            assert profile["scenario"]["sha256"] == row["scenario_sha256"]
    for name in ("feasibility_map.png", "durations.png", "reasons.png"):
        assert (out / name).read_bytes().startswith(PNG)


def test_each_plan_is_an_ordinary_scenario_that_re_runs_alone(embedded_run, tmp_path: Path):
    out, rows = embedded_run
    # The last feasible plan ran on a reused worker (12 plans on 2 workers), after plans of other bays,
    # masses and seeds: what the worker kept from them (meshes, collision geometry, compiled kernels)
    # changes nothing; planned alone in this process, the profile is the same, sample for sample.
    row = [r for r in rows if r["status"] == "succeeded"][-1]
    assert row["plan"] >= 2
    result = invoke("plan", out / row["scenario_file"], "-o", tmp_path / "again.json")
    assert result.exit_code == 0, result.stderr
    again = json.loads((tmp_path / "again.json").read_text())
    swept = json.loads((out / row["profile_file"]).read_text())
    assert again["scenario"]["sha256"] == row["scenario_sha256"]
    assert again["duration_s"] == pytest.approx(row["duration_s"], abs=1e-9)
    for key in ("t", "position", "velocity", "acceleration", "effort"):
        assert again[key] == swept[key], key


def test_a_sweep_killed_midway_resumes_without_replanning_or_duplicating(tmp_path: Path):
    sweep = bay_sweep("resume")
    sweep["axes"]["seed"] = [1]  # 6 plans
    spec = write_spec(tmp_path, sweep)
    out = tmp_path / "out"
    journal = out / JOURNAL
    proc = subprocess.Popen(
        [sys.executable, "-m", "planner.cli", "sweep", str(spec), "-o", str(out), "--workers", "2"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: the kill takes the forkserver and plans too
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.exists() and journal.read_text().count("\n") >= 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep ended before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    before = {r["scenario_sha256"]: r for r in map(json.loads, journal.read_text().splitlines())}
    assert 2 <= len(before) < 6
    assert not (out / "results.parquet").exists()  # killed: the tables were never written

    result = invoke("sweep", spec, "-o", out, "--workers", "2")
    assert result.exit_code == 0, result.stderr
    assert f"{len(before)} already done" in result.stderr
    lines = journal.read_text().splitlines()
    assert len(lines) == 6 and len({json.loads(x)["scenario_sha256"] for x in lines}) == 6
    rows = read_parquet(out / "results.parquet")
    assert len(rows) == 6
    for row in rows:  # the plans done before the kill were not planned again (same wall-clock time)
        if row["scenario_sha256"] in before:
            assert row["wall_time_s"] == before[row["scenario_sha256"]]["wall_time_s"]
    assert {r["status"] for r in rows} == {"succeeded", "failed"}

    (out / "results.parquet").unlink()  # a third run plans nothing and writes the tables again
    again = invoke("sweep", spec, "-o", out, "--no-plots")
    assert again.exit_code == 0 and "6 already done" in again.stderr, again.stderr
    assert read_parquet(out / "results.parquet") == rows


def test_a_killed_sweep_takes_its_running_plans_with_it(tmp_path: Path) -> None:
    """SIGKILL of the CLI alone while a plan searches: the plan process and the forkserver end at once.

    Nobody is left to enforce the plan's wall-clock limit or read its result, so it must not plan on (a
    plan stuck in native code would run for ever): they end with the CLI (planner.core.lifeline).
    """
    spec = stuck_sweep("killed", 120.0)
    spec["plans"] = [spec["plans"][1], spec["plans"][2], spec["plans"][0]]  # the long search last
    path = write_spec(tmp_path, spec)
    journal = tmp_path / "out" / JOURNAL
    proc = subprocess.Popen(
        [sys.executable, "-m", "planner.cli", "sweep", str(path), "-o", str(tmp_path / "out"), "--workers=1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.exists() and journal.read_text().count("\n") >= 2:
                break  # the two quick plans are done: the one worker is in the long search
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep ended before it could be killed"
        time.sleep(0.5)
        assert len(session_processes(proc.pid)) >= 3  # the CLI, its forkserver, the searching plan
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 5.0  # before the search would end on its own (about 8 s)
        while time.monotonic() < deadline and session_processes(proc.pid):
            time.sleep(0.05)
        assert not session_processes(proc.pid), "processes of the killed sweep still run"
    finally:
        if session_processes(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)


def stuck_sweep(name: str, wall_time_limit_s: float) -> dict:
    """A plan that would search for about 8 s (killed at its wall-clock limit), a refusal, a feasible plan."""
    return {
        "name": name,
        "base": stuck_base(),
        "plans": [
            {},
            {"payload_mass_kg": 400},
            {"payload_box_m": [0.45, 0.35, 0.30], "grasp": {"position": [0, 0, 0.2]}},
        ],
        "limits": {"wall_time_limit_s": wall_time_limit_s},
    }


def check_stuck_rows(rows: list[dict], limit_s: float) -> None:
    by_plan = {r["plan"]: r for r in rows}
    assert len(rows) == 3
    killed = by_plan[0]
    assert (killed["status"], killed["reason"]) == ("failed", "time_limit_exceeded")
    assert limit_s <= killed["wall_time_s"] < limit_s + 3.0
    assert killed["profile_file"] is None
    assert by_plan[1]["reason"] == "start_outside_limits"
    assert by_plan[2]["status"] == "succeeded", by_plan[2]["message"]


#: Wall-clock limit of the stuck plan in the tests [s]. Its search ends by its work budget (41 500 motion
#: checks), not by its 20 s time limit: after 7.7-8.1 s on the fastest 2-core VM seen (2026-12-04, where the
#: 8 s this limit was once let it end on its own first), about twice that on slower ones; the limit must come
#: well before. The two other plans take 0.3 s each on a quiet machine, so they finish well inside it even
#: under heavy load.
STUCK_LIMIT_S = 4.0


def _gone(pid: int) -> bool:
    return not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()


def test_a_plan_past_its_limit_is_killed_and_recorded_while_the_others_finish(tmp_path: Path):
    sweep = sweep_from_dict(stuck_sweep("stuck", STUCK_LIMIT_S))
    plans = expand_sweep(sweep)
    executor = EmbeddedExecutor(2)
    ran_on: dict[int, int] = {}

    def progress(counts: Counts) -> None:
        for plan in plans:
            if plan.sha256 in executor.started:
                ran_on[plan.index] = executor.started[plan.sha256]

    try:
        counts = run_sweep(plans, tmp_path, executor, sweep.limits, progress=progress)
        idle = [p.process.pid for p in executor._idle]
        assert all(not _gone(pid) for pid in idle)  # the killed worker was replaced: slots stay warm
    finally:
        executor.close()
    assert (counts.succeeded, counts.failed) == (1, 2)
    check_stuck_rows(read_parquet(tmp_path / "results.parquet"), STUCK_LIMIT_S)
    assert ran_on[0] not in idle and ran_on[1] == ran_on[2]  # the other worker planned both of the others
    for pid in [*idle, *ran_on.values()]:  # every process the executor started is gone
        assert _gone(pid)


def test_a_killed_embedded_worker_loses_no_row_and_is_replaced(tmp_path: Path):
    sweep = sweep_from_dict(
        {
            "name": "kill-worker",
            "base": str(SCENARIOS / "aisle-transfer.yaml"),
            "axes": {"payload_mass_kg": [100, 400], "seed": [1, 2]},
        }
    )
    plans = expand_sweep(sweep)
    executor = EmbeddedExecutor(2, warm_task(plans))
    killed: list[int] = []
    seen: set[int] = set()

    def progress(counts: Counts) -> None:
        seen.update(executor.started.values())
        pid = executor.started.get(plans[0].sha256)  # the first feasible plan, just handed to its worker
        if pid is not None and not killed:
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    try:
        counts = run_sweep(plans, tmp_path, executor, sweep.limits, progress=progress)
        alive = [p.process.pid for p in executor._idle if p.process.is_alive()]
    finally:
        executor.close()
    assert killed and counts.retried == 1
    rows = {r["plan"]: r for r in read_parquet(tmp_path / "results.parquet")}
    assert sorted(rows) == [0, 1, 2, 3]
    assert len(journal_lines(tmp_path)) == 4  # one row each, none duplicated
    assert rows[0]["attempts"] == 2 and rows[0]["status"] == "succeeded"
    assert [rows[k]["attempts"] for k in (1, 2, 3)] == [1, 1, 1]
    assert {r["status"] for r in rows.values()} == {"succeeded", "failed"}
    assert (tmp_path / rows[0]["profile_file"]).is_file()
    assert killed[0] not in alive and len(alive) >= 2  # replaced; the slots' workers wait for more
    assert len(seen) <= 3  # 4 plans (5 submissions) on the 2 first workers and 1 replacement: reused


def journal_lines(out: Path) -> list[str]:
    return (out / JOURNAL).read_text().splitlines()
