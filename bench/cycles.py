"""Cycles and campaigns benchmark: generated campaigns planned with the default options (issue 24 targets).

Measured, all in one run and on one executor (embedded warm workers, ``--workers`` of them; ``--ray``: a
local Ray with as many CPUs):

* **cycles solved / solvable**: each generated unit's cycle in the empty cabin (the generator's witnesses
  make it solvable: every key configuration has an exact, clear, holdable IK solution) planned with the
  default options                                                          [>= 99% of solvable cycles]
* **time per cycle**: the cycle planner's own clock (``report.planning_time_s``), median and p95 over every
  planned cycle, refusals included                                          [median <= 1.0 s, p95 <= 4 s]
* **campaigns with a feasible order found / having one**: ground truth from an exhaustive search (every
  unit in every cabin state: n 2^(n-1) cycles, so small campaigns, 3-4 units); found by ``order: find``
  run afresh (its own folder: no cycle reused from the exhaustive search)
* **time per campaign**: ``order: given`` over campaigns of 5 units (wall clock)       [median <= 6 s]
  and ``order: find`` over a campaign of 6 units (wall clock)                          [<= 60 s, 2 cores]
* **the independent check**: every planned cycle's profile document re-checked by
  :func:`planner.task.check.check_cycle` against its own cycle document (every profile must pass), and
  the spring-back of the events (attach, detach) over them, in mm;
* **the suite's plans** in the same process: the reference scenarios expected to succeed, planned once
  each (success and end-to-end time), so that a cycle figure and a plan figure share the machine's state.

The machine's load (``os.getloadavg``) is printed before and after: every wall-clock figure depends on it.

Run: ``python -m bench.cycles [--seed S] [--small N] [--given N] [--find N] [--workers W] [--ray]
[--json out.json]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import ompl_log
from planner.campaign.run import CampaignRun
from planner.generate.cycles import (
    CycleGeneratorOptions,
    GeneratedCampaign,
    generate_campaign,
    write_campaign,
)
from planner.sweep.run import EmbeddedExecutor, Executor, RayExecutor
from planner.task.campaign_schema import Campaign, load_campaign_file

TARGETS = (
    "targets: >= 99% of solvable cycles planned; cycle median <= 1.0 s, p95 <= 4 s; 5-unit given order "
    "median <= 6 s; find over 6 units <= 60 s on 2 cores"
)


def _pct(values: list[float], q: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[k]


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} cores"


def _executor(args: argparse.Namespace) -> Executor:
    """The executor of every cycle (no warm-up plan: the planner's own clock times each cycle)."""
    if args.ray:
        return RayExecutor(None, args.workers)
    return EmbeddedExecutor(args.workers)


def _write(case: GeneratedCampaign, folder: Path, order: str, name: str | None = None) -> Path:
    data = {**case.campaign, "order": order}
    if name:
        data["name"] = name
    case = GeneratedCampaign(data["name"], data, case.mesh_name, case.mesh_bytes, case.meta)
    return write_campaign(case, folder)


def exhaustive(run: CampaignRun) -> tuple[bool, list[dict[str, Any]]]:
    """Plan every unit in every cabin state; whether some order installs every unit, and the rows."""
    ids = run.campaign.ids
    queries = [
        (u, frozenset(s))
        for u in ids
        for k in range(len(ids))
        for s in itertools.combinations([v for v in ids if v != u], k)
    ]
    jobs = [run.job(u, s) for u, s in queries]
    rows = run.plan(jobs)
    ok = {(u, s): row.get("status") == "succeeded" for (u, s), row in zip(queries, rows, strict=True)}
    reach: set[frozenset[str]] = {frozenset()}
    for size in range(len(ids)):
        reach = {s | {u} for s in reach if len(s) == size for u in ids if u not in s and ok[(u, s)]}
    return bool(reach), rows


def _campaign(path: Path) -> Campaign:
    return load_campaign_file(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--small", type=int, default=3, help="campaigns of 3-4 units with ground truth")
    parser.add_argument("--given", type=int, default=2, help="campaigns of 5 units, given order")
    parser.add_argument("--find", type=int, default=1, help="campaigns of 6 units, order: find")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--ray", action="store_true", help="run the cycles on a local Ray")
    parser.add_argument("--no-suite", action="store_true", help="skip the reference scenarios' plans")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument(
        "--ompl-log",
        type=Path,
        default=None,
        help="also write OMPL benchmark logs here",
    )
    args = parser.parse_args(argv)
    journals: list[tuple[str, list[dict[str, Any]], float]] = []  # (experiment, rows, time limit [s])
    print(f"bench.cycles: {_load()} (start)", flush=True)
    folder = Path(tempfile.mkdtemp(prefix="cabinplan-bench-cycles-"))
    t_gen = time.perf_counter()

    # Blocking pairs and an end bay made likely: campaigns where the order matters, with room for 5-6 units.
    def options(units: tuple[int, int]) -> CycleGeneratorOptions:
        return CycleGeneratorOptions(
            units=units, pair_probability=0.6, end_bay_probability=0.6, max_attempts=60
        )

    small = [generate_campaign(args.seed, i, options((3, 4))) for i in range(args.small)]
    given = [generate_campaign(args.seed, 100 + i, options((5, 5))) for i in range(args.given)]
    finds = [generate_campaign(args.seed, 200 + i, options((6, 6))) for i in range(args.find)]
    print(
        f"generated {len(small) + len(given) + len(finds)} campaigns in {time.perf_counter() - t_gen:.1f} s"
    )
    executor = _executor(args)
    record: dict[str, Any] = {"load_start": os.getloadavg(), "executor": "ray" if args.ray else "embedded"}
    try:
        # 1. Small campaigns: exhaustive ground truth, then order: find afresh.
        cycles_alone: list[dict[str, Any]] = []
        cycle_times: list[float] = []
        truth_found = []
        for case in small:
            path = _write(case, folder / case.name, "find")
            camp = _campaign(path)
            ex = CampaignRun(camp, folder / case.name / "exhaustive", executor, base_dir=path.parent)
            t0 = time.perf_counter()
            has_order, rows = exhaustive(ex)
            wall = time.perf_counter() - t0
            journals.append((f"{case.name}-exhaustive", [r for r in rows if r], camp.options.time_limit_s))
            cycle_times += [float(r["planning_time_s"] or r["wall_time_s"]) for r in rows if r]
            for u in camp.ids:
                row = ex.journal.rows[ex.job(u, ()).sha256]
                cycles_alone.append(
                    {
                        "campaign": case.name,
                        "unit": u,
                        **{k: row.get(k) for k in ("status", "reason", "message")},
                    }
                )
            fr = CampaignRun(camp, folder / case.name / "find", executor, base_dir=path.parent)
            t0 = time.perf_counter()
            res = fr.run()
            find_wall = time.perf_counter() - t0
            truth_found.append(
                {
                    "campaign": case.name,
                    "units": len(camp.ids),
                    "has_order": has_order,
                    "found": res.succeeded,
                    "order": res.order,
                    "exhaustive_cycles": len(rows),
                    "exhaustive_wall_s": wall,
                    "find_cycles": res.cycles_planned,
                    "find_wall_s": find_wall,
                    "precedence_generated": case.meta["precedence"],
                }
            )
            print(
                f"{case.name}: {len(camp.ids)} units, order exists: {has_order}, found: {res.succeeded} "
                f"{' '.join(res.order)} ({res.cycles_planned} cycles, {find_wall:.1f} s); exhaustive "
                f"{len(rows)} cycles in {wall:.1f} s",
                flush=True,
            )

        # 2. Given order over 5 units; 3. order: find over 6 units.
        def campaign_run(case: GeneratedCampaign, order: str) -> tuple[Any, float]:
            """Run one campaign afresh; (its result, its wall time [s]), its cycles recorded."""
            path = _write(case, folder / case.name, order)
            run = CampaignRun(_campaign(path), folder / case.name / order, executor, base_dir=path.parent)
            t0 = time.perf_counter()
            res = run.run()
            wall = time.perf_counter() - t0
            rows = list(run.journal.rows.values())
            journals.append((f"{case.name}-{order}", rows, run.campaign.options.time_limit_s))
            cycle_times.extend(float(r["planning_time_s"] or r["wall_time_s"]) for r in rows)
            return res, wall

        given_walls = []
        for case in given:
            res, wall = campaign_run(case, "given")
            given_walls.append(wall)
            outcome = "all installed" if res.succeeded else res.message
            print(f"{case.name}: given order, {outcome} ({wall:.1f} s)", flush=True)
        find_walls = []
        for case in finds:
            res, wall = campaign_run(case, "find")
            find_walls.append(wall)
            print(
                f"{case.name}: find over 6 units: {' '.join(res.order) or res.message} "
                f"({res.cycles_planned} cycles, {wall:.1f} s)",
                flush=True,
            )
    finally:
        executor.close()
    solved = sum(1 for c in cycles_alone if c["status"] == "succeeded")
    having = [t for t in truth_found if t["has_order"]]
    found = [t for t in having if t["found"]]
    wrong = [t for t in truth_found if t["found"] and not t["has_order"]]
    checks = independent_checks(folder)
    suite = None if args.no_suite else _suite()
    record.update(
        cycles_alone=cycles_alone,
        campaigns=truth_found,
        cycle_time_s={
            "median": _pct(cycle_times, 0.5),
            "p95": _pct(cycle_times, 0.95),
            "n": len(cycle_times),
        },
        independent_check=checks,
        given_wall_s=given_walls,
        find_wall_s=find_walls,
        suite=suite,
        load_end=os.getloadavg(),
    )
    print()
    print(TARGETS)
    print(f"cycles solved by the default / solvable (each unit alone):  {solved}/{len(cycles_alone)}")
    for c in cycles_alone:
        if c["status"] != "succeeded":
            print(f"  refused: {c['campaign']} {c['unit']}: {c['reason']}: {(c['message'] or '')[:150]}")
    print(
        f"campaigns with a feasible order found / having one:          {len(found)}/{len(having)}"
        f" (of {len(truth_found)}; found without one: {len(wrong)})"
    )
    ct = record["cycle_time_s"]
    print(
        f"time per cycle (planner's clock, n={ct['n']}): median {ct['median']:.2f} s, p95 {ct['p95']:.2f} s"
        if ct["n"]
        else "time per cycle: no cycle planned"
    )
    print(
        f"profiles passing the independent check (every planned cycle's document, re-checked): "
        f"{checks['passed']}/{checks['checked']}"
    )
    for f in checks["failed"]:
        print(f"  FAILED the independent check: {f}")
    for kind, (lo, hi) in checks["springback_mm"].items():
        print(f"spring-back at {kind} (the events' jump, every planned cycle): {lo:.3f}-{hi:.3f} mm")
    if given_walls:
        print(
            f"campaigns of 5 units, given order (wall): median {statistics.median(given_walls):.1f} s "
            f"over {len(given_walls)}"
        )
    if find_walls:
        print(f"order: find over 6 units (wall): {', '.join(f'{w:.1f} s' for w in find_walls)}")
    if suite is not None:
        print(
            f"suite: {suite['succeeded']}/{suite['plans']} reference plans succeeded, median "
            f"{suite['median_s']:.2f} s, p95 {suite['p95_s']:.2f} s"
        )
    print(f"bench.cycles: {_load()} (end); executor {record['executor']} with {args.workers} workers")
    if args.ompl_log is not None:
        logs = [
            ompl_log.write_log(
                ompl_log.cycle_experiment(name, rows, seed=args.seed, time_limit_s=float(limit)),
                args.ompl_log / f"{name}.log",
            )
            for name, rows, limit in journals
        ]
        print(f"OMPL benchmark logs: {len(logs)} -> {args.ompl_log}")
    if args.json:
        args.json.write_text(json.dumps(record, indent=1, default=str) + "\n", encoding="utf-8")
    return 0


def independent_checks(folder: Path) -> dict[str, Any]:
    """Every planned cycle's profile document re-checked by the independent gate, and its spring-backs.

    Each campaign run's ``cycles/profiles/<cycle>.json`` that is a cycle profile (refusals apart) is
    checked against its own cycle document (``cycles/scenarios/<cycle>.json``, resolved afresh) by
    :func:`planner.task.check.check_cycle`, which rebuilds every leg's world, load and line itself.

    Returns:
        ``{"checked", "passed", "failed": [file: failures], "springback_mm": {event kind: (min, max)}}``.
    """
    from planner.task.check import check_cycle
    from planner.task.resolve import resolve_cycle
    from planner.task.schema import cycle_from_dict

    checked, passed, failed = 0, 0, []
    jumps: dict[str, list[float]] = {}
    for path in sorted(folder.glob("*/*/cycles/profiles/*.json")):  # <campaign>/<run>/cycles/profiles
        doc = json.loads(path.read_text(encoding="utf-8"))
        if doc.get("status", "succeeded") != "succeeded" or doc.get("kind") != "cycle":
            continue
        out_dir = path.parent.parent
        spec = json.loads((out_dir / "scenarios" / path.name).read_text(encoding="utf-8"))
        base_dir = out_dir.parent.parent  # the campaign file's folder (its meshes)
        cyc = resolve_cycle(cycle_from_dict(spec, source=str(path)), base_dir=base_dir)
        report = check_cycle(cyc, doc)
        checked += 1
        if report.passed:
            passed += 1
        else:
            failed.append(f"{path}: {report.summary()}")
        for event in doc.get("events", []):
            jumps.setdefault(str(event["kind"]), []).append(1e3 * float(event["springback_m"]))
    ranges = {kind: (min(v), max(v)) for kind, v in sorted(jumps.items())}
    return {"checked": checked, "passed": passed, "failed": failed, "springback_mm": ranges}


def _suite() -> dict[str, Any]:
    """The reference scenarios expected to succeed, planned once each in this process (product mode)."""
    from bench.planning import feasible_scenarios, run_once
    from planner.scenario import load_scenario

    scenarios = Path(__file__).resolve().parent.parent / "tests" / "scenarios"
    runs = [run_once(load_scenario(scenarios / f"{name}.yaml"), "product") for name in feasible_scenarios()]
    times = [r["time_s"] for r in runs]
    return {
        "plans": len(runs),
        "succeeded": sum(1 for r in runs if r["ok"]),
        "median_s": _pct(times, 0.5) or 0.0,
        "p95_s": _pct(times, 0.95) or 0.0,
    }


if __name__ == "__main__":
    sys.exit(main())
