"""End-to-end planning benchmark: the product planner against the naive baseline (issue targets in brackets).

For every feasible reference scenario (``status: succeeded`` in ``tests/scenarios/expected.yaml``) and
seeds 0..N-1, both planner modes run in the same process, interleaved per seed (the order alternates with
the seed), seed by seed over all scenarios, so that machine noise hits both modes and every scenario
alike:

* product  -- ``Planner(sc)``: straight line, transit postures, OMPL with a tuned range, shortcuts,
  certified corner blends;
* baseline -- ``Planner(sc, preset=BASELINE)``: plain OMPL RRTConnect with OMPL's defaults, the raw path, a
  stop at every waypoint; the same TOPP-RA timing and validation gate.

Measured per scenario and mode:

* success rate; a refusal (any :class:`~planner.core.exceptions.PlannerError`) is a failure, counted by reason
                                                                               [100% on feasible scenarios]
* end-to-end planning time, ``time.perf_counter()`` around ``Planner(sc).plan()``, median and p95 over
  every run, failures included (a failure costs up to the time limit)        [median <= 0.5 s, p95 <= 2 s]
* trajectory duration (median) and duration / single-drive lower bound (median, max)            [<= 1.15]
* minimum clearance over the runs (gate) and the fraction of returned profiles that passed the gate.

Times are "warm": the collision world's cabin geometry (FCL BVH, clearance grid) is cached per process
and shared by every plan on that cabin. Before its seeds, each scenario is planned once more (product
mode, seed 0) and that first plan is reported on its own as the cold time; it is cold for the process
only if no earlier scenario used the same cabin (the table says which), and its clearance grid may come
from the on-disk cache.

Run: ``python -m bench.planning [--seeds N] [--scenarios a b] [--time-limit-s T] [--json out.json]``
(or ``make bench``). The baseline's time limit is capped (``--baseline-cap-s``, default 20 s) so the
default run stays near ten minutes on two cores; the output states the cap.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from planner.core.cache import cache_dir
from planner.core.exceptions import PlannerError
from planner.plan.context import BASELINE, PRODUCT
from planner.plan.goals import line_speed_bounds
from planner.plan.pipeline import Planner
from planner.scenario.resolve import ResolvedScenario, load_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "tests" / "scenarios"
MODES = ("product", "baseline")
#: Default cap on the baseline's time limit [s]: the raw planner needs 15-20 s on the hatch cabin.
BASELINE_CAP_S = 20.0
TARGETS = (
    "targets: 100% success on feasible scenarios; median end-to-end <= 0.5 s, p95 <= 2 s; "
    "duration <= 1.15 x single-drive lower bound"
)


def feasible_scenarios() -> list[str]:
    """Names of the reference scenarios expected to succeed, in the order of ``expected.yaml``."""
    expected = yaml.safe_load((SCENARIOS / "expected.yaml").read_text())
    return [name for name, entry in expected.items() if entry.get("status") == "succeeded"]


def with_options(sc: ResolvedScenario, **update: Any) -> ResolvedScenario:
    """The resolved scenario with some planning options replaced (the planner reads ``sc.options``)."""
    options = sc.options.model_copy(update=update)
    return dataclasses.replace(sc, options=options, spec=sc.spec.model_copy(update={"options": options}))


def run_once(sc: ResolvedScenario, mode: str) -> dict[str, Any]:
    """Plan once; the raw measurement (a refusal is recorded with its reason, never raised)."""
    out: dict[str, Any] = {"mode": mode, "seed": sc.options.seed, "time_limit_s": sc.options.time_limit_s}
    t0 = time.perf_counter()
    try:
        res = Planner(sc, preset=BASELINE if mode == "baseline" else PRODUCT).plan()
    except PlannerError as exc:
        out.update(time_s=time.perf_counter() - t0, ok=False, reason=exc.reason, message=exc.message)
        return out
    except Exception as exc:  # a crash is a failure as well; keep it in the figures, not fatal to the run
        out.update(time_s=time.perf_counter() - t0, ok=False, reason=f"error:{type(exc).__name__}")
        out["message"] = str(exc)
        return out
    elapsed = time.perf_counter() - t0
    rep = res.report
    out.update(
        time_s=elapsed,
        ok=True,
        reason=None,
        duration_s=float(res.profile.duration_s),
        lower_bound_s=float(rep["single_drive_lower_bound_s"]),
        duration_ratio=float(rep["duration_ratio"]),
        staged_ratio=float(rep.get("staged_duration_ratio", rep["duration_ratio"])),
        min_clearance_m=float(res.gate.min_clearance_m),
        gate_passed=bool(res.gate.passed),
        gate_summary=res.gate.summary(),
        search=rep.get("search"),
        stages_s=rep.get("stages_s"),
        samples=int(len(res.profile.t)),
        waypoints=int(len(res.waypoints)),
    )
    return out


def stats(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Summary figures of a list of runs (one scenario and mode, or pooled)."""
    ok = [r for r in runs if r["ok"]]
    times = np.array([r["time_s"] for r in runs])
    s: dict[str, Any] = {
        "runs": len(runs),
        "succeeded": len(ok),
        "success_rate": len(ok) / len(runs) if runs else float("nan"),
        "time_median_s": float(np.median(times)) if runs else float("nan"),
        "time_p95_s": float(np.percentile(times, 95)) if runs else float("nan"),
        "refusals": dict(Counter(r["reason"] for r in runs if not r["ok"])),
        "search": dict(Counter((r["search"] or {}).get("method", "?") for r in ok)),
    }
    if ok:
        ratios = np.array([r["duration_ratio"] for r in ok])
        s.update(
            time_ok_median_s=float(np.median([r["time_s"] for r in ok])),
            duration_median_s=float(np.median([r["duration_s"] for r in ok])),
            ratio_median=float(np.median(ratios)),
            ratio_max=float(np.max(ratios)),
            staged_ratio_median=float(np.median([r["staged_ratio"] for r in ok])),
            min_clearance_m=float(min(r["min_clearance_m"] for r in ok)),
            gate_pass_fraction=sum(r["gate_passed"] for r in ok) / len(ok),
        )
    return s


