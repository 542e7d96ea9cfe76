"""cabin8's compiled pose kernel: body poses and the admissibility vector c(q) in closed form (numba).

Stage (paper eq. 4) and MDH chain (eq. 10-12), the same quantities in the same order as the CasADi pose
function (:func:`planner.robots.cabin8_geometry.pose_function`) and
``planner.robots.cabin8.constraint_terms``; the tests check both agree to 1e-12. A pose row holds 13 values: R
column-major (9), centre p (3), capsule length. The collision kernels reach these through
:mod:`planner.robots.kernels` (by the model's kernel code), never by name; the kernel parameters are
:data:`PARAMS` values: the MDH table (4 x 6) then the stage lengths L1..L4.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.robots.kernel_codes import CABIN8_KIND_CODES, CABIN8_PARAMS

#: Length of cabin8's kernel parameters and its body kinds (:mod:`planner.robots.kernel_codes`).
PARAMS = CABIN8_PARAMS
KIND_CODES = CABIN8_KIND_CODES


@njit(cache=True, fastmath=False, error_model="numpy")
def _root(v: float) -> float:
    """sqrt(v), NaN below 0 (as numpy: a link that cannot reach the rail gives NaN, never an exception)."""
    return math.sqrt(v) if v >= 0.0 else math.nan


@njit(cache=True, fastmath=False, error_model="numpy")
def _segment_pose(a: np.ndarray, b: np.ndarray, row: np.ndarray) -> None:
    """Capsule frame from a to b into ``row`` (13): z along b - a, centred at the midpoint, length |b - a|.

    The same construction as the CasADi pose function: x = helper x z normalised, y = z x x, with the
    helper (1, 0, 0) unless z is within ~26 degrees of it, then (0, 1, 0).
    """
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    zx, zy, zz = dx / length, dy / length, dz / length
    if abs(zx) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    xx, xy, xz = hy * zz - hz * zy, hz * zx - hx * zz, hx * zy - hy * zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    row[0], row[1], row[2] = xx, xy, xz
    row[3], row[4], row[5] = yx, yy, yz
    row[6], row[7], row[8] = zx, zy, zz
    row[9], row[10], row[11] = 0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])
    row[12] = length


@njit(cache=True, fastmath=False, error_model="numpy")
def constraints(
    q: np.ndarray, stage: np.ndarray, c: np.ndarray
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The admissibility vector c(q) into ``c`` (16); returns the stage points (x1, x2, x3, B, C, E).

    Stage (paper eq. 4): B, C = (x, y) -/+ L2/2 (cos g, sin g); x1 = x_B - sqrt(L1^2 - y_B^2),
    x2 = x_C + sqrt(L3^2 - y_C^2), E = (A + B)/2, x3 = x_E + sqrt(L4^2 - y_E^2); then the values of
    ``planner.robots.cabin8.constraint_terms`` in its order (NaN where a link cannot reach the rail).
    """
    L1, L2, L3, L4 = stage[0], stage[1], stage[2], stage[3]
    d1, x, y, g = q[0], q[1], q[2], q[3]
    h = 0.5 * L2
    cg, sg = math.cos(g), math.sin(g)
    xb, yb = x - h * cg, y - h * sg
    xc, yc = x + h * cg, y + h * sg
    x1 = xb - _root(L1 * L1 - yb * yb)
    x2 = xc + _root(L3 * L3 - yc * yc)
    xe, ye = 0.5 * (x1 + xb), 0.5 * yb
    x3 = xe + _root(L4 * L4 - ye * ye)
    c[0], c[1], c[2], c[3] = d1, x1, x2, x3
    for i in range(4, 8):
        c[i] = q[i]
    c[8], c[9], c[10], c[11] = y, g, x3 - x1, x2 - x3
    bd_x, bd_y = x2 - xb, -yb
    cross = (xc - xb) * bd_y - (yc - yb) * bd_x
    c[12] = -cross / (L2 * math.sqrt(bd_x * bd_x + bd_y * bd_y))
    c[13], c[14], c[15] = yb / L1, yc / L3, ye / L4
    return x1, x2, x3, xb, yb, xc, yc, xe, ye


