"""Beam and joint primitives of the stiffness model (paper section 4, eq. 54-70), batched over (..., 6, 6).

Compliances map a wrench (force [N], moment [N m]) at a point to the small twist there (translation [m],
rotation [rad]); every function works on stacks of them (leading axes) in base coordinates. The model that
assembles them for cabin8 is :mod:`planner.dynamics.stiffness`.

* A straight Euler-Bernoulli beam of rectangular section b x h: its tip compliance in the beam frame
  (x along the beam) is the cantilever matrix of eq. (54) (:func:`beam_compliance`, section constants
  :func:`section_properties`; the torsion constant ``I_p = b h^3 (1/3 - 0.21 h/b)`` is used as printed,
  b >= h).
* **Serial composition** (eq. 69-74): an element j with compliance C_j at its tip frame (rotation R_j,
  tip point t_j) adds ``J_j C_j J_j^T`` to the compliance at a reference point P, with
  ``J_j = [[R, -S(P - t) R], [0, R]]`` (eq. 70, S the skew operator of eq. 64). A drive spring of
  stiffness k along the unit twist s (at P) adds ``s s^T / k``.
* **Passive joints** (the paper's branches contain pins but eq. 62-68 leave them implicit): a branch with
  elastic compliance C (at P) and passive joint twists J_p (6 x k, at P) deflects by X = C W + J_p lambda
  with J_p^T W = 0 (a pin transmits no moment about its axis), so its stiffness is
  ``K = N (N^T C N)^-1 N^T`` with N an orthonormal basis of the wrenches orthogonal to J_p. It is singular
  along J_p, symmetric and positive semi-definite by construction.
* **Parallel assembly** (eq. 62-68): branches meeting at a point add their stiffnesses expressed there,
  ``K = sum_i J_Fi K_i J_i^-1`` with J_Fi = J_i^-T; we express every branch at the meeting point in base
  coordinates directly, so the sum is plain.

eq. (63) and (66) write ``J_i`` with ``S(r) R`` in the upper-right block and call ``J_Fi = J_i^-T`` a force
map with the block in the lower-left: consistent with each other only as twist/wrench maps of opposite
direction. We use the twist map ``[[I, -S(d)], [0, I]]`` (displacement at a point moved by d,
:func:`twist_transfer`) and its transpose for wrenches, as eq. (70) does.

A small twist displaces a pose (:func:`deflected_pose`): the translation adds to the origin, the rotation
vector rotates the frame, both in the base frame.
"""

from __future__ import annotations

import numpy as np

from planner.core.description import Section
from planner.core.types import Array


