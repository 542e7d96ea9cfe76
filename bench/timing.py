"""Jerk-limited timing benchmark: its cost in duration and run time against TOPP-RA (issue 14 targets).

For every feasible reference scenario (``status: succeeded`` in ``tests/scenarios/expected.yaml``) and
seeds 0..N-1, the scenario is planned twice in the same process, interleaved: ``options.timing:
acceleration_limited`` (TOPP-RA alone) and ``jerk_limited`` (the default). Measured:

* duration ratio: the jerk-limited law's duration / TOPP-RA's on the *same* legs (the jerk plan's
  certified legs timed by both stages here, default limit fractions)     [median <= 1.05, max <= 1.15];
  also the two plans' own profile durations (each planned with its option, sampled, after the gate)
* the stage's run time per plan (all legs), jerk-limited and TOPP-RA, wall clock  [median <= 50 ms],
  and the process CPU time (less sensitive to the other work on a shared machine)
* whole plan time (``planning_time_s``), jerk-limited / acceleration-limited plan, median
                                                                                  [grows by <= 20%]

Both modes plan the same certified legs (smoothing does not depend on the timing option): the corner
blends are C2 (quintic) in both. State the machine's load average with the figures.

Each scenario is planned once before its seeds (warm-up: the cabin's collision geometry is cached per
process). A plan that is refused is reported and left out of the figures.

Run: ``python -m bench.timing [--seeds N] [--scenarios a b]`` (or ``make bench``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from planner.core.exceptions import PlannerError
from planner.plan.pipeline import Planner
from planner.scenario.resolve import ResolvedScenario, load_scenario
from planner.timing.jerk import JerkLimitedStage
from planner.timing.path import JointPath
from planner.timing.stage import TimingStage
from planner.timing.toppra import ToppraStage

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "tests" / "scenarios"


def feasible() -> list[str]:
    """Names of the suite scenarios that must plan."""
    expected = yaml.safe_load((SCENARIOS / "expected.yaml").read_text(encoding="utf-8"))
    return [name for name, e in expected.items() if e["status"] == "succeeded"]


def with_timing(sc: ResolvedScenario, timing: str, seed: int) -> ResolvedScenario:
    """The scenario with ``options.timing`` and ``options.seed`` set."""
    return dataclasses.replace(sc, options=sc.options.model_copy(update={"timing": timing, "seed": seed}))


def _recorder(sc: ResolvedScenario, legs: list[JointPath]) -> Any:
    """The scenario's jerk-limited factory, recording the legs of the last timing."""
    period = float(sc.options.sample_period_s)

    class Recording:
        def __init__(self, robot: Any, payload: Any, safety: tuple[float, float, float]) -> None:
            self.inner = JerkLimitedStage(robot, payload, safety, sample_period_s=period)
            self.name = self.inner.name
            legs.clear()

        def time_path(self, path: JointPath) -> Any:
            legs.append(path)
            return self.inner.time_path(path)

    return Recording


