"""OMPL benchmark logs: written by ``bench.ompl_log``, read into SQLite by a parser of the documented grammar.

The parser below is written from the grammar that ``ompl_benchmark_statistics.py`` reads (OMPL's
benchmarking docs), independently of the writer: header lines matched by their fixed words, the setup
block between ``<<<|`` and ``|>>>``, typed property columns, ``; ``-terminated run values (empty = NULL)
and ``.`` closing each planner. Every number in the database is compared with the records it came from.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import pytest
import yaml

from bench import ompl_log


class _Lines:
    def __init__(self, text: str) -> None:
        self.lines = text.split("\n")
        self.i = 0

    def peek(self) -> str:
        return self.lines[self.i]

    def take(self) -> str:
        line = self.lines[self.i]
        self.i += 1
        return line

    def expect(self, *tail: str) -> list[str]:
        """The next line's words, which must end with ``tail``."""
        words = self.take().split()
        assert words[len(words) - len(tail) :] == list(tail), (words, tail)
        return words


def parse_into(db: sqlite3.Connection, text: str) -> int:
    """One experiment's log into ``experiments``, ``planners`` and ``runs``; returns the experiment id."""
    src = _Lines(text)
    version = None
    if src.peek().split()[1:2] == ["version"]:
        version = src.take().split()[-1]
    head = src.take().split()
    assert head[0] == "Experiment"
    name = head[-1]
    props: dict[str, tuple[str, str]] = {}
    if src.peek().split()[-2:] == ["experiment", "properties"]:
        for _ in range(int(src.take().split()[0])):
            left, value = src.take().split(" = ", 1)
            *words, sql_type = left.split()
            props["_".join(words)] = (sql_type, value)
    host = src.expect()[-1] if src.peek().startswith("Running on") else None
    assert src.take().startswith("Starting at")
    assert src.take() == "<<<|"
    setup = []
    while not src.peek().startswith("|>>>"):
        setup.append(src.take())
    src.take()
    seed = int(src.expect("is", "the", "random", "seed")[0])
    time_limit = float(src.expect("seconds", "per", "run")[0])
    memory_limit = float(src.expect("MB", "per", "run")[0])
    if src.peek().split()[-3:] == ["runs", "per", "planner"]:
        src.take()
    total = float(src.expect("seconds", "spent", "to", "collect", "the", "data")[0])
    for _ in range(int(src.expect("enum", "types")[0])):
        src.take()
    columns = ", ".join(f"{k} {t}" for k, (t, _) in props.items())
    db.execute(
        "CREATE TABLE IF NOT EXISTS experiments (id INTEGER PRIMARY KEY, name TEXT, version TEXT, host TEXT, "
        "setup TEXT, seed INTEGER, timelimit REAL, memorylimit REAL, totaltime REAL"
        + (", " + columns if columns else "")
        + ")"
    )
    cur = db.execute(
        "INSERT INTO experiments (name, version, host, setup, seed, timelimit, memorylimit, totaltime"
        + "".join(f", {k}" for k in props)
        + ") VALUES (?, ?, ?, ?, ?, ?, ?, ?"
        + ", ?" * len(props)
        + ")",
        (
            name,
            version,
            host,
            "\n".join(setup),
            seed,
            time_limit,
            memory_limit,
            total,
            *(v for _, v in props.values()),
        ),
    )
    exp_id = int(cur.lastrowid or 0)
    db.execute("CREATE TABLE IF NOT EXISTS planners (id INTEGER PRIMARY KEY, name TEXT, settings TEXT)")
    db.execute(
        "CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY, experimentid INTEGER, plannerid INTEGER)"
    )
    for _ in range(int(src.expect("planners")[0])):
        planner = src.take()
        settings = [src.take() for _ in range(int(src.expect("common", "properties")[0]))]
        pid = db.execute(
            "INSERT INTO planners (name, settings) VALUES (?, ?)", (planner, ";".join(settings))
        ).lastrowid
        names = []
        existing = {row[1] for row in db.execute("PRAGMA table_info(runs)")}
        for _ in range(int(src.expect("properties", "for", "each", "run")[0])):
            *words, sql_type = src.take().split()
            col = "_".join(words)
            if col not in existing:
                db.execute(f"ALTER TABLE runs ADD {col} {sql_type}")
                existing.add(col)
            names.append(col)
        for _ in range(int(src.expect("runs")[0])):
            line = src.take()
            assert line.endswith("; ") or not names
            values = [None if v == "" else v for v in line.split("; ")[:-1]]
            assert len(values) == len(names)
            db.execute(
                f"INSERT INTO runs (experimentid, plannerid, {', '.join(names)}) "
                f"VALUES (?, ?{', ?' * len(names)})",
                (exp_id, pid, *values),
            )
        assert src.take() == "."
    return exp_id


def _record(ok: bool, **kw: Any) -> dict[str, Any]:
    if not ok:
        return {
            "ok": False,
            "reason": kw.get("reason", "no_path_within_budget"),
            "wall_s": kw.get("wall_s", 3.25),
        }
    return {
        "ok": True,
        "planning_time_s": kw.get("t", 0.125),
        "path_length": kw.get("length", 4.5),
        "min_clearance_m": kw.get("clearance", 0.0125),
        "gate_passed": True,
        "recheck_passed": kw.get("strict", True),
        "duration_s": 12.5,
        "duration_ratio": 1.0625,
        "options": kw.get("options", {}),
    }