def insertion_bounds(names: list[str]) -> None:
    """Why no insertion comes near the single-drive bound: the line's own speed limit, by linear programs.

    For each insertion scenario (seed 0), at 20 configurations of the executed insertion line: the fastest
    the payload can move along the line with its orientation fixed within the drive velocity limits, and
    the fastest the rail can move meanwhile (:func:`planner.plan.goals.line_speed_bounds`). With the
    rail unable to move during the line, no trajectory beats the single-drive bound plus length / speed.
    """
    rows = []
    for name in names:
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        if sc.approach_direction is None or sc.T_base_payload_goal is None or sc.payload is None:
            continue
        res = Planner(sc).plan()
        d = sc.approach_direction / np.linalg.norm(sc.approach_direction)
        q = res.profile.joints
        p = (sc.robot.fk_batch(q) @ sc.payload.T_tool_payload)[:, :3, 3]
        back = -((p - p[-1]) @ d)
        k = int(np.flatnonzero(back >= sc.approach_distance_m - 1e-3)[-1])
        b = line_speed_bounds(sc.robot, q[k :: max(1, (len(q) - k) // 20)], sc.payload.T_tool_payload, d)
        executed = float(np.max(np.diff(p[k:] @ d) / np.diff(res.profile.t[k:])))
        lb = float(res.report["single_drive_lower_bound_s"])
        t_line = sc.approach_distance_m / float(b.line_m_s.max())
        rows.append(
            [
                name,
                fmt(sc.approach_distance_m, ".2f"),
                fmt(float(b.line_m_s.max()), ".3f"),
                fmt(executed, ".3f"),
                fmt(float(b.rail_m_s.max()), ".3f"),
                fmt(t_line, ".2f"),
                fmt(lb, ".2f"),
                fmt((lb + t_line) / lb, ".2f"),
                fmt(res.profile.duration_s / (lb + t_line), ".2f"),
            ]
        )
    if not rows:
        return
    print(
        "\ninsertions: the line's own limit (linear programs at the executed line's configurations, seed 0)"
    )
    table(
        [
            "scenario",
            "line [m]",
            "max line speed [m/s]",
            "executed max [m/s]",
            "max rail speed on line [m/s]",
            "line >= [s]",
            "single-drive LB [s]",
            "(LB + line) / LB",
            "duration / (LB + line)",
        ],
        rows,
    )


def fmt(value: Any, spec: str) -> str:
    """Format a number, or '-' when it is missing / NaN."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-"
    return format(value, spec)


def table(headers: list[str], rows: list[list[str]]) -> None:
    """Print a fixed-width table: first column left-aligned, the rest right-aligned."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]

    def line(cells: list[str]) -> str:
        first = f"{cells[0]:<{widths[0]}}"
        rest = (f"{c:>{w}}" for c, w in zip(cells[1:], widths[1:], strict=True))
        return "  ".join([first, *rest]).rstrip()

    print(line(headers))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print(line(r))


def mode_table(mode: str, names: list[str], summaries: dict[str, dict[str, Any]]) -> None:
    headers = [
        "scenario",
        "ok/runs",
        "success",
        "t med [s]",
        "t p95 [s]",
        "dur med [s]",
        "dur/LB med",
        "dur/LB max",
        "dur/staged LB med",
        "min clr/req [mm]",
        "gate pass",
        "search (ok runs)",
        "refusals",
    ]
    rows = []
    for name in [*names, "all"]:
        s = summaries[name]
        rows.append(
            [
                name,
                f"{s['succeeded']}/{s['runs']}",
                fmt(100 * s["success_rate"], ".0f") + "%",
                fmt(s["time_median_s"], ".3f"),
                fmt(s["time_p95_s"], ".3f"),
                fmt(s.get("duration_median_s"), ".2f"),
                fmt(s.get("ratio_median"), ".2f"),
                fmt(s.get("ratio_max"), ".2f"),
                fmt(s.get("staged_ratio_median"), ".2f"),
                (fmt(1e3 * s["min_clearance_m"], ".1f") if "min_clearance_m" in s else "-")
                + (f"/{s['clearance_req']}" if "clearance_req" in s else ""),
                fmt(100 * s["gate_pass_fraction"], ".0f") + "%" if "gate_pass_fraction" in s else "-",
                " ".join(f"{k} {v}" for k, v in sorted(s["search"].items())) or "-",
                " ".join(f"{k} {v}" for k, v in sorted(s["refusals"].items())) or "-",
            ]
        )
    table(headers, rows)


def comparison_table(names: list[str], summ: dict[str, dict[str, dict[str, Any]]]) -> None:
    headers = [
        "scenario",
        "success prod/base",
        "t med prod [s]",
        "t med base [s]",
        "t ratio p/b",
        "dur med prod [s]",
        "dur med base [s]",
        "dur ratio p/b",
    ]
    rows = []
    for name in [*names, "all"]:
        p, b = summ["product"][name], summ["baseline"][name]
        dp, db = p.get("duration_median_s"), b.get("duration_median_s")
        rows.append(
            [
                name,
                f"{100 * p['success_rate']:.0f}% / {100 * b['success_rate']:.0f}%",
                fmt(p["time_median_s"], ".3f"),
                fmt(b["time_median_s"], ".3f"),
                fmt(p["time_median_s"] / b["time_median_s"], ".2f"),
                fmt(dp, ".2f"),
                fmt(db, ".2f"),
                fmt(dp / db, ".2f") if dp is not None and db else "-",
            ]
        )
    table(headers, rows)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    feasible = feasible_scenarios()
    ap = argparse.ArgumentParser(
        prog="python -m bench.planning", description="Planning benchmark: product planner vs naive baseline."
    )
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per scenario and mode (default 10)")
    ap.add_argument(
        "--scenarios", nargs="+", choices=feasible, default=feasible, metavar="NAME", help=" ".join(feasible)
    )
    ap.add_argument(
        "--time-limit-s", type=float, default=None, help="override every scenario's time limit [s]"
    )
    ap.add_argument(
        "--baseline-cap-s",
        type=float,
        default=BASELINE_CAP_S,
        help=f"cap on the baseline's time limit [s] (default {BASELINE_CAP_S:g}; 0: no cap)",
    )
    ap.add_argument("--json", type=Path, default=None, metavar="PATH", help="dump every raw measurement")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error("--seeds must be >= 1")
    if args.time_limit_s is not None and not 0 < args.time_limit_s <= 600:
        ap.error("--time-limit-s must be in (0, 600]")
    if args.baseline_cap_s < 0:
        ap.error("--baseline-cap-s must be >= 0")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    names: list[str] = args.scenarios
    seeds = range(args.seeds)
    print(
        f"planning benchmark: {len(names)} feasible scenarios x {args.seeds} seeds x 2 modes, interleaved "
        f"per seed; {os.cpu_count()} CPUs, Python {platform.python_version()}"
    )
    print(f"clearance grid disk cache: {cache_dir() or 'disabled'}")
    t_bench = time.perf_counter()
    runs: list[dict[str, Any]] = []
    cold: list[dict[str, Any]] = []
    limits: dict[str, dict[str, float]] = {}
    clearance: dict[str, float] = {}
    cabins_seen: dict[str, str] = {}  # cabin mesh hash -> first scenario planned on it
    modes_of: dict[str, dict[str, ResolvedScenario]] = {}
    for name in names:
        base = load_scenario(SCENARIOS / f"{name}.yaml")
        own_limit = float(base.options.time_limit_s)
        limit = args.time_limit_s if args.time_limit_s is not None else own_limit
        base_limit = min(limit, args.baseline_cap_s) if args.baseline_cap_s > 0 else limit
        limits[name] = {"scenario": own_limit, "product": limit, "baseline": base_limit}
        clearance[name] = float(base.options.clearance_m)
        by_mode = {
            "product": with_options(base, time_limit_s=limit),
            "baseline": with_options(base, time_limit_s=base_limit),
        }

        # The first plan of this scenario in the process (product mode, seed 0): the cold figure.
        cabin_key = base.cabin.sha256 if base.cabin is not None else "none"
        first = run_once(with_options(by_mode["product"], seed=0), "product")
        first.update(
            scenario=name,
            cabin=base.cabin_source,
            first_in_process=not cold,
            cabin_loaded_by=cabins_seen.get(cabin_key),
        )
        cabins_seen.setdefault(cabin_key, name)
        cold.append(first)
        print(f"  {name}: first plan {first['time_s']:.2f} s ({first['reason'] or 'ok'})", file=sys.stderr)
        modes_of[name] = by_mode

    # Seed by seed over all scenarios (not scenario by scenario): this VM runs faster and slower by up to
    # 1.5x for tens of seconds at a time, and a slow spell should not land on one scenario's runs alone.
    for seed in seeds:
        for name in names:
            order = MODES if seed % 2 == 0 else MODES[::-1]
            for mode in order:
                r = run_once(with_options(modes_of[name][mode], seed=seed), mode)
                r["scenario"] = name
                runs.append(r)
                what = "ok" if r["ok"] else r["reason"]
                print(f"  {name} seed {seed} {mode:<8} {r['time_s']:7.2f} s  {what}", file=sys.stderr)

    summaries: dict[str, dict[str, dict[str, Any]]] = {}
    for mode in MODES:
        summaries[mode] = {}
        for name in names:
            s = stats([r for r in runs if r["mode"] == mode and r["scenario"] == name])
            s["clearance_req"] = f"{1e3 * clearance[name]:.1f}"
            summaries[mode][name] = s
        summaries[mode]["all"] = stats([r for r in runs if r["mode"] == mode])

    capped_from = sorted({f"{v['product']:g} s" for v in limits.values() if v["baseline"] < v["product"]})
    for mode in MODES:
        print()
        lim = sorted({f"{v[mode]:g} s" for v in limits.values()})
        title = "product planner" if mode == "product" else "naive baseline (raw RRTConnect, OMPL defaults)"
        extra = ""
        if mode == "baseline" and capped_from:
            extra = f" (capped by --baseline-cap-s from {', '.join(capped_from)})"
        print(f"{title}: time limit {', '.join(lim)}{extra}")
        mode_table(mode, names, summaries[mode])
    print(
        "t med / t p95: end to end (Planner(...) + plan()), warm, every run incl. failures; "
        "dur/LB: duration / single-drive lower bound;\ndur/staged LB: with an insertion, duration / (bound "
        "to the pre-insertion pose + bound along the line), the best any plan that stops there can do;\n"
        "min clr: min over successful runs of the gate's "
        "clearance / the requested one; gate pass: fraction of returned profiles that passed the gate"
    )

    print("\nfirst plan of each scenario in the process (product, seed 0), not in the warm figures above")
    rows = []
    for c in cold:
        if c["first_in_process"]:
            note = "cold: first plan in the process"
        elif c["cabin_loaded_by"] is None:
            note = f"cold cabin ({c['cabin']}), warm process"
        else:
            note = f"warm: {c['cabin']} already loaded by {c['cabin_loaded_by']}"
        warm = summaries["product"][c["scenario"]]
        rows.append(
            [
                c["scenario"],
                fmt(c["time_s"], ".3f"),
                fmt(warm["time_median_s"], ".3f"),
                c["reason"] or "ok",
                note,
            ]
        )
    table(["scenario", "first [s]", "warm med [s]", "outcome", "note"], rows)

    print("\nproduct / baseline")
    comparison_table(names, summaries)
    print(
        "t ratio: median planning time, every run; dur ratio: median duration, successful runs; "
        "< 1 means the product is faster / shorter"
    )
    insertion_bounds(names)
    print(f"\n{TARGETS}")
    wall = time.perf_counter() - t_bench
    print(f"benchmark wall time {wall:.0f} s")

    if args.json is not None:
        doc = {
            "seeds": args.seeds,
            "scenarios": names,
            "time_limits_s": limits,
            "baseline_cap_s": args.baseline_cap_s,
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "wall_time_s": wall,
            "cold": cold,
            "runs": runs,
            "summary": summaries,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1, default=str))
        print(f"raw measurements written to {args.json}")


if __name__ == "__main__":
    main()
    # OMPL's nanobind bindings report "leaked instances" at interpreter shutdown (objects still held by
    # OMPL's C++ side when the module is torn down). They are harmless but would bury the figures, so flush
    # and leave without running the interpreter's teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
