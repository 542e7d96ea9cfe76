"""pprs6 benchmarks: batch IK, batch Newton FK, Jacobian, workspace search, drive profile.

Each figure is the median of a few timings in this run (2-core shared machine: expect noise).
Run: ``python -m bench.pprs6``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from planner.robots.pprs6 import Pprs6
from planner.tools.pprs6 import profile_document, workspace_document


def seconds(fn: Callable[[], object], repeat: int = 5) -> float:
    """Median wall time of ``repeat`` calls [s]."""
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def main() -> None:
    robot = Pprs6()
    rng = np.random.default_rng(0)
    x = robot.home_pose + rng.uniform(-1, 1, (100_000, 6)) * [0.03, 0.03, 0.03, 0.15, 0.2, 0.2]
    x = x[robot.admissible(x)]
    u = robot.ik(x)
    n = len(x)
    t_ik = seconds(lambda: robot.ik(x))
    print(f"batch IK:        {n / t_ik:12.0f} poses/s   ({n} poses)")
    t_j = seconds(lambda: robot.drive_jacobian(x))
    print(f"batch Jacobian:  {n / t_j:12.0f} poses/s")
    xs, us = x[:2000], u[:2000]
    guess = xs + 0.002
    t_fk = seconds(lambda: robot.fk(us, guess=guess), repeat=3)
    print(f"batch Newton FK: {len(xs) / t_fk:12.0f} solves/s (start 2 mm / 2 mrad away)")
    t1 = seconds(lambda: robot.fk(us[0]), repeat=20)
    print(f"single FK:       {1e3 * t1:12.2f} ms (from home)")
    doc: dict = {}
    t_ws = seconds(lambda: doc.update(workspace_document(None, step_m=0.005, png=False)[0]), repeat=3)
    print(
        f"workspace 5 mm:  {t_ws:12.2f} s, volume {1e6 * doc['volume_m3']:.0f} cm^3, "
        f"extents {doc['extents_m']}"
    )
    prof: dict = {}
    t_p = seconds(lambda: prof.update(profile_document(None)), repeat=3)
    print(
        f"profile E-F-G-H-E: {t_p:10.2f} s for {len(prof['t'])} samples, duration {prof['duration_s']:.3f} s"
    )


if __name__ == "__main__":
    main()
