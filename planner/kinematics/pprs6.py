"""Kinematics of the 2PPRS-RPRS 6-DOF parallel platform ``pprs6`` (pure numpy, vectorised).

Paper: Zhang et al., "Kinematics study of six DOF parallel mechanism with three branches" (2020), in
../shared/papers/2pprs-rprs-parallel-mechanism.txt (OCR). Every length is in [m], every angle in [rad].

**Frames.** Fixed frame O-XYZ at the centre of the three supports, Z up. Support i points along
``u_i = (cos a_i, sin a_i, 0)`` with ``a = (0, 120, 240) deg`` (u1 along +X); ``v_i = z x u_i`` is the
horizontal direction normal to O B_i. The moving frame O1-X1Y1Z1 sits at the centre of the platform
triangle C1C2C3 (circumradius r), X1 towards C1, so ``c_i = r u_i`` in the platform frame (paper eq. 7).
The pose is ``x = (X, Y, Z, phi, theta, psi)`` with ``R = RotZ(phi) RotY(theta) RotX(psi)`` (eq. 5) and
``C_i = p + R c_i`` (eq. 6).

**Chains.** Drives ``q = (w1, w2, beta, s1, s2, s3)``.

* Chains 1, 2 (PPRS): the first slider B_i runs along O B_i, ``B_i = w_i u_i``; the second prismatic is
  vertical, ``D_i = w_i u_i + s_i z``; the revolute at D_i is parallel to u_i, so the link D_i C_i
  (length L_i) stays in the plane ``C . u_i = w_i`` (paper eq. 8, ``X = w1``). Closed form::

      w_i = C_i . u_i,        s_i = C_i . z - sqrt(L_i^2 - (C_i . v_i)^2)

* Chain 3 (RPRS): the revolute at the fixed point ``B_3 = R u_3`` turns about v_3 and tilts the chain
  plane (spanned by v_3 and ``d(beta) = -cos(beta) u_3 + sin(beta) z``) by beta against the base plane
  (eq. 9: the angle between B3D3 and B3O is beta); the prismatic s_3 runs along d, ``D_3 = B_3 + s_3 d``
  (eq. 11); the revolute at D_3 is normal to the chain plane (``n = sin(beta) u_3 + cos(beta) z``), so
  D_3 C_3 (length L_3) stays in it. With ``rho = R - C_3 . u_3`` and ``h = C_3 . z``::

      beta = atan2(h, rho),   s_3 = sqrt(rho^2 + h^2) - sqrt(L_3^2 - (C_3 . v_3)^2)

**Where we read the paper differently, and why.**

* Eq. (10) places the sliders at ``R - w_i`` while eq. (8) says the chain plane is ``X = w_1``; we read
  ``B_i = w_i u_i`` (w_i is the slider's distance from O), the only reading under which the platform
  (r = 160 mm) is centred over the supports for w_i in the Table 1 range [80, 180] mm.
* Eq. (10) puts B_3 at 210 deg (``(-sqrt3/2 R, -R/2)``) while the text says the supports are 120 deg
  apart and C_3 is at 240 deg (eq. 7); we put B_3 at 240 deg. (The paper's "B_3 axis at 30 deg to Y" is
  the 210 deg placement; it explains part of the workspace difference, see the README.)
* Eq. (13) (w_1, w_2, beta as *linear* functions of the pose) is garbled beyond repair (beta is an angle);
  eq. (14) has s_3 on both sides and the sign of the square root is ``+`` for s_1, i.e. the link would
  hang *below* D_i and the platform would sit below the top of the columns (Z < s_max, reaching below
  the base for s near its lower limit). We take the link pointing up from D_i to C_i (the platform above
  the columns, Fig. 1) and solve eq. (12) for the smaller root.
* Table 1's link lengths l, n, m are per chain (l = 100 mm for chain 1, n = m = 120 mm for chains 2, 3);
  eq. (12) writes m for all three.

**Closure equations** Phi(q, x) = 0, one per drive, in [m] (no square roots: they hold on every assembly
mode; the forward kinematics solves their working-branch form ``IK(x) - q = 0`` and then checks them)::

    Phi_w_i = C_i . u_i - w_i                                   (i = 1, 2)
    Phi_beta = (C_3 - B_3) . n(beta)
    Phi_s_i = ((C_i . v_i)^2 + (C_i . z - s_i)^2 - L_i^2) / (2 L_i)   (i = 1, 2)
    Phi_s_3 = (|C_3 - D_3(beta, s_3)|^2 - L_3^2) / (2 L_3)

The drive Jacobian ``J = dq/dx`` (6x6, pose rates as Euler-angle rates) is analytic; the screw
(twist) system of every chain gives the loop-closure Jacobian whose rank fixes the mobility.

**Singularity (not in the paper).** With the platform level and unyawed, C_i - p is parallel to u_i, so the
constraint forces of the chain-1/2 slider planes (along u_1, u_2 through C_1, C_2) and, at beta = 90 deg,
of the chain-3 plane (along u_3 through C_3) are three coplanar lines through O1: J is singular there (type
II), and the whole level, unyawed workspace is badly conditioned. A yaw of a few tenths of a radian cures it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from planner.core.exceptions import ForwardKinematicsFailed
from planner.core.types import Array, BoolArray

#: Drive order of every drive vector.
DRIVES = ("w1", "w2", "beta", "s1", "s2", "s3")
#: Pose coordinate order of every pose vector.
POSE = ("x", "y", "z", "phi", "theta", "psi")
_Z = np.array([0.0, 0.0, 1.0])

_JOINT_DOF: dict[str, int] = {"P": 1, "R": 1, "S": 3}


@dataclass(frozen=True)
class Pprs6Geometry:
    """Geometry of the mechanism (immutable).

    Attributes:
        r: Circumradius of the platform triangle C1C2C3 [m].
        R: Distance O B_3 of the chain-3 revolute (and length of the slider guides) [m].
        L: Link lengths D_i C_i of chains 1, 2, 3, shape (3,) [m].
        support_angles: Directions a_i of the supports O B_i in the base plane, shape (3,) [rad].
    """

    r: float
    R: float
    L: tuple[float, float, float]
    support_angles: tuple[float, float, float] = (0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0)
    u: Array = field(init=False, repr=False)
    v: Array = field(init=False, repr=False)
    c_platform: Array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        a = np.asarray(self.support_angles, dtype=float)
        u = np.column_stack([np.cos(a), np.sin(a), np.zeros(3)])
        v = np.column_stack([-np.sin(a), np.cos(a), np.zeros(3)])
        c = self.r * u
        for arr in (u, v, c):
            arr.setflags(write=False)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "v", v)
        object.__setattr__(self, "c_platform", c)

    @property
    def B3(self) -> Array:
        """Centre of the chain-3 revolute in the fixed frame, shape (3,) [m]."""
        return self.R * self.u[2]


# ---------------------------------------------------------------------------------------------- rotations
def rotation(angles: Array) -> Array:
    """R = RotZ(phi) RotY(theta) RotX(psi) (paper eq. 5) for angles (N, 3) -> (N, 3, 3)."""
    return _rotation_and_derivatives(np.atleast_2d(angles))[0]


def _rotation_and_derivatives(angles: Array) -> tuple[Array, Array, Array, Array]:
    """R and its partial derivatives w.r.t. phi, theta, psi, each (N, 3, 3)."""
    phi, theta, psi = angles[:, 0], angles[:, 1], angles[:, 2]
    Z, Y, X = _axis_rotation(2, phi), _axis_rotation(1, theta), _axis_rotation(0, psi)
    R = Z @ Y @ X
    dZ, dY, dX = _axis_rotation(2, phi, True), _axis_rotation(1, theta, True), _axis_rotation(0, psi, True)
    return R, dZ @ Y @ X, Z @ dY @ X, Z @ Y @ dX


def _axis_rotation(axis: int, t: Array, derivative: bool = False) -> Array:
    """Rotation about the base axis ``axis`` (0 x, 1 y, 2 z) by the angles t (N,) [rad], (N, 3, 3).

    In the plane (i, j) = (axis + 1, axis + 2) mod 3: ``R[i, i] = R[j, j] = cos t``,
    ``R[j, i] = -R[i, j] = sin t`` and ``R[axis, axis] = 1``. With ``derivative`` it is dR/dt: the same
    pattern with (cos, sin) replaced by their derivatives (-sin, cos), and ``R[axis, axis] = 0``.
    """
    i, j = (axis + 1) % 3, (axis + 2) % 3
    c, s = np.cos(t), np.sin(t)
    if derivative:
        c, s = -s, c
    m = np.zeros((len(t), 3, 3))
    m[:, i, i], m[:, i, j], m[:, j, i], m[:, j, j] = c, -s, s, c
    if not derivative:
        m[:, axis, axis] = 1.0
    return m


class PlatformPoints(NamedTuple):
    """Sphere centres C_i in the fixed frame, (N, 3, 3) [sample, chain, xyz], and dC_i/dx (N, 3, 3, 6)."""

    C: Array
    dC: Array


def platform_points(geom: Pprs6Geometry, pose: Array) -> PlatformPoints:
    """C_i = p + R c_i (paper eq. 6-7) and their derivatives w.r.t. the pose, for poses (N, 6)."""
    pose = np.atleast_2d(np.asarray(pose, dtype=float))
    R, dphi, dtheta, dpsi = _rotation_and_derivatives(pose[:, 3:6])
    c = geom.c_platform  # (3 chains, 3)
    C = pose[:, None, :3] + np.einsum("nab,ib->nia", R, c)
    dC = np.zeros((pose.shape[0], 3, 3, 6))
    dC[:, :, :, 0:3] = np.eye(3)
    for k, dR in enumerate((dphi, dtheta, dpsi)):
        dC[:, :, :, 3 + k] = np.einsum("nab,ib->nia", dR, c)
    return PlatformPoints(C, dC)


# ---------------------------------------------------------------------------------------------- inverse
class InverseResult(NamedTuple):
    """Closed-form inverse kinematics of N poses.

    Attributes:
        drives: (N, 6) drive positions (NaN where a chain cannot close).
        reachable: (N, 3) bool, chain i can be assembled (square roots real, chain-3 plane defined).
        dq_dC: (N, 6, 3) gradient of each drive w.r.t. the sphere centre of its chain.
    """

    drives: Array
    reachable: BoolArray
    dq_dC: Array


#: Chain of each drive (w1, w2, beta, s1, s2, s3).
DRIVE_CHAIN = (0, 1, 2, 0, 1, 2)


def inverse_from_points(geom: Pprs6Geometry, C: Array) -> InverseResult:
    """Drives from the sphere centres C (N, 3, 3); see the module docstring for the formulas."""
    n = C.shape[0]
    u, v = geom.u, geom.v
    q = np.full((n, 6), np.nan)
    grad = np.zeros((n, 6, 3))
    ok = np.zeros((n, 3), dtype=bool)
    for i in (0, 1):
        Ci = C[:, i]
        cv = Ci @ v[i]
        disc = geom.L[i] ** 2 - cv**2
        good = disc > 0.0
        root = np.sqrt(np.where(good, disc, 1.0))
        q[:, i] = Ci @ u[i]
        q[:, 3 + i] = np.where(good, Ci[:, 2] - root, np.nan)
        grad[:, i] = u[i]
        grad[:, 3 + i] = _Z + (cv / root)[:, None] * v[i]
        ok[:, i] = good
    C3 = C[:, 2]
    rho = geom.R - C3 @ u[2]
    h = C3[:, 2]
    b = C3 @ v[2]
    dist2 = rho**2 + h**2
    disc = geom.L[2] ** 2 - b**2
    good = (disc > 0.0) & (dist2 > 1e-18)
    dist = np.sqrt(np.where(good, dist2, 1.0))
    root = np.sqrt(np.where(good, disc, 1.0))
    q[:, 2] = np.where(good, np.arctan2(h, rho), np.nan)
    q[:, 5] = np.where(good, dist - root, np.nan)
    # d beta = (rho dh - h d rho) / dist^2 with d rho = -u3 . dC, dh = z . dC
    grad[:, 2] = (rho[:, None] * _Z + h[:, None] * u[2]) / np.where(good, dist2, 1.0)[:, None]
    grad[:, 5] = (-rho[:, None] * u[2] + h[:, None] * _Z) / dist[:, None] + (b / root)[:, None] * v[2]
    ok[:, 2] = good
    return InverseResult(q, ok, grad)


def inverse(geom: Pprs6Geometry, pose: Array) -> InverseResult:
    """Closed-form inverse kinematics, poses (N, 6) -> drives (N, 6) (order w1, w2, beta, s1, s2, s3)."""
    return inverse_from_points(geom, platform_points(geom, pose).C)


def drive_jacobian(geom: Pprs6Geometry, pose: Array) -> Array:
    """Analytic drive Jacobian J = dq/dx, (N, 6) poses -> (N, 6, 6) [drive, pose coordinate].

    Row k is the gradient of drive k w.r.t. its chain's sphere centre times dC/dx; pose rates are
    (X', Y', Z') [m/s] and the Euler-angle rates (phi', theta', psi') [rad/s]. NaN rows where a chain
    cannot close.
    """
    pts = platform_points(geom, pose)
    inv = inverse_from_points(geom, pts.C)
    J = np.empty((pts.C.shape[0], 6, 6))
    for k, i in enumerate(DRIVE_CHAIN):
        J[:, k] = np.einsum("na,nax->nx", inv.dq_dC[:, k], pts.dC[:, i])
    J[~inv.reachable[:, list(DRIVE_CHAIN)]] = np.nan
    return J


def scaled_condition_number(geom: Pprs6Geometry, J: Array) -> Array:
    """Condition number of the dimensionally homogenised drive Jacobian, (N, 6, 6) -> (N,).

    Rotations are scaled by the platform radius r (rad -> m of motion at C_i) and beta by R (rad -> m of
    motion at the chain-3 slider guide's end), so that every entry is dimensionless; large values flag
    the neighbourhood of singularities (a chain's link normal to its plane of motion, or the platform
    unable to resist a wrench).
    """
    Js = J.copy()
    Js[:, :, 3:] /= geom.r
    Js[:, 2, :] *= geom.R
    out = np.full(J.shape[0], np.inf)
    good = np.all(np.isfinite(Js), axis=(1, 2))
    if good.any():
        out[good] = np.linalg.cond(Js[good])
    return out


# ---------------------------------------------------------------------------------------------- closure
def closure(geom: Pprs6Geometry, drives: Array, pose: Array) -> tuple[Array, Array, Array]:
    """Closure residuals Phi(q, x) (N, 6) [m] and their Jacobians dPhi/dx, dPhi/dq (N, 6, 6).

    Residual k belongs to drive k (w1, w2, beta, s1, s2, s3); see the module docstring.
    """
    q = np.atleast_2d(np.asarray(drives, dtype=float))
    pts = platform_points(geom, pose)
    C, dC = pts.C, pts.dC
    n = C.shape[0]
    u, v = geom.u, geom.v
    phi = np.empty((n, 6))
    dphi_dC = np.zeros((n, 6, 3))
    dphi_dq = np.zeros((n, 6, 6))
    for i in (0, 1):
        Ci = C[:, i]
        L = geom.L[i]
        phi[:, i] = Ci @ u[i] - q[:, i]
        dphi_dC[:, i] = u[i]
        dphi_dq[:, i, i] = -1.0
        cv = Ci @ v[i]
        dz = Ci[:, 2] - q[:, 3 + i]
        phi[:, 3 + i] = (cv**2 + dz**2 - L**2) / (2.0 * L)
        dphi_dC[:, 3 + i] = (cv[:, None] * v[i] + dz[:, None] * _Z) / L
        dphi_dq[:, 3 + i, 3 + i] = -dz / L
    beta, s3 = q[:, 2], q[:, 5]
    cb, sb = np.cos(beta)[:, None], np.sin(beta)[:, None]
    d = -cb * u[2] + sb * _Z
    nrm = sb * u[2] + cb * _Z
    rel = C[:, 2] - geom.B3
    phi[:, 2] = np.einsum("na,na->n", rel, nrm)
    dphi_dC[:, 2] = nrm
    dphi_dq[:, 2, 2] = -np.einsum("na,na->n", rel, d)  # dn/dbeta = -d
    L3 = geom.L[2]
    gap = rel - s3[:, None] * d  # C_3 - D_3
    phi[:, 5] = (np.einsum("na,na->n", gap, gap) - L3**2) / (2.0 * L3)
    dphi_dC[:, 5] = gap / L3
    dphi_dq[:, 5, 2] = -s3 * np.einsum("na,na->n", gap, nrm) / L3  # dd/dbeta = n
    dphi_dq[:, 5, 5] = -np.einsum("na,na->n", gap, d) / L3
    dphi_dx = np.empty((n, 6, 6))
    for k, i in enumerate(DRIVE_CHAIN):
        dphi_dx[:, k] = np.einsum("na,nax->nx", dphi_dC[:, k], dC[:, i])
    return phi, dphi_dx, dphi_dq


# ---------------------------------------------------------------------------------------------- forward
@dataclass(frozen=True)
class NewtonOptions:
    """Stopping rules of the Newton forward kinematics.

    Attributes:
        tol_m: Convergence when the drives are reproduced within this (beta scaled by R) [m].
        max_iterations: Newton iterations before giving up.
        branch_tol: A converged pose must also satisfy the closure equations Phi(q, x) within this [m].
        max_step_m: Largest Newton step (translation, and rotation times r) [m].
    """

    tol_m: float = 1e-12
    max_iterations: int = 60
    branch_tol: float = 1e-8
    max_step_m: float = 0.01


def forward(
    geom: Pprs6Geometry, drives: Array, guess: Array, options: NewtonOptions | None = None
) -> tuple[Array, Array, Array]:
    """Forward kinematics by damped Newton on the closure equations, vectorised over N samples.

    The closure equations are solved in their working-branch form ``g(x) - q = 0`` where ``g`` is the
    closed-form inverse (each row is one chain's closure solved for its drive, on the assembly mode of the
    module docstring); the Newton matrix is the analytic drive Jacobian ``J = dg/dx``, well conditioned
    wherever the mechanism is away from its singularities, whatever the current error. Steps that do not
    reduce the residual (or leave the domain where every chain closes) are halved. Residuals are compared
    with beta scaled by R (rad -> m).

    Args:
        geom: Mechanism geometry.
        drives: (N, 6) drive positions.
        guess: (N, 6) or (6,) initial poses (e.g. the home pose or a nearby known pose).
        options: Stopping rules.

    Returns:
        (poses (N, 6), converged (N,) bool, max scaled residual per sample (N,) [m]). Converged means the
        drives are reproduced within ``tol_m`` AND the closure residuals Phi(q, x) are below ``branch_tol``.
    """
    opt = options or NewtonOptions()
    q = np.atleast_2d(np.asarray(drives, dtype=float))
    x = np.broadcast_to(np.asarray(guess, dtype=float), q.shape).copy()
    scale = np.array([1.0, 1.0, geom.R, 1.0, 1.0, 1.0])
    weights = np.array([1.0, 1.0, 1.0, geom.r, geom.r, geom.r])

    def evaluate(qq: Array, xx: Array) -> tuple[Array, Array, Array]:
        r = inverse(geom, xx).drives - qq
        nrm = np.max(np.abs(r) * scale, axis=1)
        return r, np.where(np.isfinite(nrm), nrm, np.inf), drive_jacobian(geom, xx)

    res, norm, J = evaluate(q, x)
    active = np.isfinite(norm) & (norm > opt.tol_m)
    for _ in range(opt.max_iterations):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        Ja = J[idx]
        good = np.all(np.isfinite(Ja), axis=(1, 2)) & (np.abs(np.linalg.det(Ja)) > 1e-300)
        step = np.zeros((len(idx), 6))
        if good.any():
            step[good] = np.linalg.solve(Ja[good], res[idx][good][:, :, None])[:, :, 0]
        # Trust region: steps of at most max_step_m (rotations weighted by r) keep Newton on the solution
        # connected to its start instead of jumping to another assembly of the same drives.
        size = np.max(np.abs(step) * weights, axis=1)
        alpha = np.minimum(1.0, opt.max_step_m / np.maximum(size, 1e-300))
        done = ~good
        accepted = np.zeros(len(idx), dtype=bool)
        for _ in range(20):  # backtracking: accept the first step that reduces the residual
            trial = x[idx] - alpha[:, None] * step
            r_t, n_t, J_t = evaluate(q[idx], trial)
            better = (n_t < norm[idx]) & ~done
            sel = idx[better]
            x[sel], res[sel], J[sel], norm[sel] = trial[better], r_t[better], J_t[better], n_t[better]
            done |= better
            accepted |= better
            if done.all():
                break
            alpha[~done] *= 0.5
        active[idx[~accepted]] = False
        active &= norm > opt.tol_m
    phi = np.max(np.abs(closure(geom, q, x)[0]), axis=1)
    converged = (norm <= opt.tol_m) & np.isfinite(phi) & (phi <= opt.branch_tol)
    return x, converged, norm


def forward_or_raise(geom: Pprs6Geometry, drives: Array, guesses: list[Array]) -> Array:
    """Forward kinematics trying each guess in turn for the samples not yet converged.

    Raises:
        ForwardKinematicsFailed: some sample converged from no guess (no assembly in the working mode,
            or a guess too far away); details name the first such sample and its residual.
    """
    q = np.atleast_2d(np.asarray(drives, dtype=float))
    out = np.full(q.shape, np.nan)
    todo = np.ones(q.shape[0], dtype=bool)
    best = np.full(q.shape[0], np.inf)
    for g in guesses:
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            break
        gg = np.asarray(g, dtype=float)
        x, ok, norm = forward(geom, q[idx], gg[idx] if gg.ndim == 2 else gg)
        out[idx[ok]] = x[ok]
        todo[idx[ok]] = False
        best[idx] = np.minimum(best[idx], norm)
    if todo.any():
        i = int(np.flatnonzero(todo)[0])
        raise ForwardKinematicsFailed(
            "forward kinematics did not converge to the working assembly mode "
            f"(sample {i}: closure residual {best[i]:.3g} m after {len(guesses)} start(s))",
            index=i,
            residual_m=float(best[i]),
            drives=dict(zip(DRIVES, q[i].tolist(), strict=True)),
            condition="fk_not_converged",
        )
    return out


# ---------------------------------------------------------------------------------------------- mobility
def grubler(chains: list[list[str]]) -> dict[str, int]:
    """Modified Kutzbach-Grübler count (paper eq. 4) from the joint list of every chain.

    Each chain is a list of joint types ("P", "R" or "S") from the base to the platform; the bodies are
    the base, the platform, and one body between each pair of consecutive joints of a chain. No redundant
    constraints nor local freedoms (v = xi = 0).

    Returns:
        {"N": bodies including the base, "g": joints, "sum_f": joint freedoms, "F": mobility}.
    """
    n_bodies = 2 + sum(len(c) - 1 for c in chains)
    g = sum(len(c) for c in chains)
    sum_f = sum(_JOINT_DOF[j] for c in chains for j in c)
    return {"N": n_bodies, "g": g, "sum_f": sum_f, "F": 6 * (n_bodies - g - 1) + sum_f}


def _rev(axis: Array, point: Array) -> Array:
    return np.concatenate([axis, np.cross(point, axis)])


def _pri(axis: Array) -> Array:
    return np.concatenate([np.zeros(3), axis])


def chain_twists(geom: Pprs6Geometry, drives: Array, pose: Array) -> list[Array]:
    """Unit joint twists (omega; v_O) of the three chains at one configuration, each (6, 6 joints).

    The order follows the joints from the base: chains 1, 2: P(u_i), P(z), R(u_i at D_i), S at C_i (three
    revolutes along X, Y, Z); chain 3: R(v_3 at B_3), P(d), R(n at D_3), S at C_3 (paper eq. 1 and 3).
    """
    q = np.asarray(drives, dtype=float)
    C = platform_points(geom, pose).C[0]
    u, v = geom.u, geom.v
    eye = np.eye(3)
    out = []
    for i in (0, 1):
        D = q[i] * u[i] + q[3 + i] * _Z
        cols = [_pri(u[i]), _pri(_Z), _rev(u[i], D)] + [_rev(eye[k], C[i]) for k in range(3)]
        out.append(np.column_stack(cols))
    beta, s3 = q[2], q[5]
    d = -np.cos(beta) * u[2] + np.sin(beta) * _Z
    nrm = np.sin(beta) * u[2] + np.cos(beta) * _Z
    D3 = geom.B3 + s3 * d
    cols = [_rev(v[2], geom.B3), _pri(d), _rev(nrm, D3)] + [_rev(eye[k], C[2]) for k in range(3)]
    out.append(np.column_stack(cols))
    return out


def loop_jacobian(geom: Pprs6Geometry, drives: Array, pose: Array) -> Array:
    """Constraint Jacobian of the closed loops, (18, 24): [blockdiag(T_1, T_2, T_3) | -[I; I; I]].

    Unknown rates: the 18 joint rates (6 per chain) and the platform twist (omega; v_O); the loop closes
    when every chain produces the platform twist. The mobility is ``24 - rank``.
    """
    twists = chain_twists(geom, drives, pose)
    A = np.zeros((18, 24))
    for i, T in enumerate(twists):
        A[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = T
        A[6 * i : 6 * i + 6, 18:] = -np.eye(6)
    return A


def numerical_rank(M: Array, rtol: float = 1e-9) -> int:
    """Rank of M by SVD: singular values above rtol times the largest."""
    s = np.linalg.svd(M, compute_uv=False)
    return int(np.sum(s > rtol * s[0])) if s.size and s[0] > 0 else 0


def level_guess(geom: Pprs6Geometry, drives: Array) -> Array:
    """A pose guess from the drives, assuming a level platform (zero orientation), (N, 6) -> (N, 6).

    With R = I, ``C_i . u_i = p . u_i + r`` gives p_xy from w_1, w_2, and chain 1's link gives
    ``Z = s_1 + sqrt(L_1^2 - (p . v_1)^2)``. Exact for level poses; a good Newton start for small tilts.
    """
    q = np.atleast_2d(np.asarray(drives, dtype=float))
    u = geom.u[:2, :2]
    pxy = np.linalg.solve(u, (q[:, :2] - geom.r).T).T
    pv = pxy @ geom.v[0, :2]
    z = q[:, 3] + np.sqrt(np.maximum(geom.L[0] ** 2 - pv**2, 0.0))
    out = np.zeros((q.shape[0], 6))
    out[:, :2], out[:, 2] = pxy, z
    return out
