"""Sweep throughput: plans per minute with 1 and 2 workers, embedded and on Ray, and the per-plan overhead.

One sweep (default 32 plans: the 100 kg aisle transfer, feasible, and the same with 400 kg, refused at
the start, over 16 seeds) runs in every configuration, each run into a fresh output folder:

* in-process -- :func:`planner.sweep.task.plan_outcome` on every plan, serially, in this warm process:
  what planning itself costs, ``T_in`` per plan (scenario resolution, planning and the JSON text of the
  profile: the work every configuration does for a plan; the planner's own ``planning_time_s`` is
  printed beside it);
* embedded, 1 and 2 workers -- :class:`~planner.sweep.run.EmbeddedExecutor` with its default warm,
  reused worker processes;
* embedded, fresh process per plan (``--plans-per-process 1``), 1 and 2 workers, for comparison;
* Ray, 1 and 2 workers -- one local Ray with 2 CPUs (bound to loopback); 1 worker is one task in flight.

Honest accounting: the clock runs around :func:`~planner.sweep.run.run_sweep` only, so it includes
everything a sweep does per plan (handing the task over, the plan, writing the profile file, the fsynced
journal row, progress) and excludes one-time start-up (forkserver warm-up, Ray start and worker warm-up),
which is printed separately. The machine's own 2-process capacity is measured in every round too: two
processes forked from the warm bench process plan the same plans in parallel with no sweep machinery (on a
machine whose scheduler shares CPU between login sessions, as this one does with
``kernel.sched_autogroup_enabled=1``, that is the ceiling of any 2-worker speed-up). Per-plan overhead =
``workers * wall / n - T_in``: the time a plan costs a worker beyond planning it in-process. The machine is
shared, so the configurations run in ``--rounds`` interleaved rounds (each with its own ``T_in``), and the
figures are medians over the rounds; the load average is printed before and after. Targets: overhead <= 50
ms embedded, <= 100 ms on Ray; 2 workers >= 1.7x the throughput of 1.

"driver CPU ms" is the CPU time of the sweep's own process per plan (handing tasks over, receiving
outcomes, the journal); "CPU overhead ms" is the CPU time every process of the run spent per plan
(driver, forkserver, workers, Ray's daemons; read from ``/proc``) minus the in-process CPU time per plan
of the same round. Both hardly move with the machine's load, unlike the wall-clock figures: with free
cores, ``workers`` workers plan ``workers * 60 / (T_cpu_in + CPU overhead)`` plans a minute as long as the
driver (one core) keeps up.

Run: ``python -m bench.sweep [--seeds N] [--rounds R] [--no-ray] [--no-fresh]`` (or ``make bench``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from statistics import mean, median
from typing import Any

from planner.sweep.expand import SweepPlan, expand_sweep
from planner.sweep.run import EmbeddedExecutor, RayExecutor, init_local_ray, run_sweep, warm_task
from planner.sweep.spec import Limits, sweep_from_dict
from planner.sweep.task import plan_outcome

SCENARIOS = Path(__file__).resolve().parents[1] / "tests" / "scenarios"

#: Per-plan overhead targets [s] and the 2-worker speed-up target.
EMBEDDED_OVERHEAD_S = 0.050
RAY_OVERHEAD_S = 0.100
SPEEDUP_2 = 1.7


def _sweep(seeds: int) -> tuple[Any, list[SweepPlan]]:
    spec = sweep_from_dict(
        {
            "name": "bench",
            "base": str(SCENARIOS / "aisle-transfer.yaml"),
            "axes": {"payload_mass_kg": [100, 400], "seed": list(range(1, seeds + 1))},
        }
    )
    return spec, expand_sweep(spec)


def _in_process(plans: list[SweepPlan]) -> tuple[float, float]:
    """Serial in-process planning of every plan: (mean T_in [s], mean planning_time_s of the feasible)."""
    times, planning = [], []
    for plan in plans:
        task = {"scenario": plan.scenario.model_dump(mode="json"), "base_dir": None}
        t0 = time.perf_counter()
        out = plan_outcome(task)
        times.append(time.perf_counter() - t0)
        if out["planning_time_s"] is not None:
            planning.append(out["planning_time_s"])
    return mean(times), mean(planning) if planning else 0.0


def _plan_all(scenarios: list[dict[str, Any]]) -> None:
    for scenario in scenarios:
        plan_outcome({"scenario": scenario, "base_dir": None})


def _in_process_parallel(pool: Any, plans: list[SweepPlan], workers: int) -> float:
    """Wall time [s] of ``workers`` warm processes (forked from this one) planning the plans, no sweep."""
    scenarios = [p.scenario.model_dump(mode="json") for p in plans]
    chunks = [scenarios[k::workers] for k in range(workers)]
    t0 = time.perf_counter()
    pool.map(_plan_all, chunks, chunksize=1)
    return time.perf_counter() - t0


def tree_cpu_s() -> float:
    """CPU time [s] of this process and every process below it, the reaped ones included.

    Sums user + system time and the children's (``cutime``/``cstime``, the processes already reaped by
    it) over the live processes of the tree (``/proc``): forkserver, plan workers, pool workers, Ray's
    GCS, raylet, agents and workers. Each CPU second is counted once.
    """
    children: dict[int, list[int]] = {}
    stats: dict[int, list[str]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            stats[int(entry.name)] = fields
            children.setdefault(int(fields[1]), []).append(int(entry.name))
    ticks, todo, total = os.sysconf("SC_CLK_TCK"), [os.getpid()], 0
    while todo:
        pid = todo.pop()
        found = stats.get(pid)
        if found is not None:
            total += sum(int(x) for x in found[11:15])  # utime, stime, cutime, cstime
        todo.extend(children.get(pid, []))
    return total / ticks


def _timed(plans: list[SweepPlan], limits: Limits, executor: Any, out: Path) -> tuple[float, float, float]:
    """(wall time, CPU time of this driver process, CPU time of the process tree) of one sweep run [s]."""
    shutil.rmtree(out, ignore_errors=True)
    t0, c0, k0 = time.perf_counter(), time.process_time(), tree_cpu_s()
    counts = run_sweep(plans, out, executor, limits)
    wall, cpu, tree = time.perf_counter() - t0, time.process_time() - c0, tree_cpu_s() - k0
    assert counts.done == len(plans) and counts.retried == 0, counts
    return wall, cpu, tree


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seeds", type=int, default=16, help="seeds per payload mass (plans = 2 x seeds)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians are reported)")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray runs")
    ap.add_argument("--no-fresh", action="store_true", help="skip the fresh-process-per-plan runs")
    args = ap.parse_args()

    spec, plans = _sweep(args.seeds)
    n = len(plans)
    root = Path(tempfile.mkdtemp(prefix="cabinplan-bench-sweep-"))
    print(
        f"sweep: {n} plans (aisle transfer 100 kg feasible / 400 kg refused x {args.seeds} seeds), "
        f"{os.cpu_count()} CPUs, {args.rounds} rounds; load average {_load()} (1, 5, 15 min)"
    )
    plan_outcome({"scenario": plans[0].scenario.model_dump(mode="json"), "base_dir": None})  # warm
    warm = warm_task(plans)
    # The machine's own 2-process capacity: two processes forked from this warm one (before any thread
    # or Ray exists) plan the plans in parallel, without any sweep machinery.
    pool = multiprocessing.get_context("fork").Pool(2)

    # Executors are started once (start-up printed, not charged to the plans) and reused by every round.
    executors: dict[str, tuple[int, Any, Callable[[], None]]] = {}
    configs: list[tuple[str, int, int]] = [("embedded", 1, 0), ("embedded", 2, 0)]
    if not args.no_fresh:
        configs += [("embedded fresh", 1, 1), ("embedded fresh", 2, 1)]
    startup: dict[str, float] = {}
    for kind, workers, ppp in configs:
        label = f"{kind}, {workers} worker{'s' if workers > 1 else ''}"
        t0 = time.perf_counter()
        ex = EmbeddedExecutor(workers, warm, plans_per_process=ppp)
        startup[label] = time.perf_counter() - t0
        executors[label] = (workers, ex, ex.close)
    ray_mod = None
    if not args.no_ray:
        t0 = time.perf_counter()
        ray_mod = init_local_ray(2)
        ray_two = RayExecutor(None, 2, 2, {}, warm)
        ray_one = RayExecutor(None, 2, 1, {}, None)  # same Ray and warm workers, one task in flight
        startup["ray (start + warm 2 workers)"] = time.perf_counter() - t0
        executors["ray, 1 worker"] = (1, ray_one, lambda: None)
        executors["ray, 2 workers"] = (2, ray_two, lambda: None)
    print("start-up (not charged): " + ", ".join(f"{k} {v:.1f} s" for k, v in startup.items()))

    walls: dict[str, list[float]] = {label: [] for label in executors}
    driver_cpu: dict[str, list[float]] = {label: [] for label in executors}
    tree_cpu: dict[str, list[float]] = {label: [] for label in executors}
    cpu_ins: list[float] = []
    t_ins: list[float] = []
    par_walls: list[float] = []
    planning: list[float] = []
    try:
        for r in range(args.rounds):
            k0 = tree_cpu_s()
            t_in, t_plan = _in_process(plans)
            cpu_ins.append((tree_cpu_s() - k0) / len(plans))
            t_ins.append(t_in)
            planning.append(t_plan)
            par_walls.append(_in_process_parallel(pool, plans, 2))
            for label, (_, ex, _) in executors.items():
                out = root / f"{label.replace(' ', '_').replace(',', '')}-{r}"
                wall, cpu, tree = _timed(plans, spec.limits, ex, out)
                walls[label].append(wall)
                driver_cpu[label].append(cpu)
                tree_cpu[label].append(tree)
                shutil.rmtree(out, ignore_errors=True)
    finally:
        pool.terminate()
        for _, _, close in executors.values():
            close()
        if ray_mod is not None and ray_mod.is_initialized():
            ray_mod.shutdown()
        shutil.rmtree(root, ignore_errors=True)

    t_in = median(t_ins)
    print(
        f"in-process T_in: median over rounds {1e3 * t_in:.1f} ms per plan (rounds: "
        + ", ".join(f"{1e3 * t:.0f}" for t in t_ins)
        + f"); planner's own planning_time_s of the feasible plans {1e3 * median(planning):.0f} ms"
    )
    machine = [n * t / w for t, w in zip(t_ins, par_walls, strict=True)]
    print(f"in-process CPU per plan: median {1e3 * median(cpu_ins):.1f} ms")
    print(
        f"in-process, 2 processes (no sweep): {median(par_walls):.2f} s, the machine's 2-process speed-up "
        f"{median(machine):.2f} (rounds: " + ", ".join(f"{m:.2f}" for m in machine) + "); 1.00 means the"
        " other users' load leaves this session one core's worth of CPU whatever it runs"
    )
    print(
        f"{'configuration':<28} {'wall s':>7} {'plans/min':>10} {'overhead ms':>12} "
        f"{'per round (ms)':>22} {'x vs 1':>7} {'driver CPU ms':>14} {'CPU overhead ms':>16}"
    )
    extra: list[str] = []
    for label, (workers, _, _) in executors.items():
        w = median(walls[label])
        # Overhead of each round against that round's own in-process time, then the median.
        per_round = [workers * wall / n - t for wall, t in zip(walls[label], t_ins, strict=True)]
        overhead = median(per_round)
        ratio = "1.00"
        if workers == 2:
            one = label.replace("2 workers", "1 worker")
            paired = [a / b for a, b in zip(walls[one], walls[label], strict=True)]
            ratio = f"{median(paired):.2f}"
            # Against the machine's own 2-process planning in the same round: the sweep's share of it.
            same = [2 * (wall - par) / n for wall, par in zip(walls[label], par_walls, strict=True)]
            extra.append(
                f"{label}: overhead against 2 in-process planners {1e3 * median(same):.0f} ms per plan, "
                f"speed-up {median(paired):.2f} = "
                f"{median(a / m for a, m in zip(paired, machine, strict=True)):.2f} of the machine's"
            )
        rounds = " ".join(f"{1e3 * o:.0f}" for o in per_round)
        cpu = 1e3 * median(driver_cpu[label]) / n
        # CPU seconds all processes spent per plan, against the same round's in-process CPU per plan.
        cpu_over = 1e3 * median(t / n - c for t, c in zip(tree_cpu[label], cpu_ins, strict=True))
        head = f"{label:<28} {w:7.2f} {60 * n / w:10.1f} {1e3 * overhead:12.1f}"
        print(f"{head} {rounds:>22} {ratio:>7} {cpu:14.1f} {cpu_over:16.1f}")
    for line in extra:
        print(line)
    print(f"load average after: {_load()}")
    print(
        f"targets: overhead <= {1e3 * EMBEDDED_OVERHEAD_S:.0f} ms embedded, <= {1e3 * RAY_OVERHEAD_S:.0f} ms "
        f"Ray; 2 workers >= {SPEEDUP_2}x the plans/min of 1 (x vs 1: median of the rounds' paired ratios)"
    )


if __name__ == "__main__":
    main()
