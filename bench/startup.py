"""Start-up cost of a ``cabinplan plan`` call: wall time outside the plan's own ``planning_time_s``.

Each run is a fresh process (``python -m planner.cli plan SCENARIO -o OUT``), as a user's shell call is,
on a warmed machine (kernels compiled and cached, one unmeasured run first). Printed per scenario: the
median and the worst of ``wall - planning_time_s`` over the runs [target: <= 1.5 s], and the import time of
the modules a plan needs (``python -X importtime``), largest first.

Run: ``python -m bench.startup [--runs 5]``.
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


def _one(scenario: str, out: Path) -> tuple[float, float, float]:
    """(wall time [s], the report's planning_time_s, CPU time [s]) of one CLI call in a new process."""
    path = ROOT / "tests" / "scenarios" / f"{scenario}.yaml"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "planner.cli", "plan", str(path), "-o", str(out)],
        check=True,
        capture_output=True,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, float(json.loads(out.read_text())["report"]["planning_time_s"]), cpu


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


def main() -> None:
    """Print the figures."""
    ap = argparse.ArgumentParser(prog="python -m bench.startup", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
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
    print("\nimport time of a plan's modules (cumulative, s):")
    for seconds, name in _imports():
        print(f"  {seconds:6.2f}  {name}")


if __name__ == "__main__":
    main()
