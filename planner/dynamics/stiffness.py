"""Stiffness model of cabin8 and deflection-compensated goals (paper section 4, eq. 54-75; section 5.2).

Model (the paper's method, read as below). Every flexible member is a straight Euler-Bernoulli beam of
rectangular section b x h between joint centres / frame origins: the stage links AB, CD, EF and the platform
BC (in the stage plane, section width b along the base z axis), the column (frame 2 -> 3), the arm (3 -> 4)
and the slide (4 -> 6, the same members as :mod:`planner.dynamics.lagrange`). Its tip compliance in the
beam frame (x along the beam) is the cantilever matrix of eq. (54). Every drive is a spring along or about
its axis (rail, the three sliders, theta3, theta4, d5, theta6); every stage pin (A, B, C, D, E, F) is a
passive revolute joint about the base z axis that carries no moment about it, with a translational
compliance ``pin_compliance_m_N`` along each base axis (its bearing; issue 15); the slider carriages, the
rail carriage, the tool and the payload are rigid. The data and where they come from (``stiffness.source``:
paper-fit, calibrated, nominal) are in the description (:mod:`planner.dynamics.paper_fit`,
:mod:`planner.dynamics.calibration`).

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
  coordinates directly, so the sum is plain. The stage reduces exactly in two levels: at the midpoint E of
  AB, branch (slider A, pin A, beam A-E) in parallel with branch (slider F, pin F, beam F-E, pin E); then at
  the platform centre O, branch (node E, beam E-B, pin B, beam B-O) in parallel with branch (slider D, pin D,
  beam D-C, pin C, beam C-O).
* **Whole robot**: ``C_P = C_rail + J_O C_stage J_O^T + sum over the serial elements`` (eq. 71-75, the
  stage being one element of the serial chain, as the paper says) and ``K_P = C_P^-1``.

Where our reading differs from the printed equations:

* eq. (55)-(61), link AB loaded at its midpoint E by EF: the printed compliance (61) is not symmetric (the
  ``2 L1^3 sin/(3 E I cos)`` entry has no mirror, the axial entry mixes force and moment units), which no
  linear elastic member can have. We do not use it: AB is two beams A-E and E-B joined at E, and EF's
  load enters at E through the two-level parallel/serial reduction above, which is exact for the
  Euler-Bernoulli model.
* eq. (63) and (66) write ``J_i`` with ``S(r) R`` in the upper-right block and call ``J_Fi = J_i^-T`` a
  force map with the block in the lower-left: consistent with each other only as twist/wrench maps of
  opposite direction. We use the twist map ``[[I, -S(d)], [0, I]]`` (displacement at a point moved by d)
  and its transpose for wrenches, as eq. (70) does.
* eq. (71) and (73)-(74) sum over six elements; cabin8 has the rail, the stage, column, arm and slide and
  four arm drives: we sum over all of them.
* eq. (54)'s torsion constant ``I_p = b h^3 (1/3 - 0.21 h/b)`` is used as printed (b >= h).

Loads. Under gravity each member's weight is lumped half at each end node (the same split by which the
dynamics' potential energy of a uniform bar, ``-m g.(p0 + p1)/2``, equals two half masses): the serial
members' halves at their frame origins, the tool at its origin, the payload at its centre of mass. The
stage members' weights are lumped at the platform centre O (their halves at the sliders go straight into
the rigid slider guides); the independent FE route (:mod:`planner.dynamics.frame_fe`) puts them at
their true nodes, which bounds this lumping. Each element's compliance multiplies the wrench of every load
distal to it (eq. 73 with the internal wrench of element j instead of only the tip wrench).

Deflections are small-displacement twists of the reference frame's origin: translation [m] and rotation
[rad], both in the base frame. The reference frame is the tool frame or any frame rigidly attached to it
(the payload frame: ``T_tool_frame`` = the grasp).

This module is the math only; the stiffness document of the CLI and the API (payload and wrench inputs,
the JSON report) is :mod:`planner.documents.stiffness`.
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.description import Section, StiffnessSpec
from planner.core.exceptions import DeflectionNotCompensated, InvalidInput, InvalidRobotDescription
from planner.core.so3 import matrix_to_quat_wxyz, pose_error
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.kinematics import chain, parallel
from planner.kinematics.closed_form import redundant_family
from planner.robots.cabin8 import Cabin8

#: Compensation tolerances of the issue: 0.01 mm and 1e-5 rad (what the gate demands).
COMPENSATION_TOL_M = 1e-5
COMPENSATION_TOL_RAD = 1e-5
#: The compensation iterates ten times further, so a result that just converged never fails the gate.
COMPENSATION_ITERATE_TO = 0.1

_EZ = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------------------------------ building blocks
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


# ------------------------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class StaticDeflection:
    """Small-displacement twist of a frame origin: translation [m] and rotation [rad], base frame."""

    translation_m: Array
    rotation_rad: Array

    @property
    def twist(self) -> Array:
        """(dx, dy, dz, rx, ry, rz), shape (6,)."""
        return np.concatenate([self.translation_m, self.rotation_rad])

    def to_dict(self) -> dict[str, Any]:
        """JSON form with norms."""
        return {
            "translation_m": self.translation_m.tolist(),
            "rotation_rad": self.rotation_rad.tolist(),
            "translation_norm_m": float(np.linalg.norm(self.translation_m)),
            "rotation_norm_rad": float(np.linalg.norm(self.rotation_rad)),
        }


def deflected_pose(T: Array, twist: Array) -> Array:
    """The pose T (4x4) displaced by a small twist (translation, rotation vector) in the base frame."""
    from scipy.spatial.transform import Rotation

    out = np.array(T, dtype=float, copy=True)
    out[:3, 3] += twist[:3]
    out[:3, :3] = Rotation.from_rotvec(twist[3:]).as_matrix() @ out[:3, :3]
    return out


@dataclass(frozen=True)
class CompensationStep:
    """One iteration of the goal compensation: the residual of the deflected pose to the request."""

    residual_m: float
    residual_rad: float


@dataclass(frozen=True)
class Compensation:
    """Deflection-compensated goal: the command whose deflected pose is the requested pose.

    Attributes:
        T_base_frame_nominal: The requested pose of the frame (4x4).
        T_base_frame_commanded: The pose to command (4x4).
        q_nominal: The configuration the compensation started from (8,).
        q_commanded: Exact IK of the commanded pose on the same (gamma, d5) (8,).
        deflection: Predicted deflection at the commanded configuration.
        residual_m: |p_deflected - p_requested| [m].
        residual_rad: |log(R_requested R_deflected^T)| [rad].
        iterations: Residual before each correction, then the final one.
    """

    T_base_frame_nominal: Array = field(repr=False)
    T_base_frame_commanded: Array = field(repr=False)
    q_nominal: Array = field(repr=False)
    q_commanded: Array = field(repr=False)
    deflection: StaticDeflection
    residual_m: float
    residual_rad: float
    iterations: tuple[CompensationStep, ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON form: nominal and compensated goals (pose and joints), deflection, iteration log."""
        return {
            "nominal": _pose_dict(self.T_base_frame_nominal) | {"joints": self.q_nominal.tolist()},
            "compensated": _pose_dict(self.T_base_frame_commanded) | {"joints": self.q_commanded.tolist()},
            "predicted_deflection": self.deflection.to_dict(),
            "residual_m": self.residual_m,
            "residual_rad": self.residual_rad,
            "iterations": [
                {"residual_m": s.residual_m, "residual_rad": s.residual_rad} for s in self.iterations
            ],
        }


