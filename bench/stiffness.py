"""Stiffness benchmarks of cabin8 (issue 7).

* Cartesian stiffness K at one configuration (analytical model, eq. 54-75)
* gravity deflection along a trajectory of 1000 samples (``deflection_along``, vectorised)
* one goal compensation (fixed point to a tenth of the gate's 0.01 mm / 1e-5 rad, closed-form IK per step)
* one FE solve (the independent frame finite-element route, for scale)

Each figure is the median of repeated timings in this run (spread in brackets).
Run: ``python -m bench.stiffness``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from planner.dynamics.frame_fe import fe_deflection
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.dynamics.stiffness import StiffnessModel, compensate_goal
from planner.robots.cabin8 import Cabin8


def per_call_ms(fn: Callable[[], object], number: int, repeat: int = 7) -> tuple[float, float, float]:
    """(median, min, max) milliseconds per call over ``repeat`` runs of ``number`` calls."""
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        runs.append((time.perf_counter() - t0) / number * 1e3)
    return statistics.median(runs), min(runs), max(runs)


def report(name: str, fig: tuple[float, float, float]) -> None:
    """Print one benchmark line."""
    med, lo, hi = fig
    print(f"{name:<52} {med:9.3f} ms  (spread {lo:.3f}-{hi:.3f})")  # noqa: T201


def _admissible(robot: Cabin8, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ps = robot.desc.parallel_stage
    lo, hi = robot.limits.lower.copy(), robot.limits.upper.copy()
    lo[1:4] = [-0.3, ps.y_range[0], -ps.gamma_max]
    hi[1:4] = [0.3, ps.y_range[1], ps.gamma_max]
    out: list[np.ndarray] = []
    while len(out) < n:
        for q in rng.uniform(lo, hi, size=(4 * n, 8)):
            if not robot.violations(q):
                out.append(q)
                if len(out) == n:
                    break
    return np.array(out)


def main() -> None:
    """Run every benchmark and print the medians."""
    robot = Cabin8()
    model = StiffnessModel(robot)
    payload = RigidPayload.from_grasp(100.0, np.zeros(3), box_inertia(100.0, (0.45, 0.35, 0.3)), np.eye(4))
    grasp = np.eye(4)
    grasp[:3, 3] = [0.0, 0.0, 0.2]
    qs = _admissible(robot, 1000, seed=5)
    q_goal = robot.joints_from_drives(robot.home_drives)
    q_goal[4] = 1.2
    T_goal = robot.fk(q_goal) @ grasp
    print("cabin8 stiffness benchmark (100 kg payload, 0.2 m grasp offset)\n")  # noqa: T201
    report("stiffness K at one configuration", per_call_ms(lambda: model.stiffness(qs[0], grasp), 200))
    report(
        "deflection_along, 1000 samples", per_call_ms(lambda: model.deflection_along(qs, payload, grasp), 5)
    )
    report(
        "one goal compensation (to 1 um / 1e-6 rad)",
        per_call_ms(lambda: compensate_goal(model, T_goal, q_goal, payload, grasp), 20),
    )
    report(
        "one FE solve (independent route)",
        per_call_ms(lambda: fe_deflection(robot, qs[0], payload, grasp), 50),
    )
    comp = compensate_goal(model, T_goal, q_goal, payload, grasp)
    x = model.deflection_along(qs, payload, grasp)
    tr = np.linalg.norm(x[:, :3], axis=1) * 1e3
    print(  # noqa: T201
        f"\ncompensation: {len(comp.iterations)} evaluations, residual {comp.residual_m * 1e6:.3f} um; "
        f"gravity sag over 1000 random admissible configurations: median {np.median(tr):.2f} mm, "
        f"90% {np.percentile(tr, 90):.2f} mm, max {tr.max():.1f} mm"
    )


if __name__ == "__main__":
    main()
