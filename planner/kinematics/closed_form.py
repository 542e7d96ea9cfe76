"""Closed-form inverse kinematics of cabin8's redundant family of solutions.

For a tool pose T = (R, p), write the chain as ``T = Trans(0,0,d1) Trans(x,y,0) RotZ(gamma) T_26`` where
T_26(theta3, theta4, d5, theta6) is the serial RRPR part. Two facts make the inverse explicit:

* the rotation of T_26 does not depend on d5, and its third column is
  ``a = (c3 c4, -s4, -s3 c4)`` (paper eq. 13 with gamma = 0). With R_26 = RotZ(gamma)^T R:
  ``theta4 = -asin(a_y)`` (|theta4| < 90 deg on this robot, so c4 > 0 and the branch is unique),
  ``theta3 = atan2(-a_z, a_x)``, and theta6 from R_56 = R_25^T R_26 = RotX(-90 deg) RotZ(theta6);
* the position of T_26 is affine in d5: ``p_26 = p_0(theta3, theta4) + d5 z_5`` (the prismatic axis),
  and (x, y, d1) then follow from ``p = (x, y, d1) + RotZ(gamma) p_26``.

So every solution is fixed by the two redundant parameters (gamma, d5): the family is
q(gamma, d5), evaluated here for whole grids at once (numpy). The QP-based IK uses it to choose a good
region of the self-motion manifold (limit and singularity margins) before refining.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planner.core.description import MDHSpec
from planner.core.types import Array
from planner.kinematics.chain import mdh_batch


def redundant_family(links: Sequence[MDHSpec], T: Array, gamma: Array, d5: Array) -> Array:
    """Joint vectors reaching tool pose T for each (gamma, d5) pair.

    Args:
        links: The four MDH links (theta3, theta4, d5, theta6).
        T: Tool pose in the base frame (4x4), or one pose per pair (K, 4, 4).
        gamma: Platform angles [rad], shape (K,).
        d5: Slide positions [m], shape (K,).

    Returns:
        (K, 8) joint vectors (d1, x, y, gamma, theta3, theta4, d5, theta6); limits are not checked.
    """
    gamma = np.asarray(gamma, dtype=float).reshape(-1)
    d5 = np.asarray(d5, dtype=float).reshape(-1)
    k = gamma.size
    cg, sg = np.cos(gamma), np.sin(gamma)
    Rz = np.zeros((k, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = cg, -sg, sg, cg, 1.0
    Tb = np.asarray(T, dtype=float)
    Tb = Tb if Tb.ndim == 3 else Tb[None]  # (K or 1, 4, 4)
    R26 = np.swapaxes(Rz, 1, 2) @ Tb[:, :3, :3]
    a = R26[:, :, 2]
    theta4 = -np.arcsin(np.clip(a[:, 1], -1.0, 1.0)) - links[1].theta
    theta3 = np.arctan2(-a[:, 2], a[:, 0]) - links[0].theta
    # Rotation and origin of frame 5 for d5 = 0 (the slide's own offset enters through links[2].d).
    T25 = (
        mdh_batch(links[0].alpha, links[0].a, theta3 + links[0].theta, links[0].d, k)
        @ mdh_batch(links[1].alpha, links[1].a, theta4 + links[1].theta, links[1].d, k)
        @ mdh_batch(links[2].alpha, links[2].a, links[2].theta, links[2].d, k)
    )
    R25 = T25[:, :3, :3]
    R56 = np.swapaxes(R25, 1, 2) @ R26
    # R56 = RotX(alpha4) RotZ(theta6): first row (c6, -s6, 0) for alpha4 = -90 deg.
    theta6 = np.arctan2(-R56[:, 0, 1], R56[:, 0, 0]) - links[3].theta
    T56 = mdh_batch(links[3].alpha, links[3].a, 0.0, links[3].d, k)
    p26 = T25[:, :3, 3] + d5[:, None] * R25[:, :, 2] + np.einsum("kij,kj->ki", R25, T56[:, :3, 3])
    p_world = np.einsum("kij,kj->ki", Rz, p26)
    q = np.empty((k, 8))
    q[:, 0] = Tb[:, 2, 3] - p_world[:, 2]
    q[:, 1] = Tb[:, 0, 3] - p_world[:, 0]
    q[:, 2] = Tb[:, 1, 3] - p_world[:, 1]
    q[:, 3] = gamma
    q[:, 4] = theta3
    q[:, 5] = theta4
    q[:, 6] = d5
    q[:, 7] = np.arctan2(np.sin(theta6), np.cos(theta6))
    return q
