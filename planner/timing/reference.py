"""The acceleration-limited reference speed of the jerk-limited stage (:mod:`planner.timing.jerk`).

The jerk LP linearises the drive jerk sd (u' y' + 3 u'' y + u''' x) around a reference speed; its
reference is derived from the time-optimal acceleration-limited speed x_acc(s) = sd^2 of the path, which
this module computes by the classic forward-backward integration on the grid (Bobrow, Dubowsky & Gibson
1985; the bang-bang structure of Shin & McKay): every grid point's constraints are rows
cx x + cy y <= b in (x, y) = (sd^2, sdd); the maximum velocity curve is the largest x with a feasible y;
the forward pass accelerates at the largest feasible y, x_{i+1} = x_i + 2 y ds_i, the backward pass
decelerates at the smallest, and the profile is the smaller of the two and the curve. It is only a
reference: the LP (HiGHS) decides the law under every constraint, conservatively with respect to it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.core.types import Array

#: Bisection steps of the maximum velocity curve (relative accuracy 2^-40).
BISECTIONS = 40


@njit(cache=True, fastmath=False, error_model="numpy")
def _y_range(cx: Array, cy: Array, b: Array, x: float) -> tuple[float, float]:  # pragma: no cover - numba
    """The interval of y allowed by the rows at one point for x (lo > hi: none)."""
    lo, hi = -np.inf, np.inf
    for r in range(len(b)):
        rhs = b[r] - cx[r] * x
        if cy[r] > 1e-12:
            hi = min(hi, rhs / cy[r])
        elif cy[r] < -1e-12:
            lo = max(lo, rhs / cy[r])
        elif rhs < 0.0:
            return np.inf, -np.inf
    return lo, hi


@njit(cache=True, fastmath=False, error_model="numpy")
def _forward_backward(
    ds: Array, cx: Array, cy: Array, b: Array, x_max: Array
) -> Array:  # pragma: no cover - numba
    n = len(x_max)
    mvc = np.zeros(n)
    for i in range(n):
        lo, hi = _y_range(cx[i], cy[i], b[i], x_max[i])
        if lo <= hi:
            mvc[i] = x_max[i]
            continue
        a, c = 0.0, x_max[i]
        for _ in range(BISECTIONS):
            mid = 0.5 * (a + c)
            lo, hi = _y_range(cx[i], cy[i], b[i], mid)
            if lo <= hi:
                a = mid
            else:
                c = mid
        mvc[i] = a
    fwd = np.zeros(n)
    for i in range(n - 1):
        lo, hi = _y_range(cx[i], cy[i], b[i], fwd[i])
        step = max(hi, 0.0) if lo <= hi else 0.0
        fwd[i + 1] = min(mvc[i + 1], fwd[i] + 2.0 * ds[i] * step)
    out = np.zeros(n)
    for i in range(n - 2, -1, -1):
        lo, hi = _y_range(cx[i + 1], cy[i + 1], b[i + 1], out[i + 1])
        step = max(-lo, 0.0) if lo <= hi else 0.0
        out[i] = min(fwd[i], out[i + 1] + 2.0 * ds[i] * step)
    out[-1] = 0.0
    return out


def acceleration_limited(ds: Array, cx: Array, cy: Array, b: Array, x_max: Array) -> Array:
    """sd^2 (N + 1,) of the time-optimal acceleration-limited law at rest at both ends.

    Args:
        ds: (N,) grid intervals.
        cx: (N + 1, R) coefficients of x = sd^2 in the rows cx x + cy y <= b at each grid point.
        cy: (N + 1, R) coefficients of y = sdd.
        b: (N + 1, R) right-hand sides.
        x_max: (N + 1,) upper bound of x at each point (velocity limits).
    """
    return np.asarray(
        _forward_backward(
            np.ascontiguousarray(ds, dtype=float),
            np.ascontiguousarray(cx, dtype=float),
            np.ascontiguousarray(cy, dtype=float),
            np.ascontiguousarray(b, dtype=float),
            np.ascontiguousarray(x_max, dtype=float),
        )
    )
