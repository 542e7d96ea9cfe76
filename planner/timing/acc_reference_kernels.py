"""The compiled forward-backward integration of :mod:`planner.timing.acc_reference` (numba).

Reached through :func:`planner.timing.acc_reference.acceleration_limited`, which checks the arguments and runs
the ahead-of-time build of these functions (:data:`planner.timing.acc_reference.EXTENSION`) or, without one,
numba's JIT.
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
