"""Serial kinematic chain of cabin8: frames by Craig's modified DH, numeric (numpy, batched) and symbolic.

The chain (paper eq. 10-12, Table 1)::

    T_base_tool = Trans(0, 0, d1) . Trans(x, y, 0) RotZ(gamma)            (frames 1 and 2)
                  . MDH(-90deg, 0,     theta3, 0.261)                        (frame 3)
                  . MDH(-90deg, 0.485, theta4, 0)                            (frame 4)
                  . MDH(-90deg, 0.050, -90deg, d5)                           (frame 5)
                  . MDH(-90deg, 0,     theta6, 0.010)                        (frame 6, the tool)

with MDH(alpha, a, theta, d) = RotX(alpha) TransX(a) RotZ(theta) TransZ(d). The link parameters come from
the description file, so this module only knows the structure (rail, planar pose, four MDH links whose
variables are the joints theta3, theta4, d5, theta6 in that order).

Two independent implementations live here on purpose: :func:`frames_batch` (numpy, vectorised over N
configurations) and :func:`frames_sx` (CasADi, for automatic differentiation). The tests compare them.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from planner.core.description import MDHSpec
from planner.core.types import Array

#: Index of each joint in q = (d1, x, y, gamma, theta3, theta4, d5, theta6).
D1, X, Y, GAMMA, THETA3, THETA4, D5, THETA6 = range(8)
#: For each MDH link, the joint index of its variable and whether it replaces theta (True) or d (False).
_LINK_VARIABLES: tuple[tuple[int, bool], ...] = ((THETA3, True), (THETA4, True), (D5, False), (THETA6, True))
#: Public name of the same table (the collision kernels evaluate the chain in closed form).
LINK_VARIABLES = _LINK_VARIABLES


def _link_values(links: Sequence[MDHSpec], i: int, q_var: Array) -> tuple[Array | float, Array | float]:
    link = links[i]
    _, revolute = _LINK_VARIABLES[i]
    theta = q_var + link.theta if revolute else link.theta
    d = link.d if revolute else q_var + link.d
    return theta, d


def mdh_batch(alpha: float, a: float, theta: Array | float, d: Array | float, n: int) -> Array:
    """Modified-DH transforms, shape (n, 4, 4): RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""
    theta = np.broadcast_to(np.asarray(theta, dtype=float), (n,))
    d = np.broadcast_to(np.asarray(d, dtype=float), (n,))
    ct, st = np.cos(theta), np.sin(theta)
    ca_, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros((n, 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 0, 3] = ct, -st, a
    T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st * ca_, ct * ca_, -sa, -sa * d
    T[:, 2, 0], T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = st * sa, ct * sa, ca_, ca_ * d
    T[:, 3, 3] = 1.0
    return T


def platform_batch(q: Array) -> Array:
    """T_base_platform (frame 2) for (N, 8) joint vectors, shape (N, 4, 4)."""
    n = q.shape[0]
    c, s = np.cos(q[:, GAMMA]), np.sin(q[:, GAMMA])
    T = np.zeros((n, 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 0, 3] = c, -s, q[:, X]
    T[:, 1, 0], T[:, 1, 1], T[:, 1, 3] = s, c, q[:, Y]
    T[:, 2, 2], T[:, 2, 3] = 1.0, q[:, D1]
    T[:, 3, 3] = 1.0
    return T


def frames_batch(links: Sequence[MDHSpec], q: Array) -> Array:
    """Every frame of the chain for N configurations.

    Args:
        links: The four MDH links of the description.
        q: (N, 8) joint vectors (d1, x, y, gamma, theta3, theta4, d5, theta6) [m, rad].

    Returns:
        (N, 7, 4, 4): T_base_i for i = 0 (base, identity), 1 (carriage), 2 (platform), 3..6 (tool).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    out = np.empty((n, 7, 4, 4))
    out[:, 0] = np.eye(4)
    out[:, 1] = np.eye(4)
    out[:, 1, 2, 3] = q[:, D1]
    out[:, 2] = platform_batch(q)
    for i, link in enumerate(links):
        j, _ = _LINK_VARIABLES[i]
        theta, d = _link_values(links, i, q[:, j])
        out[:, 3 + i] = out[:, 2 + i] @ mdh_batch(link.alpha, link.a, theta, d, n)
    return out


def tool_batch(links: Sequence[MDHSpec], q: Array) -> Array:
    """T_base_tool for (N, 8) joint vectors, shape (N, 4, 4); the fast route (no 4x4 products).

    The rotation is carried as three column arrays and each MDH link updates them in place of a matrix
    product: with M = RotX(alpha) RotZ(theta),
    ``r0' = c r0 + ca s r1 + sa s r2``, ``r1' = -s r0 + ca c r1 + sa c r2``, ``r2' = -sa r1 + ca r2`` and
    ``p' = p + a r0 + d r2'``, all elementwise on (3, N) arrays. :func:`frames_batch` (matrix products)
    is the independent check.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    cg, sg = np.cos(q[:, GAMMA]), np.sin(q[:, GAMMA])
    zeros, ones = np.zeros(n), np.ones(n)
    r0 = np.stack([cg, sg, zeros])  # (3, N) columns of the platform rotation
    r1 = np.stack([-sg, cg, zeros])
    r2 = np.stack([zeros, zeros, ones])
    p = np.stack([q[:, X], q[:, Y], q[:, D1]])
    for i, link in enumerate(links):
        j, _ = _LINK_VARIABLES[i]
        theta, d = _link_values(links, i, q[:, j])
        c, s = np.cos(theta), np.sin(theta)
        ca_, sa = float(np.cos(link.alpha)), float(np.sin(link.alpha))
        p = p + link.a * r0  # TransX(a) after RotX(alpha): along the unchanged x column
        u1, u2 = ca_ * r1 + sa * r2, -sa * r1 + ca_ * r2
        r0, r1, r2 = c * r0 + s * u1, c * u1 - s * r0, u2
        p = p + d * u2
    T = np.zeros((n, 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = r0.T, r1.T, r2.T, p.T
    T[:, 3, 3] = 1.0
    return T


def mdh_sx(alpha: float, a: float, theta: ca.SX | float, d: ca.SX | float) -> ca.SX:
    """Symbolic modified-DH transform RotX(alpha) TransX(a) RotZ(theta) TransZ(d) (4x4 SX)."""
    ct, st = ca.cos(theta), ca.sin(theta)
    cal, sal = float(np.cos(alpha)), float(np.sin(alpha))
    return ca.vertcat(
        ca.horzcat(ct, -st, 0, a),
        ca.horzcat(st * cal, ct * cal, -sal, -sal * d),
        ca.horzcat(st * sal, ct * sal, cal, cal * d),
        ca.horzcat(0, 0, 0, 1),
    )


def frames_sx(links: Sequence[MDHSpec], q: ca.SX) -> list[ca.SX]:
    """Symbolic frames T_base_i, i = 0..6, for an 8x1 SX joint vector (same layout as frames_batch)."""
    eye = ca.SX.eye(4)
    carriage = ca.vertcat(
        ca.horzcat(1, 0, 0, 0), ca.horzcat(0, 1, 0, 0), ca.horzcat(0, 0, 1, q[D1]), ca.horzcat(0, 0, 0, 1)
    )
    c, s = ca.cos(q[GAMMA]), ca.sin(q[GAMMA])
    platform = ca.vertcat(
        ca.horzcat(c, -s, 0, q[X]),
        ca.horzcat(s, c, 0, q[Y]),
        ca.horzcat(0, 0, 1, q[D1]),
        ca.horzcat(0, 0, 0, 1),
    )
    frames = [eye, carriage, platform]
    for i, link in enumerate(links):
        j, revolute = _LINK_VARIABLES[i]
        theta = q[j] + link.theta if revolute else link.theta
        d = link.d if revolute else q[j] + link.d
        frames.append(ca.mtimes(frames[-1], mdh_sx(link.alpha, link.a, theta, d)))
    return frames


def geometric_jacobian_sx(T: ca.SX, q: ca.SX) -> ca.SX:
    """6xn geometric Jacobian of frame T(q): rows (v of the origin; omega), both in the base frame.

    v = dp/dq, and column i of the angular part is vee((dR/dq_i) R^T), exact for any joint type.
    """
    p = T[0:3, 3]
    R = T[0:3, 0:3]
    Jv = ca.jacobian(p, q)
    cols = []
    for i in range(q.shape[0]):
        dR = ca.jacobian(ca.vec(R), q[i])
        W = ca.mtimes(ca.reshape(dR, 3, 3), R.T)
        cols.append(
            ca.vertcat(0.5 * (W[2, 1] - W[1, 2]), 0.5 * (W[0, 2] - W[2, 0]), 0.5 * (W[1, 0] - W[0, 1]))
        )
    return ca.vertcat(Jv, ca.horzcat(*cols))
