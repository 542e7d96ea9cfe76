"""Start-up cost of a ``cabinplan plan`` call: wall time outside the plan's own ``planning_time_s``.

Each run is a fresh process (``python -m planner.cli plan SCENARIO -o OUT``), as a user's shell call is,
on a warmed machine (kernels compiled and cached, one unmeasured run first). Printed per scenario: the
median and the worst of ``wall - planning_time_s`` over the runs [target: <= 1.5 s], and the import time of
the modules a plan needs (``python -X importtime``), largest first.

Then on generated cabins nobody planned in before (``--generated N`` cases of the new families of
:mod:`planner.generate.families`, seed ``--generated-seed``, by default one drawn from the clock and
printed): the **first call** on each cabin, which builds its clearance grid (the cache folder gains a
``grid-*`` entry during the call; a call that finds the grid cached is reported apart), and the **later
calls** (``--runs`` - 1 each), reported apart [issue 26 targets: <= 2 s first, <= 0.8 s later].

Run: ``python -m bench.startup [--runs 5] [--generated 6] [--generated-seed S]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("aisle-transfer", "aisle-bay-insert", "hatch-pass")
TARGET_S = 1.5


def _one(scenario: str | Path, out: Path) -> tuple[float, float, float]:
    """(wall time [s], the report's planning_time_s, CPU time [s]) of one CLI call in a new process.

    ``scenario``: a suite scenario's name or a scenario file's path.
    """
    path = scenario if isinstance(scenario, Path) else ROOT / "tests" / "scenarios" / f"{scenario}.yaml"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "planner.cli", "plan", str(path), "-o", str(out)],
        capture_output=True,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    if done.returncode != 0:  # a refusal (its document has no planning time) or an error
        lines = done.stderr.decode(errors="replace").strip().splitlines()
        raise Refused(lines[-1] if lines else f"exit status {done.returncode}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, float(json.loads(out.read_text())["report"]["planning_time_s"]), cpu


class Refused(Exception):
    """The CLI refused the plan (or failed): the call has no planning time to subtract."""


def _imports() -> list[tuple[float, str]]:
    """Cumulative import time [s] of the top-level modules a plan imports, largest first."""
    code = "import planner.plan.pipeline, planner.scenario, planner.documents.output"
    res = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True, cwd=ROOT, check=True
    )
    out = []
    for line in res.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            name = parts[2].rstrip()
            if name.startswith(" ") and not name.startswith("   "):  # direct imports of the command
                out.append((int(parts[1]) / 1e6, name.strip()))
            elif not name.startswith(" "):
                out.append((int(parts[1]) / 1e6, name.strip()))
    return sorted(out, reverse=True)[:12]


def _grids() -> set[str]:
    """The clearance grids in the cache folder (names)."""
    from planner.core.cache import cache_dir

    root = cache_dir()
    return {p.name for p in root.rglob("grid-*")} if root is not None and root.is_dir() else set()


def _generated(count: int, seed: int, runs: int, folder: Path) -> None:
    """First and later calls on ``count`` generated cabins (one family after another)."""
    from planner.generate import NEW_FAMILIES, GeneratorOptions, generate_case, write_case

    out = folder / "out.json"
    first: list[float] = []
    first_cached: list[float] = []
    later: list[float] = []
    plan_first: list[float] = []
    plan_later: list[float] = []
    print(
        f"\ngenerated cabins (seed {seed}): wall time outside planning_time_s [first <= 2 s, later <= 0.8 s]"
    )
    print(f"{'scenario':<28} {'first s':>8} {'grid built':>10} {'later median s':>15} {'later max s':>12}")
    for index in range(count):
        family = NEW_FAMILIES[index % len(NEW_FAMILIES)]
        case = generate_case(seed, index, GeneratorOptions(family=family))
        path = write_case(case, folder)
        grids = _grids()
        try:
            wall, plan_s, _ = _one(path, out)
        except Refused as exc:  # a generated case the planner refuses: said, not measured
            print(f"{case.name:<28} refused, not measured: {exc}")
            continue
        built = bool(_grids() - grids)
        (first if built else first_cached).append(wall - plan_s)
        plan_first.append(plan_s)
        rest = [_one(path, out) for _ in range(max(runs - 1, 1))]
        outside = [w - p for w, p, _ in rest]
        later += outside
        plan_later += [p for _, p, _ in rest]
        print(
            f"{case.name:<28} {wall - plan_s:>8.2f} {'yes' if built else 'no':>10} "
            f"{statistics.median(outside):>15.2f} {max(outside):>12.2f}"
        )
    if first:
        print(
            f"first call, grid built ({len(first)}): median {statistics.median(first):.2f} s, "
            f"max {max(first):.2f} s"
        )
    if first_cached:
        print(
            f"first call, grid found cached ({len(first_cached)}): "
            f"median {statistics.median(first_cached):.2f} s"
        )
    print(f"later calls ({len(later)}): median {statistics.median(later):.2f} s, max {max(later):.2f} s")
    print(
        f"planning_time_s itself: first calls median {statistics.median(plan_first):.2f} s, "
        f"later calls median {statistics.median(plan_later):.2f} s (load average {os.getloadavg()[0]:.1f})"
    )


def main() -> None:
    """Print the figures."""
    ap = argparse.ArgumentParser(prog="python -m bench.startup", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--generated", type=int, default=6, help="generated cabins (0: none)")
    ap.add_argument("--generated-seed", type=int, default=None, help="default: drawn from the clock")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        _one(SCENARIOS[0], out)  # warm: kernels and native builds cached
        print(
            f"cabinplan plan: wall time outside planning_time_s over {args.runs} fresh processes "
            f"[<= {TARGET_S} s]"
        )
        print(f"(load average {os.getloadavg()[0]:.1f}; CPU s = the process's user + system time, all of it)")
        print(f"{'scenario':<20} {'median s':>9} {'max s':>7} {'plan s (median)':>16} {'CPU s (median)':>15}")
        for name in SCENARIOS:
            runs = [_one(name, out) for _ in range(args.runs)]
            outside = [w - p for w, p, _ in runs]
            plan_s = statistics.median(p for _, p, _ in runs)
            cpu_s = statistics.median(c for _, _, c in runs)
            print(
                f"{name:<20} {statistics.median(outside):>9.2f} {max(outside):>7.2f} {plan_s:>16.2f} "
                f"{cpu_s:>15.2f}"
            )
        if args.generated > 0:
            seed = args.generated_seed if args.generated_seed is not None else int(time.time()) % 1_000_000
            _generated(args.generated, seed, args.runs, Path(tmp))
    print("\nimport time of a plan's modules (cumulative, s):")
    for seconds, name in _imports():
        print(f"  {seconds:6.2f}  {name}")


if __name__ == "__main__":
    main()
