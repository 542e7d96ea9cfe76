"""OMPL's benchmark log format, so the product's figures sit next to other planners' in Planner Arena.

The grammar is the one ``ompl_benchmark_statistics.py`` reads into SQLite (OMPL's benchmarking docs,
"Processing the benchmarking log file"). One log file is one experiment -- here one benchmark problem
(a scenario); every planner configuration that ran on it is an entry with its runs::

    cabinplan version <version>
    Experiment <name without spaces>
    <K> experiment properties
    <name> <SQL type> = <value>                      (K lines)
    Running on <host>
    Starting at <date>
    <<<|
    <setup, any lines>
    |>>>
    <seed> is the random seed
    <t> seconds per run
    <m> MB per run
    <r> runs per planner                              (optional: entries may have other counts)
    <total> seconds spent to collect the data
    0 enum types
    <P> planners
    <planner name>                                   (per planner:)
    <C> common properties
    <name> = <value>                                 (C lines)
    <R> properties for each run
    <property words> <TYPE>                          (R lines; TYPE is REAL, INTEGER, BOOLEAN, ...)
    <N> runs
    <v1>; <v2>; ...; <vR>;                           (N lines; an empty value is NULL)
    .

Run properties written here (:data:`RUN_PROPERTIES`): ``time`` (planning time [s]; wall time of a
refusal), ``solved``, ``solution length`` (the drive path's length, Euclidean in drive coordinates,
metres and radians mixed as OMPL mixes its state-space coordinates), ``solution clearance`` (the gate's
certified minimum clearance [m]), ``correct solution`` (the planner's own gate passed), ``correct solution
strict`` (the independent re-check of the profile after a JSON round trip passed), ``trajectory duration``
[s] and ``duration ratio`` (duration over the single-drive lower bound).
"""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: (property name, SQL type) of every run, in the order of each run line.
RUN_PROPERTIES: tuple[tuple[str, str], ...] = (
    ("time", "REAL"),
    ("solved", "BOOLEAN"),
    ("solution length", "REAL"),
    ("solution clearance", "REAL"),
    ("correct solution", "BOOLEAN"),
    ("correct solution strict", "BOOLEAN"),
    ("trajectory duration", "REAL"),
    ("duration ratio", "REAL"),
)


@dataclass(frozen=True)
class PlannerEntry:
    """One planner configuration of an experiment: its name, settings and runs (values by property name)."""

    name: str
    settings: Mapping[str, str]
    runs: Sequence[Mapping[str, float | int | bool | None]]


@dataclass(frozen=True)
class Experiment:
    """One benchmark problem with the planner entries that ran on it."""

    name: str
    planners: Sequence[PlannerEntry]
    setup: str
    seed: int
    time_limit_s: float
    total_time_s: float
    memory_limit_mb: float = 0.0
    properties: Mapping[str, tuple[str, str | float | int]] = field(default_factory=dict)
    host: str = field(default_factory=platform.node)
    date: str = field(default_factory=lambda: time.strftime("%Y-%m-%d %H:%M:%S"))
    version: str = "0"


def _token(text: str) -> str:
    """A name the grammar reads as one token (no spaces)."""
    return "_".join(str(text).split()) or "unnamed"


def _value(v: float | int | bool | None) -> str:
    if v is None:
        return ""
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if isinstance(v, int | np.integer):
        return str(int(v))
    f = float(v)
    return repr(f) if math.isfinite(f) else ""


def log_text(exp: Experiment) -> str:
    """The experiment as an OMPL benchmark log (see the module docstring)."""
    lines = [f"cabinplan version {_token(exp.version)}", f"Experiment {_token(exp.name)}"]
    lines.append(f"{len(exp.properties)} experiment properties")
    for name, (sql_type, value) in exp.properties.items():
        lines.append(f"{_token(name)} {sql_type} = {value}")
    lines += [f"Running on {_token(exp.host)}", f"Starting at {exp.date}", "<<<|"]
    lines += [s for s in exp.setup.splitlines() if not s.startswith(("<<<|", "|>>>"))]
    lines += [
        "|>>>",
        f"{int(exp.seed)} is the random seed",
        f"{float(exp.time_limit_s)!r} seconds per run",
        f"{float(exp.memory_limit_mb)!r} MB per run",
    ]
    counts = {len(p.runs) for p in exp.planners}
    if len(counts) == 1:
        lines.append(f"{counts.pop()} runs per planner")
    lines += [
        f"{float(exp.total_time_s)!r} seconds spent to collect the data",
        "0 enum types",
        f"{len(exp.planners)} planners",
    ]
    for planner in exp.planners:
        lines.append(_token(planner.name))
        lines.append(f"{len(planner.settings)} common properties")
        lines += [f"{_token(k)} = {v}" for k, v in planner.settings.items()]
        lines.append(f"{len(RUN_PROPERTIES)} properties for each run")
        lines += [f"{name} {sql_type}" for name, sql_type in RUN_PROPERTIES]
        lines.append(f"{len(planner.runs)} runs")
        for run in planner.runs:
            lines.append("".join(f"{_value(run.get(name))}; " for name, _ in RUN_PROPERTIES))
        lines.append(".")
    return "\n".join(lines) + "\n"


