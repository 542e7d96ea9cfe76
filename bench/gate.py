"""The validation gate's time on the suite's plans (issue 26: <= 50 ms for a 20 s profile at 4 ms).

Every feasible reference scenario is planned once; then the gate
(:func:`planner.gate.checks.validate_profile`) runs ``--runs`` times on its profile in the same
process, and the median is printed with its parts: the rigid robot's batched pass
(:meth:`CollisionWorld.along`: certificate and the clearance figure), the sagging robot's batched pass
(its deflection predicted, then certified), and everything else (drive checks, forces, goal, path).
``hatch-bay-insert`` is the 20 s case: 5291 samples at 4 ms. The machine's load is printed first and
last: the gate shares two cores with whatever else runs.

Run: ``python -m bench.gate [--runs 5] [--scenarios a b]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import yaml

from planner.gate.checks import deflected_joints, sagging_certificate, validate_profile
from planner.gate.requirements import requirements_for
from planner.plan.pipeline import Planner
from planner.scenario.resolve import load_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "tests" / "scenarios"


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} on {os.cpu_count()} cores"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--scenarios", nargs="*", default=None)
    args = ap.parse_args()
    expected = yaml.safe_load((SCENARIOS / "expected.yaml").read_text())
    names = args.scenarios or sorted(k for k, v in expected.items() if v["status"] == "succeeded")
    print(_load())  # noqa: T201
    header = (
        f"{'scenario':24s} {'samples':>7s} {'gate ms':>8s} {'along ms':>9s} {'sag ms':>7s} {'rest ms':>8s}"
    )
    print(header + "  min clearance (exact / bound / tolerance)")  # noqa: T201
    for name in names:
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        planner = Planner(sc)
        res = planner.plan()
        req = requirements_for(sc, planner.payload)
        world, prof = planner.world, res.profile
        q = sc.robot.joints_from_drives(prof.position)
        gate, along, sag = [], [], []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            report = validate_profile(prof, sc.robot, world, req, planner.dynamics)
            t1 = time.perf_counter()
            path = world.along(q)
            path.certify(req.clearance_m, world.self_clearance, req.motion_margin_m)
            path.clearance()
            t2 = time.perf_counter()
            if req.deflection_check and sc.robot.desc.stiffness is not None:
                q_def, _ = deflected_joints(sc.robot, q, req.payload, req.T_tool_payload)
                sagging_certificate(world, q_def, req.clearance_m, req.motion_margin_m, path)
            t3 = time.perf_counter()
            gate.append(t1 - t0)
            along.append(t2 - t1)
            sag.append(t3 - t2)
        g, a, s = (1e3 * statistics.median(x) for x in (gate, along, sag))
        at = report.min_clearance_at or {}
        bound = report.min_clearance_bound_m
        figure = (
            f"{1e3 * report.min_clearance_m:.2f} / {1e3 * bound:.2f} / "
            f"{1e3 * at.get('tolerance_m', 0.0):.2f} mm"
            if bound is not None
            else "-"
        )
        print(f"{name:24s} {len(prof.t):7d} {g:8.1f} {a:9.1f} {s:7.1f} {max(0.0, g - a - s):8.1f}  {figure}")  # noqa: T201
    print(_load())  # noqa: T201


if __name__ == "__main__":
    main()