def cross(a: Array, b: Array) -> Array:
    """Cross product along the last axis (..., 3), broadcasting; cheaper than ``np.cross`` on small N."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def skew(r: Array) -> Array:
    """Skew operator S(r) of eq. (64): S(r) v = r x v; r (..., 3) -> (..., 3, 3)."""
    r = np.asarray(r, dtype=float)
    S = np.zeros((*r.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2] = -r[..., 2], r[..., 1]
    S[..., 1, 0], S[..., 1, 2] = r[..., 2], -r[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -r[..., 1], r[..., 0]
    return S


def twist_transfer(d: Array) -> Array:
    """Map ``[[I, -S(d)], [0, I]]`` (..., 6, 6) of a small rigid displacement from a point a to a + d.

    A rigid twist (translation t of a, rotation phi) moves a + d by ``t + phi x d``. The transpose moves a
    wrench (force f at a + d, moment m) to a: ``(f, m + d x f)``.
    """
    d = np.asarray(d, dtype=float)
    T = np.zeros((*d.shape[:-1], 6, 6))
    T[..., :3, :3] = np.eye(3)
    T[..., 3:, 3:] = np.eye(3)
    T[..., :3, 3:] = -skew(d)
    return T


def section_properties(section: Section) -> tuple[float, float, float, float]:
    """(A, I_y, I_z, I_p) of a rectangle b x h (paper eq. 54): A = bh, I_y = b^3 h/12, I_z = b h^3/12.

    I_p is the torsion constant as printed, ``b h^3 (1/3 - 0.21 h/b)`` (b >= h).
    """
    b, h = section.b, section.h
    return b * h, b**3 * h / 12.0, b * h**3 / 12.0, b * h**3 * (1.0 / 3.0 - 0.21 * h / b)


def beam_compliance(length_m: Array | float, section: Section, E_Pa: float, G_Pa: float) -> Array:
    """Cantilever tip compliance of a rectangular beam in its own frame (paper eq. 54).

    The beam is clamped at its base and runs along its local x axis; the load (F_x, F_y, F_z, M_x, M_y,
    M_z) acts at the free end and the result maps it to the tip twist (dx, dy, dz, rx, ry, rz):
    axial ``L/EA``, bending ``L^3/3EI`` with the coupling ``+-L^2/2EI`` and ``L/EI``, torsion ``L/GI_p``.

    Args:
        length_m: Beam length(s) L [m], scalar or shape (N,).
        section: The cross-section (b along local z, h along local y).
        E_Pa: Young's modulus [Pa].
        G_Pa: Shear modulus [Pa].

    Returns:
        Compliance (6, 6) or (N, 6, 6) [m/N, rad/N, rad/(N m)].
    """
    L = np.asarray(length_m, dtype=float)
    A, Iy, Iz, Ip = section_properties(section)
    C = np.zeros((*L.shape, 6, 6))
    C[..., 0, 0] = L / (E_Pa * A)
    C[..., 1, 1] = L**3 / (3.0 * E_Pa * Iz)
    C[..., 1, 5] = C[..., 5, 1] = L**2 / (2.0 * E_Pa * Iz)
    C[..., 2, 2] = L**3 / (3.0 * E_Pa * Iy)
    C[..., 2, 4] = C[..., 4, 2] = -(L**2) / (2.0 * E_Pa * Iy)
    C[..., 3, 3] = L / (G_Pa * Ip)
    C[..., 4, 4] = L / (E_Pa * Iy)
    C[..., 5, 5] = L / (E_Pa * Iz)
    return C


def beam_frame(p_base: Array, p_tip: Array, z_ref: Array) -> tuple[Array, Array]:
    """Rotation (N, 3, 3) of a beam frame (x from base to tip, z from z_ref made orthogonal) and lengths."""
    axis = p_tip - p_base
    length = np.linalg.norm(axis, axis=-1)
    x = axis / length[..., None]
    z = z_ref - np.sum(z_ref * x, axis=-1, keepdims=True) * x
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = cross(z, x)
    return np.stack([x, y, z], axis=-1), length


def rotate6(R: Array) -> Array:
    """blockdiag(R, R), (N, 6, 6): a local twist or wrench expressed in the base frame."""
    B = np.zeros((*R.shape[:-2], 6, 6))
    B[..., :3, :3] = R
    B[..., 3:, 3:] = R
    return B


def map_compliance(C_local: Array, R: Array, tip: Array, point: Array) -> Array:
    """Compliance of an element (local C at its tip frame R, tip) seen at ``point``, base axes (eq. 70)."""
    J = twist_transfer(point - tip) @ rotate6(R)
    return J @ C_local @ np.swapaxes(J, -1, -2)


def spring_compliance(s: Array, k: float) -> Array:
    """Compliance ``s s^T / k`` (N, 6, 6) of a spring of stiffness k along the unit twist s (N, 6)."""
    return s[..., :, None] * s[..., None, :] / k


def revolute_twist(axis: Array, through: Array, point: Array) -> Array:
    """Unit twist (N, 6) at ``point`` of a rotation about ``axis`` through ``through``.

    It is ``(axis x (point - through), axis)``.
    """
    axis = np.broadcast_to(axis, np.shape(point))
    return np.concatenate([cross(axis, point - through), axis], axis=-1)


def prismatic_twist(axis: Array) -> Array:
    """Unit twist (N, 6) of a translation along ``axis`` (N, 3)."""
    return np.concatenate([axis, np.zeros_like(axis)], axis=-1)


def branch_stiffness(C: Array, J_passive: Array | None = None) -> Array:
    """Stiffness (N, 6, 6) of a branch: elastic compliance C (N, 6, 6), passive joint twists (N, 6, k).

    Without passive joints K = C^-1. With them, K = N (N^T C N)^-1 N^T where the columns of N span the
    wrenches that do no work on the passive twists (J_p^T W = 0): the pins carry no load along themselves.
    The compliance is scaled to order one first (K is homogeneous of degree -1 in C).
    """
    scale = np.max(np.abs(C), axis=(-2, -1), keepdims=True)
    Cs = C / scale
    if J_passive is None or J_passive.shape[-1] == 0:
        K = np.linalg.inv(Cs)
    else:
        k = J_passive.shape[-1]
        U, _, _ = np.linalg.svd(J_passive, full_matrices=True)
        N = U[..., :, k:]
        Nt = np.swapaxes(N, -1, -2)
        K = N @ np.linalg.inv(Nt @ Cs @ N) @ Nt
    K = K / scale
    return 0.5 * (K + np.swapaxes(K, -1, -2))


def wrench_at(force: Array, at: Array, point: Array) -> Array:
    """Wrench (N, 6) at ``point`` of forces (N, 3) acting at ``at`` (N, 3): (f, (at - point) x f)."""
    return np.concatenate([force, cross(at - point, force)], axis=-1)


def deflected_pose(T: Array, twist: Array) -> Array:
    """The pose T (4x4) displaced by a small twist (translation, rotation vector) in the base frame."""
    from scipy.spatial.transform import Rotation

    out = np.array(T, dtype=float, copy=True)
    out[:3, 3] += twist[:3]
    out[:3, :3] = Rotation.from_rotvec(twist[3:]).as_matrix() @ out[:3, :3]
    return out