def _pose_dict(T: Array) -> dict[str, Any]:
    w, x, y, z = matrix_to_quat_wxyz(T[:3, :3])
    return {"position": T[:3, 3].tolist(), "orientation": {"w": w, "x": x, "y": y, "z": z}}


# ------------------------------------------------------------------------------------------------ the model
class StiffnessModel:
    """The analytical stiffness model of a :class:`Cabin8` (module docstring); every method is batched.

    Args:
        robot: The robot; its description must have a ``stiffness`` section (unless ``spec`` is given).
        spec: Stiffness data to use instead of the description's (the fit and the calibration try
            candidate data on the same geometry).

    Raises:
        InvalidRobotDescription: the description has no stiffness data.
    """

    def __init__(self, robot: Cabin8, spec: StiffnessSpec | None = None) -> None:
        spec = spec if spec is not None else robot.desc.stiffness
        if spec is None:
            raise InvalidRobotDescription(
                f"robot description {robot.name}: stiffness: missing (needed for the stiffness model)",
                field="stiffness",
            )
        self.robot = robot
        self.spec: StiffnessSpec = spec
        self.k_drive = spec.drive_stiffness()
        self.masses = robot.desc.masses
        self.gravity = np.asarray(robot.desc.gravity_m_s2, dtype=float)

    # ------------------------------------------------------------------ geometry
    def _beam(self, name: str, p0: Array, p1: Array, z_ref: Array, point: Array) -> Array:
        R, length = beam_frame(p0, p1, z_ref)
        sec = getattr(self.spec.sections, name)
        return map_compliance(beam_compliance(length, sec, self.spec.E_Pa, self.spec.G_Pa), R, p1, point)

    def _pin_compliance(self, at: Array, point: Array) -> Array:
        """Translational compliance (N, 6, 6) of a stage pin at ``at`` seen at ``point`` (issue 15).

        The pin's bearing gives along each base axis under a force through it (``pin_compliance_m_N``);
        it is a serial element of its branch, like the beams.
        """
        c = self.spec.pin_compliance_m_N
        C_local = np.zeros((*at.shape[:-1], 6, 6))
        C_local[..., [0, 1, 2], [0, 1, 2]] = c
        return map_compliance(C_local, np.broadcast_to(np.eye(3), (*at.shape[:-1], 3, 3)), at, point)

    def _stage_points(self, q: Array) -> dict[str, Array]:
        pts = parallel.stage_points(self.robot.geometry, q[:, chain.X], q[:, chain.Y], q[:, chain.GAMMA])
        out = {}
        for name, (x, y) in zip("ABCDEF", pts, strict=True):
            out[name] = np.stack(
                [np.broadcast_to(x, q[:, 0].shape), np.broadcast_to(y, q[:, 0].shape), q[:, 0]], -1
            )
        out["O"] = np.stack([q[:, chain.X], q[:, chain.Y], q[:, 0]], axis=-1)
        return out

    def stage_stiffness(self, q: Array) -> Array:
        """Stiffness (N, 6, 6) of the parallel stage at the platform centre O, base axes (eq. 62-68).

        Args:
            q: Joint vectors (N, 8) or (8,).
        """
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        return self._stage(q2, self._stage_points(q2))

    def _stage(self, q: Array, p: dict[str, Array]) -> Array:
        n = q.shape[0]
        ez = np.broadcast_to(_EZ, (n, 3))
        ex = np.broadcast_to(np.array([1.0, 0.0, 0.0]), (n, 3))
        kx = self.k_drive[1:4]
        slide_x = prismatic_twist(ex)
        E, centre = p["E"], p["O"]
        pin = self._pin_compliance
        # Level 1, at E: (slider A, pin A, beam A-E) || (slider F, pin F, beam F-E, pin E).
        C_a = self._beam("link_ab", p["A"], E, ez, E) + spring_compliance(slide_x, kx[0]) + pin(p["A"], E)
        K_a = branch_stiffness(C_a, revolute_twist(ez, p["A"], E)[..., None])
        C_b = (
            self._beam("link_ef", p["F"], E, ez, E)
            + spring_compliance(slide_x, kx[2])
            + pin(p["F"], E)
            + pin(E, E)
        )
        J_b = np.stack([revolute_twist(ez, p["F"], E), revolute_twist(ez, E, E)], axis=-1)
        K_b = branch_stiffness(C_b, J_b)
        C_E = np.asarray(np.linalg.inv(K_a + K_b), dtype=float)
        # Level 2, at O: (node E, beam E-B, pin B, beam B-O) || (slider D, pin D, beam D-C, pin C, beam C-O).
        C_1 = (
            map_compliance(C_E, np.broadcast_to(np.eye(3), (n, 3, 3)), E, centre)
            + self._beam("link_ab", E, p["B"], ez, centre)
            + self._beam("platform", p["B"], centre, ez, centre)
            + pin(p["B"], centre)
        )
        K_1 = branch_stiffness(C_1, revolute_twist(ez, p["B"], centre)[..., None])
        C_2 = (
            spring_compliance(slide_x, kx[1])
            + self._beam("link_cd", p["D"], p["C"], ez, centre)
            + self._beam("platform", p["C"], centre, ez, centre)
            + pin(p["D"], centre)
            + pin(p["C"], centre)
        )
        J_2 = np.stack([revolute_twist(ez, p["D"], centre), revolute_twist(ez, p["C"], centre)], axis=-1)
        K_2 = branch_stiffness(C_2, J_2)
        K = K_1 + K_2
        return 0.5 * (K + np.swapaxes(K, -1, -2))

    def _elements(self, q: Array, T_tool_frame: Array) -> tuple[Array, list[Array], dict[str, Array]]:
        """Reference points (N, 3) and the element compliances at them, proximal to distal.

        Order: rail, stage, theta3, column, arm, theta4, d5, slide, theta6 -- the loads that each carries
        are given by :data:`_LOAD_LEVEL`.
        """
        n = q.shape[0]
        F = self.robot.frames(q)
        T_frame = F[:, 6] @ T_tool_frame
        P = T_frame[:, :3, 3]
        p = self._stage_points(q)
        centre = p["O"]
        o3, o4, o6 = F[:, 3, :3, 3], F[:, 4, :3, 3], F[:, 6, :3, 3]
        x3, z3, z4, z5, z6 = F[:, 3, :3, 0], F[:, 3, :3, 2], F[:, 4, :3, 2], F[:, 5, :3, 2], F[:, 6, :3, 2]
        k = self.k_drive
        C_stage = np.asarray(np.linalg.inv(self._stage(q, p)), dtype=float)
        elems = [
            spring_compliance(prismatic_twist(np.broadcast_to(_EZ, (n, 3))), k[0]),
            map_compliance(C_stage, np.broadcast_to(np.eye(3), (n, 3, 3)), centre, P),
            spring_compliance(revolute_twist(z3, o3, P), k[4]),
            self._beam("column", centre, o3, x3, P),
            self._beam("arm", o3, o4, z4, P),
            spring_compliance(revolute_twist(z4, o4, P), k[5]),
            spring_compliance(prismatic_twist(z5), k[6]),
            self._beam("slide", o4, o6, z4, P),
            spring_compliance(revolute_twist(z6, o6, P), k[7]),
        ]
        pts = {"P": P, "O": centre, "o3": o3, "o4": o4, "o6": o6, "R6": F[:, 6, :3, :3]}
        return P, elems, pts

    # ------------------------------------------------------------------- public
    def compliance(self, q: Array, T_tool_frame: Array | None = None) -> Array:
        """Cartesian compliance C (6, 6) or (N, 6, 6) at the frame origin, base axes (eq. 74-75).

        Maps a wrench (force [N], moment [N m]) at the frame origin to the frame's small twist
        (translation [m], rotation [rad]), both in the base frame.

        Args:
            q: Joint vectors (8,) or (N, 8).
            T_tool_frame: The reference frame in the tool frame (4x4; default: the tool frame itself).
        """
        q2, single = _rows(q)
        _, elems, _ = self._elements(q2, _frame(T_tool_frame))
        C = np.sum(elems, axis=0)
        C = 0.5 * (C + np.swapaxes(C, -1, -2))
        return C[0] if single else C

    def stiffness(self, q: Array, T_tool_frame: Array | None = None) -> Array:
        """Cartesian stiffness K = C^-1 (6, 6) or (N, 6, 6) at the frame origin, base axes."""
        C = self.compliance(q, T_tool_frame)
        scale = np.max(np.abs(C), axis=(-2, -1), keepdims=True)
        K = np.linalg.inv(C / scale) / scale
        return 0.5 * (K + np.swapaxes(K, -1, -2))

    def deflection_batch(
        self,
        q: Array,
        payload: RigidPayload | None = None,
        T_tool_frame: Array | None = None,
        wrench: Array | None = None,
        gravity: bool = True,
    ) -> Array:
        """Static deflection twists (N, 6) of the frame origin under gravity and/or a wrench at it.

        Args:
            q: Joint vectors (N, 8).
            payload: Payload carried by the tool (default: none).
            T_tool_frame: The reference frame in the tool frame (default: the tool frame).
            wrench: External wrench (6,) or (N, 6) at the frame origin, base axes (force [N], moment [N m]).
            gravity: Include the weight of the links, tool and payload.

        Returns:
            (N, 6): translation [m] and rotation [rad] of the frame origin, base frame.
        """
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        n = q2.shape[0]
        P, elems, pts = self._elements(q2, _frame(T_tool_frame))
        W = np.zeros((len(_LOAD_LEVEL_NAMES), n, 6))  # wrench at P of the loads at each level
        if gravity:
            g = self.gravity
            ms = self.masses
            pay = payload or RigidPayload()

            def weight(m: float, at: Array) -> Array:
                return wrench_at(np.broadcast_to(m * g, (n, 3)), at, P)

            com = pts["o6"] + np.einsum("nij,j->ni", pts["R6"], pay.com_tool)
            W[_LEVEL["tip"]] = weight(ms.tool, pts["o6"]) + weight(pay.mass, com)
            W[_LEVEL["o6"]] = weight(0.5 * ms.slide, pts["o6"])
            W[_LEVEL["o4"]] = weight(0.5 * (ms.arm + ms.slide), pts["o4"])
            W[_LEVEL["o3"]] = weight(0.5 * (ms.column + ms.arm), pts["o3"])
            stage_mass = ms.platform + 0.5 * (ms.link_ab + ms.link_cd + ms.link_ef) + 0.5 * ms.column
            W[_LEVEL["O"]] = weight(stage_mass, pts["O"])
        if wrench is not None:
            W[_LEVEL["tip"]] += np.broadcast_to(np.asarray(wrench, dtype=float), (n, 6))
        # Cumulative from the tip: the wrench carried by the elements proximal to each level.
        carried = np.cumsum(W[::-1], axis=0)[::-1]
        X = np.zeros((n, 6))
        for C_j, level in zip(elems, _ELEMENT_LEVEL, strict=True):
            X += np.einsum("nij,nj->ni", C_j, carried[level])
        return X

    def deflection(
        self,
        q: Array,
        payload: RigidPayload | None = None,
        T_tool_frame: Array | None = None,
        wrench: Array | None = None,
        gravity: bool = True,
    ) -> StaticDeflection:
        """Static deflection of the frame origin at one configuration (see :meth:`deflection_batch`)."""
        x = self.deflection_batch(np.asarray(q, dtype=float)[None], payload, T_tool_frame, wrench, gravity)[0]
        return StaticDeflection(x[:3].copy(), x[3:].copy())

    def deflection_along(
        self, q_samples: Array, payload: RigidPayload | None = None, T_tool_frame: Array | None = None
    ) -> Array:
        """Gravity deflection (N, 6) of the frame along a trajectory's joint samples (N, 8)."""
        return self.deflection_batch(q_samples, payload, T_tool_frame)


