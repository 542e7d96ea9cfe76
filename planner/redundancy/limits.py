"""Limits of a redundancy-resolution step, linearised into inequality constraints G dq <= h."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

from planner.core.types import Array
from planner.redundancy.configuration import Configuration


class Constraint(NamedTuple):
    """Linear inequality G dq <= h on the joint step dq (G: (m, 8), h: (m,))."""

    G: Array
    h: Array


class Limit(Protocol):
    """Anything that constrains the joint step at a configuration."""

    def compute_qp_inequalities(self, configuration: Configuration) -> Constraint:
        """Inequalities G dq <= h at the configuration."""
        ...


class AdmissibilityLimit:
    """Every drive limit, platform range, slider gap and singularity margin of the robot.

    Each scalar constraint lower <= c(q) <= upper is linearised: lower - c <= dc/dq dq <= upper - c, with
    the right-hand sides scaled by ``gain`` in (0, 1] so a step moves only part of the way to a bound
    (the mink ``ConfigurationLimit`` idea, extended to the nonlinear stage measures).

    Args:
        gain: Fraction of the distance to a bound one step may use.
        margin: Extra inset from every bound, per constraint (shape (m,)) or scalar, in its units.
    """

    def __init__(self, gain: float = 0.95, margin: float | Array = 0.0) -> None:
        if not 0.0 < gain <= 1.0:
            raise ValueError(f"gain must be in (0, 1], got {gain}")
        self.gain = gain
        self.margin = margin

    def compute_qp_inequalities(self, configuration: Configuration) -> Constraint:
        """Inequalities for the upper and lower bounds that are finite."""
        robot = configuration.robot
        rows, sign, bound = _bound_rows(robot.c_lower, robot.c_upper)
        bound = bound - sign * np.broadcast_to(self.margin, robot.c_upper.shape)[rows]
        # Upper rows: dc dq <= gain (up - c); lower rows: -dc dq <= gain (c - lo). A bound already
        # violated gives a negative right-hand side: the step must move back towards it.
        G = configuration.dc_dq[rows] * sign[:, None]
        h = self.gain * sign * (bound - configuration.c[rows])
        return Constraint(G, h)


_ROWS_CACHE: dict[tuple[bytes, bytes], tuple[Array, Array, Array]] = {}


def _bound_rows(lower: Array, upper: Array) -> tuple[Array, Array, Array]:
    """(row index, sign +1 upper / -1 lower, bound value) for every finite bound, cached per limits."""
    key = (lower.tobytes(), upper.tobytes())
    hit = _ROWS_CACHE.get(key)
    if hit is None:
        hi = np.flatnonzero(np.isfinite(upper))
        lo = np.flatnonzero(np.isfinite(lower))
        hit = (
            np.concatenate([hi, lo]),
            np.concatenate([np.ones(hi.size), -np.ones(lo.size)]),
            np.concatenate([upper[hi], lower[lo]]),
        )
        _ROWS_CACHE[key] = hit
    return hit


class DriveVelocityLimit:
    """|du_i| <= v_max_i dt for the drive step du = G dq of a differential-IK step of duration dt [s]."""

    def __init__(self, dt: float, scale: float = 1.0) -> None:
        if dt <= 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.dt = dt
        self.scale = scale

    def compute_qp_inequalities(self, configuration: Configuration) -> Constraint:
        """Two-sided bounds on the linearised drive step."""
        robot = configuration.robot
        G = configuration.dc_dq[:8]
        bound = self.scale * robot.limits.v_max * self.dt
        return Constraint(np.vstack([G, -G]), np.concatenate([bound, bound]))
