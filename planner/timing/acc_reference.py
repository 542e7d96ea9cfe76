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

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from planner.core import aot
from planner.core.aot import F8, Entry, check_array
from planner.core.types import Array


def _jit_module() -> ModuleType:
    """The ``@njit`` integration (:mod:`planner.timing.acc_reference_kernels`; importing it imports numba)."""
    from planner.timing import acc_reference_kernels

    return acc_reference_kernels


#: The extension of the integration (:mod:`planner.timing.acc_reference_kernels`), built ahead of time by
#: :mod:`planner.core.aot` (``python -m planner.timing.acc_reference``; at first use otherwise).
EXTENSION = aot.Extension(
    name="cabinplan_timing_kernels",
    kernels_module=_jit_module,
    builder_module="planner.timing.acc_reference",
    sources=(Path(__file__).resolve().parent / "acc_reference_kernels.py",),
    entries=(Entry("_forward_backward", ("f8[1]", "f8[2]", "f8[2]", "f8[2]", "f8[1]"), "f8[1]w"),),
)

_kernels: Any = None


def kernels(module: Any = None) -> Any:
    """The implementation of the integration: ``module`` if given (tests), else the build or the JIT."""
    global _kernels
    if module is not None:
        return module
    if _kernels is None:
        _kernels = aot.kernels(EXTENSION)
    return _kernels


def acceleration_limited(
    ds: Array, cx: Array, cy: Array, b: Array, x_max: Array, implementation: Any = None
) -> Array:
    """sd^2 (N + 1,) of the time-optimal acceleration-limited law at rest at both ends.

    Args:
        ds: (N,) grid intervals.
        cx: (N + 1, R) coefficients of x = sd^2 in the rows cx x + cy y <= b at each grid point.
        cy: (N + 1, R) coefficients of y = sdd.
        b: (N + 1, R) right-hand sides.
        x_max: (N + 1,) upper bound of x at each point (velocity limits).
        implementation: The compiled functions to use (tests: the build or the JIT); default: the build.

    Raises:
        TypeError: an argument has the wrong number of dimensions.
        ValueError: the shapes do not fit together (the compiled code does not check its indices).
    """
    ds = check_array(np.ascontiguousarray(ds, dtype=float), "ds", F8, 1)
    cx = check_array(np.ascontiguousarray(cx, dtype=float), "cx", F8, 2)
    cy = check_array(np.ascontiguousarray(cy, dtype=float), "cy", F8, 2)
    b = check_array(np.ascontiguousarray(b, dtype=float), "b", F8, 2)
    x_max = check_array(np.ascontiguousarray(x_max, dtype=float), "x_max", F8, 1)
    n = len(x_max)
    if not (n >= 1 and cx.shape == cy.shape == b.shape and cx.shape[0] == n and len(ds) >= n - 1):
        raise ValueError(
            f"acceleration_limited: shapes ds {ds.shape}, cx {cx.shape}, cy {cy.shape}, b {b.shape}, "
            f"x_max {x_max.shape} do not fit (N,), (N + 1, R) x 3, (N + 1,) with N >= 0"
        )
    return np.asarray(kernels(implementation)._forward_backward(ds, cx, cy, b, x_max))


if __name__ == "__main__":
    aot.main(EXTENSION)
