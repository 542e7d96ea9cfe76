"""Small rotation helpers for the hot loops (quaternion conversion at the edges uses scipy)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from planner.core.types import Array


def rotation_angles(R: Array) -> Array:
    """Rotation angles [rad] in [0, pi] of (N, 3, 3) rotation matrices, shape (N,) (vectorised).

    ``atan2(|axial part| / 2, (trace - 1) / 2)``: accurate over the whole range (the angle is; only the
    axis is ill-conditioned near pi, and it is not needed here).
    """
    R = np.asarray(R, dtype=float)
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    cos_t = np.clip(0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    return np.arctan2(0.5 * np.linalg.norm(w, axis=1), cos_t)


def rotation_log(R: Array) -> Array:
    """Rotation vector (axis * angle [rad], angle in [0, pi]) of a 3x3 rotation matrix.

    Accurate across the whole range, including angles near 0 (series) and near pi (from the symmetric
    part), which the textbook ``acos`` formula is not.
    """
    r = R.tolist()
    cos_t = min(1.0, max(-1.0, 0.5 * (r[0][0] + r[1][1] + r[2][2] - 1.0)))
    wx, wy, wz = r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]
    sin_t = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
    theta = math.atan2(sin_t, cos_t)
    if theta < 1e-6:
        k = 0.5 * (1.0 + theta * theta / 6.0)
        return np.array([k * wx, k * wy, k * wz])
    if math.pi - theta > 1e-4:
        k = theta / (2.0 * math.sin(theta))
        return np.array([k * wx, k * wy, k * wz])
    # Near pi: axis from the diagonal of (R + I) / 2 = n n^T, sign from the skew part.
    return np.asarray(Rotation.from_matrix(R).as_rotvec(), dtype=float)


def quat_wxyz_to_matrix(q: tuple[float, float, float, float] | Array) -> Array:
    """3x3 rotation of a (w, x, y, z) quaternion; the quaternion is normalised first."""
    w, x, y, z = (float(v) for v in q)
    return np.asarray(Rotation.from_quat([x, y, z, w]).as_matrix(), dtype=float)


def matrix_to_quat_wxyz(R: Array) -> Array:
    """(w, x, y, z) unit quaternion of a rotation matrix, with w >= 0."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def pose_error(T_target: Array, T: Array) -> Array:
    """6-vector (dp; dtheta) that moves T onto T_target to first order, both in the base frame.

    dp = p_target - p and dtheta = log(R_target R^T), matching a geometric Jacobian whose angular rows
    are the angular velocity in the base frame.
    """
    return np.concatenate((T_target[:3, 3] - T[:3, 3], rotation_log(T_target[:3, :3] @ T[:3, :3].T)))
