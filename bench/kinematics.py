"""Kinematics and redundancy benchmarks of cabin8 (issue targets in brackets).

* FK + joint and drive Jacobians for one configuration            [<= 20 us]
* batch FK of 1e5 configurations (numpy)                           [>= 1e6 configurations/s]
* one redundancy QP step (build + solve) per solver                [<= 100 us]
* one full IK solve on random reachable poses                      [median <= 5 ms]

Each figure is the median of repeated timings in this run; machine noise is reported as the spread.
Run: ``python -m bench.kinematics`` (or ``make bench``).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from planner.core.so3 import pose_error
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.redundancy.compiled_step import IKStep, StepWeights
from planner.redundancy.configuration import Configuration
from planner.redundancy.ik import comfort_margins, random_admissible_joints, solve_pose_ik
from planner.redundancy.limits import AdmissibilityLimit
from planner.redundancy.solve import build_problem, solve_problem, solve_step
from planner.redundancy.tasks import FrameTask, MarginTask, PostureTask
from planner.robots.cabin8 import Cabin8


def per_call_us(fn: Callable[[], object], number: int, repeat: int = 7) -> tuple[float, float, float]:
    """(median, min, max) microseconds per call over ``repeat`` runs of ``number`` calls."""
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        runs.append((time.perf_counter() - t0) / number * 1e6)
    return statistics.median(runs), min(runs), max(runs)


def line(name: str, stats: tuple[float, float, float], unit: str = "us", target: str = "") -> None:
    med, lo, hi = stats
    print(f"{name:<48} {med:10.2f} {unit}  (spread {lo:.2f}-{hi:.2f}) {target}")


def main() -> None:
    robot = Cabin8()
    rng = np.random.default_rng(0)
    qs = random_admissible_joints(robot, rng, 200)
    q = qs[0]
    print(f"cabin8 kinematics benchmark, {len(qs)} random admissible configurations\n")

    line(
        "FK + J_q + J_u (one compiled call)",
        per_call_us(lambda: robot.fk_jacobians(q), 5000),
        target="[<= 20 us]",
    )
    line("FK only", per_call_us(lambda: robot.fk(q), 5000))
    line("constraints c(q), dc/dq", per_call_us(lambda: robot.constraint_values(q), 5000))

    big = np.repeat(qs, 500, axis=0)  # 1e5 configurations
    batch = per_call_us(lambda: robot.fk_batch(big), 1, repeat=7)
    rate = big.shape[0] / (batch[0] * 1e-6)
    print(
        f"{'batch FK, 1e5 configurations':<48} {batch[0] / 1e3:10.2f} ms  -> {rate:,.0f} configurations/s "
        "[>= 1e6/s]"
    )

    dyn = Cabin8Dynamics(robot)
    payload = RigidPayload(100.0, np.array([0, 0, 0.3]), box_inertia(100.0, (0.45, 0.35, 0.5)))
    qd, qdd = rng.normal(size=8) * 0.1, rng.normal(size=8) * 0.1
    line(
        "inverse dynamics (tau_q and tau_u)",
        per_call_us(lambda: dyn.inverse_dynamics(q, qd, qdd, payload), 3000),
    )
    # Batched drive forces (TOPP-RA's force constraint, the gate): the native build against CasADi's
    # virtual machine, per grid point, on the same 1024 states.
    qb = np.resize(qs, (1024, 8))
    qdb, qddb = rng.normal(size=qb.shape) * 0.1, rng.normal(size=qb.shape) * 0.1
    native = per_call_us(lambda: dyn.drive_forces_batch(qb, qdb, qddb, payload), 20)
    par = payload.params()
    vm = per_call_us(lambda: [dyn.id_vm(qb[i], qdb[i], qddb[i], par) for i in range(len(qb))], 3)
    n = len(qb)
    line("batched drive forces, native build, per point", (native[0] / n, native[1] / n, native[2] / n))
    line("the same, CasADi VM calls point by point", (vm[0] / n, vm[1] / n, vm[2] / n))

    cfg = Configuration(robot, q)
    T = cfg.T_base_tool.copy()
    T[:3, 3] += [0.05, 0.02, 0.1]
    tasks = [FrameTask(T, lm_damping=1e-3), PostureTask(q, 0.05), MarginTask(np.full(16, 0.05), 0.2)]
    limits = [AdmissibilityLimit(0.9)]
    step_max = np.full(8, 0.2)
    line(
        "QP step build (FK, Jacobians, tasks, limits)",
        per_call_us(lambda: build_problem(Configuration(robot, q), tasks, limits, step_max=step_max), 3000),
    )
    problem = build_problem(cfg, tasks, limits, step_max=step_max)
    for solver in ("daqp", "quadprog", "osqp"):
        line(f"QP solve only: {solver}", per_call_us(lambda s=solver: solve_problem(problem, s), 500))  # type: ignore[misc]
    line(
        "QP step, generic task classes + daqp",
        per_call_us(lambda: solve_step(Configuration(robot, q), tasks, limits, step_max=step_max), 3000),
    )
    step = IKStep(robot, comfort_margins(robot))
    weights = StepWeights(1.0, 1.0, 1e-3, 0.05, 0.2, 0.9)

    def compiled_step() -> None:
        err = pose_error(T, robot.fk(q))
        solve_problem(step.problem(q, err, q, weights, step_max))

    line(
        "QP step, compiled (FK, error, QP build, daqp)",
        per_call_us(compiled_step, 3000),
        target="[<= 100 us]",
    )

    times = []
    for qq in qs:
        Tq = robot.fk(qq)
        t0 = time.perf_counter()
        solve_pose_ik(robot, Tq)
        times.append((time.perf_counter() - t0) * 1e3)
    print(
        f"{'IK solve, ' + str(len(qs)) + ' random reachable poses':<48} {statistics.median(times):10.2f} ms  "
        f"(p95 {np.percentile(times, 95):.2f} ms, max {max(times):.2f} ms) [median <= 5 ms]"
    )


if __name__ == "__main__":
    main()
