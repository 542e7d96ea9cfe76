"""The robot's body poses and admissibility vector c(q) inside the compiled kernels, through its model.

The pose kernel is the robot model's (its :class:`~planner.robots.geometry.CollisionModel` gives the code
and parameters packed in the world's buffers); :mod:`planner.robots.kernels` dispatches to it, so no
robot is named here. A pose row holds 13 values: R column-major (9), centre p (3), capsule length.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.collision.kernels.buffers import Packed
from planner.robots import kernels


@njit(cache=True, fastmath=False, error_model="numpy")
def poses_at(q: np.ndarray, u: Packed, poses: np.ndarray, c: np.ndarray) -> None:
    """Body poses at q into ``poses`` (B, 13) and c(q) into ``c`` (m,), on unpacked data."""
    kernels.body_poses(u.kernel, q, u.T_tool_box, u.params, u.kinds, poses, c)


@njit(cache=True, fastmath=False, error_model="numpy")
def constraints_at(q: np.ndarray, u: Packed, c: np.ndarray) -> None:
    """The admissibility vector c(q) into ``c`` (m,), on unpacked data."""
    kernels.constraints(u.kernel, q, u.params, c)


@njit(cache=True, fastmath=False, error_model="numpy")
def admissible(c: np.ndarray, c_lo: np.ndarray, c_hi: np.ndarray) -> bool:
    """Every admissibility value within its (already tolerance-widened) bounds; NaN is not."""
    for i in range(c.shape[0]):
        if not (c[i] >= c_lo[i] and c[i] <= c_hi[i]):
            return False
    return True