def write_log(exp: Experiment, path: Path) -> Path:
    """Write one experiment's log file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(log_text(exp), encoding="utf-8")
    return path


def path_length(position: Any) -> float:
    """Length of a drive path (N, D): the sum of the Euclidean steps between samples [m and rad mixed]."""
    u = np.asarray(position, dtype=float)
    return float(np.linalg.norm(np.diff(u, axis=0), axis=1).sum()) if len(u) > 1 else 0.0


def run_of(record: Mapping[str, Any]) -> dict[str, float | int | bool | None]:
    """The run properties of one plan record of :func:`bench.generalization.plan_file`."""
    ok = bool(record.get("ok"))
    return {
        "time": record.get("planning_time_s") if ok else record.get("wall_s"),
        "solved": ok,
        "solution length": record.get("path_length") if ok else None,
        "solution clearance": record.get("min_clearance_m") if ok else None,
        "correct solution": bool(record.get("gate_passed")) if ok else None,
        "correct solution strict": bool(record.get("recheck_passed")) if ok else None,
        "trajectory duration": record.get("duration_s") if ok else None,
        "duration ratio": record.get("duration_ratio") if ok else None,
    }


def variant_name(options: Mapping[str, Any]) -> str:
    """The planner entry's name of an exhaustive variant's options (``planner``, ``seed``, margin)."""
    name = f"exhaustive_{options.get('planner', 'RRTConnect')}_seed{options.get('seed', 0)}"
    if options.get("motion_margin_m") is not None:
        name += f"_margin{options['motion_margin_m']}"
    return name


def generalization_experiments(
    cases: Sequence[Mapping[str, Any]],
    default: Mapping[str, Mapping[str, Any]],
    exhaustive: Mapping[str, Sequence[Mapping[str, Any]]],
    *,
    seed: int,
    time_limits_s: Mapping[str, float],
    version: str = "0",
) -> list[Experiment]:
    """One experiment per generated case: the default planner and every exhaustive variant that ran on it.

    Args:
        cases: The generated cases (``name``, ``scenario``, ``goal`` ...), as the benchmark's manifest.
        default: The default mode's record by case name.
        exhaustive: The exhaustive variants' records by case name, in the order they ran.
        seed: The generator's seed.
        time_limits_s: The default's time limit by case name [s].
        version: The planner's version.
    """
    out = []
    for case in cases:
        name = str(case["name"])
        base = default[name]
        entries = [
            PlannerEntry(
                "cabinplan_default",
                {"preset": "product", "planner": "RRTConnect", "time_limit_s": str(time_limits_s[name])},
                [run_of(base)],
            )
        ]
        for rec in exhaustive.get(name, []):
            opts = dict(rec.get("options") or {})
            settings = {"preset": "product", **{k: str(v) for k, v in opts.items()}}
            entries.append(PlannerEntry(variant_name(opts), settings, [run_of(rec)]))
        times = [float(t) for e in entries for r in e.runs if isinstance(t := r.get("time"), int | float)]
        props: dict[str, tuple[str, str | float | int]] = {"generator_seed": ("INTEGER", int(seed))}
        if case.get("goal") is not None:
            props["goal_kind"] = ("TEXT", str(case["goal"]))
        if case.get("min_free_m") is not None:
            props["min_free_m"] = ("REAL", float(case["min_free_m"]))
        out.append(
            Experiment(
                name=name,
                planners=entries,
                setup=f"scenario {case.get('scenario', name)}\n",
                seed=int(seed),
                time_limit_s=float(time_limits_s[name]),
                total_time_s=float(sum(times)),
                properties=props,
                version=version,
            )
        )
    return out


def write_generalization_logs(out_dir: Path, experiments: Sequence[Experiment]) -> list[Path]:
    """One ``<experiment>.log`` per experiment in ``out_dir`` (``ompl_benchmark_statistics.py`` reads all)."""
    return [write_log(e, out_dir / f"{_token(e.name)}.log") for e in experiments]


def cycle_run_of(row: Mapping[str, Any]) -> dict[str, float | int | bool | None]:
    """The run properties of one cycle of a campaign's journal (:mod:`planner.campaign.worker`'s row).

    A planned cycle passed the cycle gate over its whole timeline (``correct solution``); its clearance is
    the cycle's exact minimum over every sample. Cycles have no single path length in one space (their
    legs carry different loads): left empty, as the strict re-check, which the benchmark does not run.
    """
    ok = row.get("status") == "succeeded"
    wall = row.get("planning_time_s") if row.get("planning_time_s") is not None else row.get("wall_time_s")
    return {
        "time": wall,
        "solved": ok,
        "solution length": None,
        "solution clearance": row.get("min_clearance_m") if ok else None,
        "correct solution": True if ok else None,
        "correct solution strict": None,
        "trajectory duration": row.get("duration_s") if ok else None,
        "duration ratio": None,
    }


def cycle_experiment(
    name: str, rows: Sequence[Mapping[str, Any]], *, seed: int, time_limit_s: float, version: str = "0"
) -> Experiment:
    """One experiment of the cycle benchmark: every cycle a campaign run planned, as runs of the default.

    Args:
        name: The experiment's name (e.g. the campaign's).
        rows: The journal rows of its cycles (one per cycle planned, refused ones included).
        seed: The generator's seed.
        time_limit_s: The cycles' time limit [s].
        version: The planner's version.
    """
    runs = [cycle_run_of(r) for r in rows]
    total = sum((float(t) for r in runs if isinstance(t := r.get("time"), int | float)), 0.0)
    return Experiment(
        name=name,
        planners=[PlannerEntry("cabinplan_cycle_default", {"preset": "product"}, runs)],
        setup=f"campaign {name}: one run per cycle planned\n",
        seed=int(seed),
        time_limit_s=float(time_limit_s),
        total_time_s=total,
        properties={"generator_seed": ("INTEGER", int(seed)), "cycles": ("INTEGER", len(runs))},
        version=version,
    )