#: Load levels, tip first; an element carries the loads at its own level and every more distal one.
_LOAD_LEVEL_NAMES = ("rail", "O", "o3", "o4", "o6", "tip")
_LEVEL = {name: i for i, name in enumerate(_LOAD_LEVEL_NAMES)}
#: Level of each element of StiffnessModel._elements: the first load level distal to it.
#: rail -> every load (the stage's own loads included); stage -> loads at O and beyond; theta3, column ->
#: o3 and beyond; arm -> o4 and beyond; theta4, d5, slide -> o6 and beyond; theta6 -> the tool and payload.
_ELEMENT_LEVEL = (
    _LEVEL["rail"],
    _LEVEL["O"],
    _LEVEL["o3"],
    _LEVEL["o3"],
    _LEVEL["o4"],
    _LEVEL["o6"],
    _LEVEL["o6"],
    _LEVEL["o6"],
    _LEVEL["tip"],
)


def _rows(q: Array) -> tuple[Array, bool]:
    qa = np.asarray(q, dtype=float)
    if qa.shape[-1] != 8 or qa.ndim > 2:
        raise InvalidInput(f"joints: expected shape (8,) or (N, 8), got {qa.shape}", field="joints")
    return np.atleast_2d(qa), qa.ndim == 1


def _frame(T: Array | None) -> Array:
    if T is None:
        return np.eye(4)
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InvalidInput("T_tool_frame: expected a finite 4x4 transform", field="T_tool_frame")
    return T


