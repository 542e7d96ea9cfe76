"""Small rotation helpers for the hot loops (quaternion conversion at the edges uses scipy)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]


def rotation_log(R: Array) -> Array:
    """Rotation vector (axis * angle [rad], angle in [0, pi]) of a 3x3 rotation matrix.

    Accurate across the whole range, including angles near 0 (series) and near pi (from the symmetric
    part), which the textbook ``acos`` formula is not.
    """
    cos_t = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    cos_t = min(1.0, max(-1.0, cos_t))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin_t = 0.5 * float(np.linalg.norm(w))
    theta = float(np.arctan2(sin_t, cos_t))
    if theta < 1e-6:
        return 0.5 * (1.0 + theta**2 / 6.0) * w
    if np.pi - theta > 1e-4:
        return theta / (2.0 * np.sin(theta)) * w
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
    err = np.empty(6)
    err[:3] = T_target[:3, 3] - T[:3, 3]
    err[3:] = rotation_log(T_target[:3, :3] @ T[:3, :3].T)
    return err
