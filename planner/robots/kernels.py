"""The compiled pose kernels of every robot, behind one entry each: the collision kernels call these.

The collision world's compiled hot path (:mod:`planner.collision.kernels`) needs a robot's body poses and
admissibility vector c(q) inside compiled code. It calls :func:`body_poses` and :func:`constraints` with
the code and parameters its robot model gave (:class:`~planner.robots.geometry.CollisionModel`'s
``kernel`` and ``kernel_params``); these dispatch to the robot's own kernel. A robot adds its kernel
module and one branch in each function below.

Why a branch and not a function handed to the kernels: numba specialises a kernel on every function it is
given and keys its on-disk cache on that function's identity, which differs in every process (measured:
a cache miss, 2-3 s of compilation, in every new process, and ~100 us per call when the function is passed
as a first-class value). A branch on an integer keeps every kernel cached and costs nothing measurable.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.robots import cabin8_kernels
from planner.robots.kernel_codes import CABIN8

__all__ = ["CABIN8", "body_poses", "constraints"]


@njit(cache=True, fastmath=False, error_model="numpy")
def body_poses(
    kernel: int,  # the robot's kernel code
    q: np.ndarray,  # (n_joints,) joints
    T_tool_box: np.ndarray,  # (4, 4) payload box frame in the tool frame
    params: np.ndarray,  # the robot's kernel parameters
    kinds: np.ndarray,  # (B,) body kind codes (``CollisionModel.kind_code``)
    poses: np.ndarray,  # (B, 13) out: R column-major, p, capsule length
    c: np.ndarray,  # (m,) out: admissibility values c(q)
) -> None:
    """Body poses and the admissibility vector of the robot ``kernel`` at one configuration (NaN: none)."""
    if kernel == CABIN8:
        cabin8_kernels.body_poses(q, T_tool_box, params, kinds, poses, c)
    else:
        poses[:, :] = math.nan
        c[:] = math.nan


@njit(cache=True, fastmath=False, error_model="numpy")
def constraints(kernel: int, q: np.ndarray, params: np.ndarray, c: np.ndarray) -> None:
    """The admissibility vector c(q) of the robot ``kernel`` into ``c`` (NaN: an unknown kernel)."""
    if kernel == CABIN8:
        cabin8_kernels.constraint_values(q, params, c)
    else:
        c[:] = math.nan