# ---------------------------------------------------------------------------------------------- compensation
def compensate_goal(
    model: StiffnessModel,
    T_base_frame_goal: Array,
    q_goal: Array,
    payload: RigidPayload | None = None,
    T_tool_frame: Array | None = None,
    wrench: Array | None = None,
    tol_m: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_M,
    tol_rad: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_RAD,
    max_iterations: int = 20,
) -> Compensation:
    """The commanded pose whose deflected pose is the requested one, and its exact IK near ``q_goal``.

    Fixed-point iteration on the pose: with T_cmd = T_goal first, the configuration is the exact
    closed-form IK of T_cmd on the same redundant coordinates (gamma, d5) as ``q_goal``
    (:func:`~planner.kinematics.closed_form.redundant_family`), its deflected pose T_def = exp(x) T_cmd
    (x the static deflection there), and the residual e = T_goal - T_def (position difference and
    rotation vector, base frame) corrects T_cmd <- exp(e) T_cmd. The deflection changes little with the
    configuration, so the error contracts by about |dx/dq| per step (three or four steps in practice).

    Args:
        model: The stiffness model.
        T_base_frame_goal: Requested pose of the frame (4x4), e.g. the payload frame.
        q_goal: A configuration (8,) reaching ``T_base_frame_goal`` exactly (the planner's goal).
        payload: Payload carried (its weight deflects the robot).
        T_tool_frame: The frame in the tool frame (the grasp for the payload frame; default tool).
        wrench: Additional wrench at the frame origin (6,), base axes, e.g. an insertion force.
        tol_m: Position residual to reach [m] (default 0.01 mm).
        tol_rad: Orientation residual to reach [rad] (default 1e-5).
        max_iterations: Corrections allowed.

    Raises:
        DeflectionNotCompensated: the residual is still above the tolerances after ``max_iterations``, or
            the commanded configuration leaves the robot's admissible set (``details`` has the log).
    """
    robot = model.robot
    T_tf = _frame(T_tool_frame)
    T_ft = np.linalg.inv(T_tf)
    T_goal = np.asarray(T_base_frame_goal, dtype=float)
    q_goal = np.asarray(q_goal, dtype=float)
    gamma, d5 = np.array([q_goal[chain.GAMMA]]), np.array([q_goal[chain.D5]])
    T_cmd = T_goal.copy()
    log: list[CompensationStep] = []
    for it in range(max_iterations + 1):
        q = redundant_family(robot.desc.serial_chain, T_cmd @ T_ft, gamma, d5)[0]
        q[chain.THETA6] = q_goal[chain.THETA6] + math.remainder(
            q[chain.THETA6] - q_goal[chain.THETA6], 2 * math.pi
        )
        defl = model.deflection(q, payload, T_tf, wrench)
        e = pose_error(T_goal, deflected_pose(T_cmd, defl.twist))
        step = CompensationStep(float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])))
        log.append(step)
        if step.residual_m <= tol_m and step.residual_rad <= tol_rad:
            bad = robot.violations(q)
            if bad:
                raise DeflectionNotCompensated(
                    "goal compensation: the commanded configuration violates "
                    + ", ".join(b["name"] for b in bad),
                    violations=bad,
                    iterations=[s.__dict__ for s in log],
                )
            return Compensation(
                T_goal, T_cmd, q_goal, q, defl, step.residual_m, step.residual_rad, tuple(log)
            )
        if it == max_iterations:
            break
        T_cmd = deflected_pose(T_cmd, e)
    raise DeflectionNotCompensated(
        f"goal compensation: residual {1e3 * log[-1].residual_m:.4g} mm / {log[-1].residual_rad:.3g} rad "
        f"after {max_iterations} corrections (tolerance {1e3 * tol_m:g} mm / {tol_rad:g} rad)",
        iterations=[s.__dict__ for s in log],
        tol_m=tol_m,
        tol_rad=tol_rad,
    )


