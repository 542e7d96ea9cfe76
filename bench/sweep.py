"""Sweep throughput: plans per minute with 1 and 2 workers, embedded and on Ray, and the per-plan overhead.

One sweep (default 16 plans: the 100 kg aisle transfer, feasible, and the same with 400 kg, refused at
the start, over 8 seeds) runs in these configurations, each into a fresh output folder:

* in-process baseline -- :func:`planner.sweep.task.plan_outcome` on every plan, serially, in this (warm)
  process: the time planning itself costs, ``T_in`` per plan (resolution included);
* embedded, 1 and 2 workers -- :class:`~planner.sweep.run.EmbeddedExecutor`, a fresh process per plan
  (the default), and with ``--plans-per-process`` processes reused (``ppp``);
* Ray, 1 and 2 workers -- a local Ray with that many CPUs (:class:`~planner.sweep.run.RayExecutor`).

Start-up (forkserver warm-up, Ray start and worker warm-up) is excluded: the clock runs around
:func:`~planner.sweep.run.run_sweep` only. Per-plan overhead = ``workers * wall / n - T_in``: the wall
time a plan costs a worker beyond its in-process planning. Targets: overhead <= 50 ms embedded, <= 100 ms
on Ray; 2 workers >= 1.7x the throughput of 1.

Run: ``python -m bench.sweep [--seeds N] [--no-ray] [--plans-per-process K]`` (or ``make bench``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path
from statistics import mean

from planner.sweep.expand import expand_sweep
from planner.sweep.run import EmbeddedExecutor, RayExecutor, run_sweep, warm_task
from planner.sweep.spec import sweep_from_dict
from planner.sweep.task import plan_outcome

SCENARIOS = Path(__file__).resolve().parents[1] / "tests" / "scenarios"


def _sweep(seeds: int):
    spec = sweep_from_dict(
        {
            "name": "bench",
            "base": str(SCENARIOS / "aisle-transfer.yaml"),
            "axes": {"payload_mass_kg": [100, 400], "seed": list(range(1, seeds + 1))},
        }
    )
    return spec, expand_sweep(spec)


def _timed(plans, limits, executor, root: Path, label: str) -> float:
    out = root / label
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    counts = run_sweep(plans, out, executor, limits)
    wall = time.perf_counter() - t0
    assert counts.done == len(plans), counts
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8, help="seeds per payload mass (plans = 2 x seeds)")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray runs")
    ap.add_argument("--plans-per-process", type=int, default=8, help="also run embedded with reuse")
    args = ap.parse_args()

    spec, plans = _sweep(args.seeds)
    n = len(plans)
    tasks = [{"scenario": p.scenario.model_dump(mode="json"), "base_dir": None} for p in plans]
    plan_outcome(tasks[0])  # warm this process
    t_in = []
    for task in tasks:
        t0 = time.perf_counter()
        plan_outcome(task)
        t_in.append(time.perf_counter() - t0)
    base = mean(t_in)
    print(
        f"sweep: {n} plans (aisle transfer 100 kg feasible / 400 kg refused x {args.seeds} seeds), "
        f"{os.cpu_count()} CPUs"
    )
    feasible = [t for t, p in zip(t_in, plans, strict=True) if p.scenario.payload.mass < 400]
    refused = [t for t, p in zip(t_in, plans, strict=True) if p.scenario.payload.mass >= 400]
    print(
        f"in-process planning T_in: mean {1e3 * base:.1f} ms per plan "
        f"(feasible {1e3 * mean(feasible):.0f} ms, refused {1e3 * mean(refused):.0f} ms)"
    )
    print(f"{'configuration':<34} {'wall s':>8} {'plans/min':>10} {'overhead ms':>12} {'x vs 1':>7}")
    root = Path(tempfile.mkdtemp(prefix="cabinplan-bench-sweep-"))
    results: dict[str, tuple[int, float]] = {}

    def report(label: str, workers: int, wall: float, one: str | None) -> None:
        results[label] = (workers, wall)
        overhead = workers * wall / n - base
        ratio = f"{results[one][1] / wall:.2f}" if one in results and one != label else "1.00"
        print(f"{label:<34} {wall:8.2f} {60 * n / wall:10.1f} {1e3 * overhead:12.1f} {ratio:>7}")

    warm = warm_task(plans)
    configs: list[tuple[str, int, int]] = [("embedded, 1 worker", 1, 1), ("embedded, 2 workers", 2, 1)]
    if args.plans_per_process > 1:
        k = args.plans_per_process
        configs += [(f"embedded ppp={k}, 1 worker", 1, k), (f"embedded ppp={k}, 2 workers", 2, k)]
    for label, workers, ppp in configs:
        executor = EmbeddedExecutor(workers, warm, plans_per_process=ppp)
        try:
            wall = _timed(plans, spec.limits, executor, root, label.replace(" ", "_").replace(",", ""))
        finally:
            executor.close()
        report(label, workers, wall, label.replace("2 workers", "1 worker"))
    if not args.no_ray:
        import ray

        for workers in (1, 2):
            label = f"ray, {workers} worker{'s' if workers > 1 else ''}"
            executor = RayExecutor(None, workers, None, {}, warm)
            try:
                wall = _timed(plans, spec.limits, executor, root, f"ray{workers}")
            finally:
                executor.close()
                if ray.is_initialized():
                    ray.shutdown()
            report(label, workers, wall, "ray, 1 worker")
    shutil.rmtree(root, ignore_errors=True)
    print("targets: overhead <= 50 ms embedded, <= 100 ms Ray; 2 workers >= 1.7x the plans/min of 1")


if __name__ == "__main__":
    main()
