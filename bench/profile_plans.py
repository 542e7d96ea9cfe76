"""Where plans spend their time: ``report.stages_s`` and a cProfile of each scenario file given.

Each scenario is planned once unmeasured (imports, kernels, the cabin's clearance grid: start-up, not
planning), then once under :mod:`cProfile`. Printed per scenario: ``planning_time_s``, the stages' times,
and the functions with the largest cumulative time (calls, cumulative s, own s); then, over all the
scenarios, the same table summed.

Run: ``python -m bench.profile_plans DIR/gen-*.yaml [--top 30] [--match planner]``.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
from pathlib import Path
from typing import Any


def _plan(path: Path) -> dict[str, Any]:
    """The plan's report, or the refusal's reason and the run time (a refusal is profiled too)."""
    from planner.core.exceptions import PlannerError
    from planner.plan.pipeline import plan_scenario
    from planner.scenario import load_scenario

    sc = load_scenario(path)
    t0 = time.perf_counter()
    try:
        return dict(plan_scenario(sc).report)
    except PlannerError as exc:
        return {"refused": exc.reason, "planning_time_s": time.perf_counter() - t0}


def _rows(stats: pstats.Stats, match: str, top: int) -> list[tuple[float, float, int, str]]:
    raw: dict[Any, Any] = stats.stats  # type: ignore[attr-defined]
    rows = []
    for (file, line, fn), (_, ncalls, tottime, cumtime, _) in raw.items():
        if match in file or match in fn:
            where = file.split("site-packages/")[-1].split("/gen/")[-1]
            rows.append((cumtime, tottime, ncalls, f"{where}:{line}({fn})"))
    return sorted(rows, reverse=True)[:top]


def _print(rows: list[tuple[float, float, int, str]]) -> None:
    print(f"    {'cum s':>7} {'own s':>7} {'calls':>9}  function")
    for cum, own, calls, name in rows:
        print(f"    {cum:>7.3f} {own:>7.3f} {calls:>9}  {name}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.profile_plans", description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+", type=Path)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--match", default="planner", help="only functions whose file or name contains this")
    args = ap.parse_args(argv)
    total: pstats.Stats | None = None
    print(f"load average {os.getloadavg()[0]:.1f}")
    for path in args.scenarios:
        _plan(path)  # unmeasured: start-up and the cabin's grid
        prof = cProfile.Profile()
        prof.enable()
        report = _plan(path)
        prof.disable()
        stats = pstats.Stats(prof)
        total = stats if total is None else (total.add(prof) or total)
        stages = ", ".join(f"{k} {v:.3f}" for k, v in report.get("stages_s", {}).items())
        what = f"refused {report['refused']} after" if "refused" in report else "planning_time_s"
        print(f"\n{path.name}: {what} {report['planning_time_s']:.3f} s (under cProfile); {stages}")
        _print(_rows(stats, args.match, args.top))
    if total is not None and len(args.scenarios) > 1:
        print(f"\nall {len(args.scenarios)} scenarios:")
        _print(_rows(total, args.match, args.top))


if __name__ == "__main__":
    main()