@njit(cache=True, fastmath=False, error_model="numpy")
def body_poses(
    q: np.ndarray,  # (8,) joints (d1, x, y, gamma, theta3, theta4, d5, theta6)
    T_tool_box: np.ndarray,  # (4, 4) payload box frame in the tool frame
    params: np.ndarray,  # (PARAMS,) the MDH table (4 x 6) then the stage lengths L1..L4
    kinds: np.ndarray,  # (B,) body kind codes (KIND_CODES)
    poses: np.ndarray,  # (B, 13) out: R column-major, p, capsule length
    c: np.ndarray,  # (16,) out: admissibility values c(q)
) -> None:
    """Body poses and the admissibility vector at one configuration, closed form (no CasADi call).

    Stage points and c(q) from :func:`constraints`. Chain (eq. 10-12):
    T_2 = Trans(x, y, d1) RotZ(gamma), then T_i = T_(i-1) RotX(alpha) TransX(a) RotZ(theta) TransZ(d).
    The same quantities, in the same order, as the CasADi pose function and ``constraint_terms``; the
    tests check both agree to 1e-12.
    """
    mdh, stage = params[:24].reshape((4, 6)), params[24:PARAMS]
    x1, x2, x3, xb, yb, xc, yc, xe, ye = constraints(q, stage, c)
    d1, x, y, g = q[0], q[1], q[2], q[3]
    cg, sg = math.cos(g), math.sin(g)
    # Serial chain: R (3, 3) and p (3,) of frames 2..6; origins kept for the capsules.
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = cg, -sg, 0.0
    R[1, 0], R[1, 1], R[1, 2] = sg, cg, 0.0
    R[2, 0], R[2, 1], R[2, 2] = 0.0, 0.0, 1.0
    p = np.empty(3)
    p[0], p[1], p[2] = x, y, d1
    R2 = R.copy()
    origins = np.empty((5, 3))  # frames 2, 3, 4, 5, 6
    origins[0] = p
    M = np.empty((3, 3))
    Rn = np.empty((3, 3))
    for i in range(4):
        alpha, a, th0, dd0 = mdh[i, 0], mdh[i, 1], mdh[i, 2], mdh[i, 3]
        j = int(mdh[i, 4])
        if mdh[i, 5] > 0.5:
            theta, d = q[j] + th0, dd0
        else:
            theta, d = th0, q[j] + dd0
        ct, st = math.cos(theta), math.sin(theta)
        cal, sal = math.cos(alpha), math.sin(alpha)
        M[0, 0], M[0, 1], M[0, 2] = ct, -st, 0.0
        M[1, 0], M[1, 1], M[1, 2] = st * cal, ct * cal, -sal
        M[2, 0], M[2, 1], M[2, 2] = st * sal, ct * sal, cal
        mp0, mp1, mp2 = a, -sal * d, cal * d
        for r in range(3):
            p[r] = p[r] + R[r, 0] * mp0 + R[r, 1] * mp1 + R[r, 2] * mp2
            for k in range(3):
                Rn[r, k] = R[r, 0] * M[0, k] + R[r, 1] * M[1, k] + R[r, 2] * M[2, k]
        R[:, :] = Rn
        origins[i + 1] = p
    pa = np.empty(3)
    pb = np.empty(3)
    for b in range(kinds.shape[0]):
        kind = kinds[b]
        row = poses[b]
        if kind == 0:  # carriage: axis-aligned at (0, -0.06, d1)
            for i in range(9):
                row[i] = 0.0
            row[0] = row[4] = row[8] = 1.0
            row[9], row[10], row[11], row[12] = 0.0, -0.06, d1, 0.0
        elif kind == 4:  # platform: frame 2
            for jj in range(3):
                for i in range(3):
                    row[3 * jj + i] = R2[i, jj]
            row[9], row[10], row[11], row[12] = origins[0, 0], origins[0, 1], origins[0, 2], 0.0
        elif kind == 8:  # payload: T_6 T_tool_box
            for jj in range(3):
                for i in range(3):
                    row[3 * jj + i] = (
                        R[i, 0] * T_tool_box[0, jj]
                        + R[i, 1] * T_tool_box[1, jj]
                        + R[i, 2] * T_tool_box[2, jj]
                    )
            for i in range(3):
                row[9 + i] = (
                    R[i, 0] * T_tool_box[0, 3]
                    + R[i, 1] * T_tool_box[1, 3]
                    + R[i, 2] * T_tool_box[2, 3]
                    + p[i]
                )
            row[12] = 0.0
        else:
            if kind == 1:  # A -> B
                pa[0], pa[1], pa[2] = x1, 0.0, d1
                pb[0], pb[1], pb[2] = xb, yb, d1
            elif kind == 2:  # C -> D
                pa[0], pa[1], pa[2] = xc, yc, d1
                pb[0], pb[1], pb[2] = x2, 0.0, d1
            elif kind == 3:  # E -> F
                pa[0], pa[1], pa[2] = xe, ye, d1
                pb[0], pb[1], pb[2] = x3, 0.0, d1
            else:  # column 2 -> 3, arm 3 -> 4, slide 4 -> 6
                first = 0 if kind == 5 else 1 if kind == 6 else 2
                last = 1 if kind == 5 else 2 if kind == 6 else 4
                pa[:] = origins[first]
                pb[:] = origins[last]
            _segment_pose(pa, pb, row)


@njit(cache=True, fastmath=False, error_model="numpy")
def constraint_values(q: np.ndarray, params: np.ndarray, c: np.ndarray) -> None:
    """The admissibility vector c(q) into ``c`` (16), from the kernel parameters (:func:`constraints`)."""
    constraints(q, params[24:PARAMS], c)