def _time_legs(stage: TimingStage, legs: list[JointPath]) -> tuple[float, float, float]:
    """(total duration [s], wall run time [s], CPU run time [s]) of timing every leg with ``stage``."""
    t0, c0 = time.perf_counter(), time.process_time()
    duration = sum(stage.time_path(leg).duration for leg in legs)
    return duration, time.perf_counter() - t0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--scenarios", nargs="*", default=None)
    args = ap.parse_args()
    names = args.scenarios or feasible()
    rows: list[dict[str, Any]] = []
    for name in names:
        base = load_scenario(SCENARIOS / f"{name}.yaml")
        try:  # warm-up: the cabin's collision geometry is cached per process
            Planner(with_timing(base, "jerk_limited", 0)).plan()
        except PlannerError:
            pass
        for seed in range(args.seeds):
            legs: list[JointPath] = []
            sc_j = with_timing(base, "jerk_limited", seed)
            sc_a = with_timing(base, "acceleration_limited", seed)
            order = [("jerk", sc_j), ("acc", sc_a)] if seed % 2 == 0 else [("acc", sc_a), ("jerk", sc_j)]
            plan_s: dict[str, float] = {}
            profile_s: dict[str, float] = {}
            try:
                for mode, sc in order:
                    timing = _recorder(sc, legs) if mode == "jerk" else None
                    result = Planner(sc, timing=timing).plan()
                    plan_s[mode] = float(result.report["planning_time_s"])
                    profile_s[mode] = result.profile.duration_s
            except PlannerError as exc:
                print(f"{name:22s} seed {seed}: refused ({exc.reason}: {exc.message[:120]})", flush=True)
                continue
            robot, payload = base.robot, (base.payload.rigid_payload() if base.payload else None)
            period = float(base.options.sample_period_s)
            d_j, run_j, cpu_j = _time_legs(JerkLimitedStage(robot, payload, sample_period_s=period), legs)
            d_a, run_a, cpu_a = _time_legs(ToppraStage(robot, payload), legs)
            rows.append(
                {
                    "scenario": name,
                    "seed": seed,
                    "legs": len(legs),
                    "ratio": d_j / d_a,
                    "jerk_ms": 1e3 * run_j,
                    "toppra_ms": 1e3 * run_a,
                    "jerk_cpu_ms": 1e3 * cpu_j,
                    "toppra_cpu_ms": 1e3 * cpu_a,
                    "profile_ratio": profile_s["jerk"] / profile_s["acc"],
                    "plan_growth": plan_s["jerk"] / plan_s["acc"],
                    "plan_jerk_s": plan_s["jerk"],
                    "plan_acc_s": plan_s["acc"],
                }
            )
            r = rows[-1]
            print(
                f"{name:22s} seed {seed}: legs {r['legs']}, duration ratio {r['ratio']:.3f} (plans "
                f"{r['profile_ratio']:.3f}), stage {r['jerk_ms']:.1f} ms, CPU {r['jerk_cpu_ms']:.1f} ms "
                f"(TOPP-RA {r['toppra_ms']:.1f} ms, CPU {r['toppra_cpu_ms']:.1f} ms), "
                f"plan {r['plan_jerk_s']:.3f} s vs {r['plan_acc_s']:.3f} s (x{r['plan_growth']:.3f})",
                flush=True,
            )
    ratio = np.array([r["ratio"] for r in rows])
    plans = np.array([r["profile_ratio"] for r in rows])
    run = np.array([r["jerk_ms"] for r in rows])
    topp = np.array([r["toppra_ms"] for r in rows])
    cpu = np.array([r["jerk_cpu_ms"] for r in rows])
    topp_cpu = np.array([r["toppra_cpu_ms"] for r in rows])
    growth = np.array([r["plan_growth"] for r in rows])
    print(
        f"\nduration ratio jerk / acceleration-limited: median {np.median(ratio):.3f} [<= 1.05], "
        f"max {ratio.max():.3f} [<= 1.15]; the plans' own profiles: median {np.median(plans):.3f}, max "
        f"{plans.max():.3f}"
    )
    print(
        f"jerk-limited stage run time per plan: median {np.median(run):.1f} ms [<= 50 ms], max "
        f"{run.max():.1f} ms (TOPP-RA alone: median {np.median(topp):.1f} ms); CPU time median "
        f"{np.median(cpu):.1f} ms (TOPP-RA {np.median(topp_cpu):.1f} ms)"
    )
    print(
        f"whole plan time, jerk / acceleration-limited: median x{np.median(growth):.3f} [<= 1.20], "
        f"max x{growth.max():.3f}"
    )
    print(f"load average at the end: {os.getloadavg()[0]:.2f} (1 min), {os.getloadavg()[1]:.2f} (5 min)")


if __name__ == "__main__":
    main()
