"""The checks every drive profile must pass, whatever the robot: the drive-space half of the gate.

``finite``, ``time``, ``start``, ``end_at_rest``, ``position``, ``velocity``, ``acceleration`` (reported and
executed dv/dt), ``jerk`` (the change of the sampled acceleration over each period, for a robot with jerk
limits) and ``consistency`` (see :mod:`planner.gate.checks`), from the sampled drives and the
robot's :class:`~planner.robots.base.DriveLimits` alone. Each robot's gate adds its own checks (cabin8:
workspace, forces, goal, approach, collision; pprs6: pose path, singularity).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.types import Array
from planner.gate.requirements import ACC_CONSISTENCY, LIMIT_TOLERANCE, START_TOL
from planner.robots.base import RobotModel
from planner.timing.profile import DriveProfile


@dataclass(frozen=True)
class Check:
    """One check of the gate: its outcome, a readable detail, the worst value and where."""

    name: str
    passed: bool
    detail: str
    worst: float | None = None
    sample: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "name": self.name,
            "passed": bool(self.passed),
            "detail": self.detail,
            "worst": None if self.worst is None else float(self.worst),
            "sample": None if self.sample is None else int(self.sample),
        }


@dataclass(frozen=True)
class GateReport:
    """Every check's outcome; ``passed`` only if all passed."""

    checks: tuple[Check, ...]
    samples: int
    #: The smallest exact distance over every sample [m] (any body to the cabin, or two checked bodies).
    min_clearance_m: float
    peak_ratios: dict[str, float]
    #: Certified lower bound [m] of that distance along the polyline through the samples, between them.
    min_clearance_bound_m: float | None = None
    #: Where ``min_clearance_m`` is: ``{"t_s", "sample", "bodies": [a, b], "tolerance_m"}`` (b "cabin" for
    #: the cabin; no sample's exact distance is below ``min_clearance_m`` by more than ``tolerance_m``).
    min_clearance_at: dict[str, Any] | None = None
    #: The payload frame's predicted static deflection the sagging certificate used: (sample indices (K,),
    #: twists (K, 6) [m, rad]); None where the gate did not evaluate it. Not part of :meth:`to_dict`: the
    #: plan's report publishes it (``report.deflection``), from these numbers.
    deflection: tuple[Any, Any] | None = field(default=None, compare=False, repr=False)

    @property
    def passed(self) -> bool:
        """True when every check passed."""
        return all(c.passed for c in self.checks)

    @property
    def failures(self) -> list[Check]:
        """The checks that failed."""
        return [c for c in self.checks if not c.passed]

    def to_dict(self) -> dict[str, Any]:
        """JSON form of the whole report."""
        return {
            "passed": bool(self.passed),
            "samples": self.samples,
            "min_clearance_m": self.min_clearance_m,
            "min_clearance_bound_m": self.min_clearance_bound_m,
            "min_clearance_at": self.min_clearance_at,
            "peak_ratios": self.peak_ratios,
            "checks": [c.to_dict() for c in self.checks],
        }

    def summary(self) -> str:
        """One line: every failure, or the number of passed checks."""
        if self.passed:
            return f"all {len(self.checks)} checks passed on {self.samples} samples"
        return "; ".join(f"{c.name}: {c.detail}" for c in self.failures)


def ratio_check(
    name: str, values: Array, limit: Array, robot: RobotModel, unit: str, n: int
) -> tuple[Check, float]:
    """Peak of |values| / limit over every row; rows past ``n`` are per-step values (step k = row - n)."""
    ratio = np.abs(values) / limit[None, :]
    row, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    worst = float(ratio[row, j])
    ok = worst <= 1.0 + LIMIT_TOLERANCE
    if row < n:
        where = f"{robot.drive_names[j]} at sample {row}, {values[row, j]:.4g} {unit}"
        sample = int(row)
    else:
        sample = int(row - n)
        where = (
            f"{robot.drive_names[j]} executed between samples {sample} and {sample + 1}, "
            f"{values[row, j]:.4g} {unit}"
        )
    detail = f"peak {100 * worst:.1f}% of the limit ({where})"
    return Check(name, ok, detail, worst, sample), worst