def test_logs_parse_into_sqlite_with_every_number(tmp_path: Path) -> None:
    cases = [
        {"name": "gen-0-0", "scenario": "/tmp/gen-0-0.yaml", "goal": "bay", "min_free_m": 0.0151},
        {"name": "gen-0-1", "scenario": "/tmp/gen-0-1.yaml", "goal": "transfer"},
    ]
    default = {"gen-0-0": _record(False, wall_s=31.5), "gen-0-1": _record(True, t=0.0625, length=2.75)}
    variant_a = {"planner": "RRTConnect", "seed": 1, "time_limit_s": 30.0}
    variant_b = {"planner": "RRTConnect", "seed": 0, "time_limit_s": 30.0, "motion_margin_m": 0.001}
    exhaustive = {
        "gen-0-0": [
            {**_record(False, wall_s=30.75), "options": variant_a},
            _record(True, t=7.5, clearance=0.0101, strict=True, options=variant_b),
        ],
        "gen-0-1": [],
    }
    exps = ompl_log.generalization_experiments(
        cases, default, exhaustive, seed=7, time_limits_s={"gen-0-0": 30.0, "gen-0-1": 20.0}, version="1.2.3"
    )
    paths = ompl_log.write_generalization_logs(tmp_path / "logs", exps)
    assert [p.name for p in paths] == ["gen-0-0.log", "gen-0-1.log"]
    db = sqlite3.connect(tmp_path / "bench.db")
    ids = {p.stem: parse_into(db, p.read_text()) for p in paths}
    exp = db.execute(
        "SELECT name, version, seed, timelimit, totaltime, goal_kind, min_free_m FROM experiments "
        "WHERE id = ?",
        (ids["gen-0-0"],),
    ).fetchone()
    assert exp == ("gen-0-0", "1.2.3", 7, 30.0, 31.5 + 30.75 + 7.5, "bay", 0.0151)
    rows = db.execute(
        "SELECT planners.name, time, solved, solution_length, solution_clearance, correct_solution, "
        "correct_solution_strict, trajectory_duration, duration_ratio FROM runs JOIN planners "
        "ON planners.id = runs.plannerid WHERE experimentid = ? ORDER BY runs.id",
        (ids["gen-0-0"],),
    ).fetchall()
    assert rows == [
        ("cabinplan_default", 31.5, 0, None, None, None, None, None, None),
        ("exhaustive_RRTConnect_seed1", 30.75, 0, None, None, None, None, None, None),
        ("exhaustive_RRTConnect_seed0_margin0.001", 7.5, 1, 4.5, 0.0101, 1, 1, 12.5, 1.0625),
    ]
    (one,) = db.execute(
        "SELECT time, solution_length FROM runs WHERE experimentid = ?", (ids["gen-0-1"],)
    ).fetchall()
    assert one == (0.0625, 2.75)
    settings = db.execute("SELECT settings FROM planners WHERE name LIKE '%margin%'").fetchone()[0]
    assert "motion_margin_m = 0.001" in settings and "planner = RRTConnect" in settings


def test_a_real_plan_record_carries_its_path_length(tmp_path: Path) -> None:
    """``plan_file`` (the benchmark's worker) on a free-space move: the log's length is the profile's."""
    from bench.generalization import plan_file

    home = {"d1": 1.0, "x1": -0.46, "x2": 0.46, "x3": -0.09, "theta3": 1.2, "theta4": -0.8, "d5": -0.25}
    scenario = {
        "name": "free-transfer",
        "start": {"drives": {**home, "theta6": 0.0}},
        "goal": {"drives": {**home, "d1": 1.5, "theta6": 0.0}},
        "options": {"seed": 1, "time_limit_s": 20},
    }
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario))
    record = plan_file(str(path))
    assert record["ok"] and record["recheck_passed"]
    # a pure rail move: the drive path is the rail's 0.5 m (the other drives stay put)
    assert record["path_length"] == pytest.approx(0.5, abs=1e-9)
    run = ompl_log.run_of(record)
    text = ompl_log.log_text(
        ompl_log.Experiment("one", [ompl_log.PlannerEntry("p", {}, [run])], "s\n", 1, 20.0, 1.0)
    )
    db = sqlite3.connect(":memory:")
    parse_into(db, text)
    assert db.execute("SELECT solution_length, solved, time FROM runs").fetchone() == (
        pytest.approx(0.5, abs=1e-9),
        1,
        record["planning_time_s"],
    )


def test_the_cycle_benchmarks_campaign_runs_parse_into_sqlite(tmp_path: Path) -> None:
    """Each campaign run of ``bench.cycles`` is one experiment, a run per cycle, refused cycles included."""
    rows = [
        {"status": "succeeded", "planning_time_s": 1.25, "min_clearance_m": 0.0144, "duration_s": 37.75},
        {
            "status": "failed",
            "planning_time_s": None,
            "wall_time_s": 30.5,
            "reason": "no_path_within_time_limit",
        },
    ]
    exp = ompl_log.cycle_experiment("gen-camp-0-100-given", rows, seed=3, time_limit_s=30.0)
    path = ompl_log.write_log(exp, tmp_path / "logs" / "gen-camp-0-100-given.log")
    db = sqlite3.connect(tmp_path / "cycles.db")
    eid = parse_into(db, path.read_text())
    assert db.execute(
        "SELECT name, seed, timelimit, totaltime, cycles FROM experiments WHERE id = ?", (eid,)
    ).fetchone() == (
        "gen-camp-0-100-given",
        3,
        30.0,
        1.25 + 30.5,
        2,
    )
    runs = db.execute(
        "SELECT time, solved, solution_clearance, correct_solution, trajectory_duration FROM runs "
        "WHERE experimentid = ? ORDER BY id",
        (eid,),
    ).fetchall()
    assert runs == [(1.25, 1, 0.0144, 1, 37.75), (30.5, 0, None, None, None)]