_MODELS: weakref.WeakKeyDictionary[Cabin8, StiffnessModel] = weakref.WeakKeyDictionary()


def stiffness_model(robot: Cabin8) -> StiffnessModel:
    """The (cached) stiffness model of a robot instance (released with the robot)."""
    model = _MODELS.get(robot)
    if model is None:
        model = _MODELS[robot] = StiffnessModel(robot)
    return model


# ------------------------------------------------------------------------------------------ planner hook
@dataclass(frozen=True)
class CompensatedGoals:
    """Goal configurations (and approach lines) moved onto their compensated commands.

    ``targets[i]``, ``lines[i]`` and ``compensations[i]`` belong together; candidates whose moved line or
    configuration was rejected are dropped (``rejected`` counts them).
    """

    targets: list[Array]
    lines: list[Any]
    compensations: list[Compensation]
    rejected: int


def compensate_goals(
    model: StiffnessModel,
    targets: list[Array],
    lines: list[Any],
    T_base_payload_goal: Array,
    payload: RigidPayload | None,
    T_tool_payload: Array,
    accept: Callable[[Array], bool],
) -> CompensatedGoals:
    """Move each goal configuration (and its approach line) onto the command that deflects onto the goal.

    Each candidate's final configuration (the end of its approach line, else the target) is compensated by
    :func:`compensate_goal` on its own (gamma, d5). The whole line is shifted by the same joint offset
    dq = q_commanded - q_goal: a fixed-redundancy line stays a straight joint segment whose payload path is
    the requested insertion line moved by the goal's correction (the deflection along the line changes
    little; it is reported with the plan). ``accept(path (K, 8)) -> bool`` re-checks each moved line (or
    the single configuration) for limits, force and clearance.

    Raises:
        DeflectionNotCompensated: no candidate can be compensated and accepted (``details`` says why).
    """
    out_t: list[Array] = []
    out_l: list[Any] = []
    comps: list[Compensation] = []
    errors: list[str] = []
    rejected = 0
    for q, line in zip(targets, lines, strict=True):
        path = line.line if (line is not None and getattr(line, "line", None) is not None) else None
        q_end = path[-1] if path is not None else q
        try:
            comp = compensate_goal(model, T_base_payload_goal, q_end, payload, T_tool_payload)
        except DeflectionNotCompensated as exc:
            errors.append(exc.message)
            continue
        dq = comp.q_commanded - q_end
        moved = (path if path is not None else q[None, :]) + dq[None, :]
        if not accept(moved):
            rejected += 1
            continue
        out_l.append(dataclasses.replace(line, line=moved, q=line.q + dq) if path is not None else line)
        out_t.append(moved[0])
        comps.append(comp)
    if not out_t:
        raise DeflectionNotCompensated(
            "goal compensation: no goal configuration can be moved onto its deflection-compensated command "
            f"({rejected} rejected for limits, force or clearance; {len(errors)} did not converge)",
            rejected=rejected,
            errors=errors[:3],
        )
    return CompensatedGoals(out_t, out_l, comps, rejected)