def drive_checks(
    profile: DriveProfile,
    robot: RobotModel,
    start_u: Array,
    sample_period_s: float | None,
    require_jerk: bool = True,
) -> tuple[list[Check], dict[str, float]]:
    """The robot-independent checks of a sampled profile and the peak limit ratios.

    The first check is ``finite``; when it fails no other check is evaluated.

    Args:
        profile: The sampled profile.
        robot: Its robot (drive names and limits).
        start_u: The start the profile must begin at, at rest (n_drives,).
        sample_period_s: The controller period the profile must be sampled at (None: its own).
        require_jerk: Whether the jerk limits bind (False for an acceleration-limited profile, asked for
            by ``options.timing``: the check then reports the peak and passes).
    """
    checks: list[Check] = []
    lim = robot.limits
    t, u, ud, udd = profile.t, profile.position, profile.velocity, profile.acceleration
    series = [u, ud, udd] + ([profile.effort] if profile.effort is not None else [])
    n, m = len(t), robot.n_drives
    arrays_ok = all(a.shape == (n, m) for a in series) and t.ndim == 1 and n >= 2
    finite = arrays_ok and all(np.all(np.isfinite(a)) for a in (t, *series))
    checks.append(
        Check("finite", bool(finite), "all values finite" if finite else "non-finite or mis-shaped arrays")
    )
    if not finite:
        return checks, {}
    dt = np.diff(t)
    period = profile.sample_period_s
    time_ok = (
        abs(t[0]) < 1e-12
        and bool(np.all(dt > 0))
        and bool(np.all(np.abs(dt - period) < 1e-9 * max(1.0, t[-1])))
    )
    detail = f"{n} samples every {period} s" if time_ok else "t must start at 0 and step by the sample period"
    if sample_period_s is not None and abs(period - sample_period_s) > 1e-12:
        time_ok = False
        detail = f"sampled every {period} s, but the controller period is {sample_period_s} s"
    checks.append(Check("time", time_ok, detail))
    err0 = float(np.max(np.abs(u[0] - start_u)))
    checks.append(
        Check(
            "start",
            err0 <= START_TOL and float(np.max(np.abs(ud[0]))) == 0.0,
            f"start deviation {err0:.3g}",
            err0,
            0,
        )
    )
    vend = float(np.max(np.abs(ud[-1])))
    aend = float(np.max(np.abs(udd[-1])))
    checks.append(
        Check(
            "end_at_rest",
            vend == 0.0 and aend == 0.0,
            f"final velocity {vend:.3g}, final acceleration {aend:.3g}",
            max(vend, aend),
            n - 1,
        )
    )
    pos_lo = float(np.max(lim.lower[None, :] - u))
    pos_hi = float(np.max(u - lim.upper[None, :]))
    checks.append(
        Check("position", max(pos_lo, pos_hi) <= 1e-9, f"worst excursion {max(pos_lo, pos_hi, 0.0):.3g}")
    )
    peaks: dict[str, float] = {}
    # The acceleration a controller executes between samples is dv/dt: both it and the reported one count.
    mean_acc = np.diff(ud, axis=0) / dt[:, None]
    executed = np.vstack([udd, mean_acc])
    for name, vals, limit, unit in (
        ("velocity", ud, lim.v_max, "/s"),
        ("acceleration", executed, lim.a_max, "/s^2"),
    ):
        chk, peaks[name] = ratio_check(name, vals, limit, robot, unit, n)
        checks.append(chk)
    if lim.j_max is not None:
        # Jerk from the sampled accelerations: (a_{k+1} - a_k) / dt, the jerk a controller executes.
        jerk = np.diff(udd, axis=0) / dt[:, None]
        chk, peaks["jerk"] = ratio_check("jerk", jerk, lim.j_max, robot, "/s^3", 0)
        if not require_jerk:
            chk = Check("jerk", True, f"not required (acceleration-limited timing): {chk.detail}", chk.worst)
        checks.append(chk)
    # Kinematic consistency: positions integrate the velocities (trapezoid rule), and the mean
    # acceleration of each step, dv/dt, lies between the reported accelerations at its ends (the time
    # law's acceleration is piecewise constant, so it may switch within a step).
    dpos = np.abs(np.diff(u, axis=0) - 0.5 * dt[:, None] * (ud[1:] + ud[:-1])) / (
        lim.v_max[None, :] * dt[:, None]
    )
    lo_acc = np.minimum(udd[1:], udd[:-1])
    hi_acc = np.maximum(udd[1:], udd[:-1])
    dvel = np.maximum(lo_acc - mean_acc, mean_acc - hi_acc).clip(min=0.0) / lim.a_max[None, :]
    worst_c = float(max(dpos.max(), dvel.max() / ACC_CONSISTENCY * LIMIT_TOLERANCE))
    checks.append(
        Check(
            "consistency",
            worst_c <= LIMIT_TOLERANCE,
            f"positions integrate velocities and velocities accelerations to {100 * worst_c:.2f}% of a limit",
            worst_c,
        )
    )
    return checks, peaks
