"""Stiffness model of cabin8 (paper section 4, eq. 54-75): compliance, stiffness and static deflections.

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

The beam, spring and pin primitives and the serial / parallel composition rules (eq. 62-70) are
:mod:`planner.dynamics.beams`.

* **The stage** reduces exactly in two levels: at the midpoint E of AB, branch (slider A, pin A, beam A-E) in
  parallel with branch (slider F, pin F, beam F-E, pin E); then at the platform centre O, branch (node E, beam
  E-B, pin B, beam B-O) in parallel with branch (slider D, pin D, beam D-C, pin C, beam C-O).
* **Whole robot**: ``C_P = C_rail + J_O C_stage J_O^T + sum over the serial elements`` (eq. 71-75, the
  stage being one element of the serial chain, as the paper says) and ``K_P = C_P^-1``.

Where our reading differs from the printed equations:

* eq. (55)-(61), link AB loaded at its midpoint E by EF: the printed compliance (61) is not symmetric (the
  ``2 L1^3 sin/(3 E I cos)`` entry has no mirror, the axial entry mixes force and moment units), which no
  linear elastic member can have. We do not use it: AB is two beams A-E and E-B joined at E, and EF's
  load enters at E through the two-level parallel/serial reduction above, which is exact for the
  Euler-Bernoulli model.
* eq. (71) and (73)-(74) sum over six elements; cabin8 has the rail, the stage, column, arm and slide and
  four arm drives: we sum over all of them.

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

A load case (:class:`LoadCase`: payload, frame, external wrench, gravity) is one value; the model's
entry :meth:`StiffnessModel.deflections` takes joint vectors and a load case, and the thin forms of the
common case (gravity, a payload, a frame) are :meth:`StiffnessModel.deflection` (one configuration) and
:meth:`StiffnessModel.deflection_along` (a trajectory's samples); the deflection change when a payload is
attached or released is :func:`planner.dynamics.load_change.load_change`.

This module is the math only; the goal compensation is :mod:`planner.dynamics.compensation`, the
stiffness document of the CLI and the API (payload and wrench inputs, the JSON report)
:mod:`planner.documents.stiffness`.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.core.description import StiffnessSpec
from planner.core.exceptions import InvalidInput, InvalidRobotDescription
from planner.core.lru import BoundedLRU
from planner.core.types import Array
from planner.dynamics.beams import (
    beam_compliance,
    beam_frame,
    branch_stiffness,
    deflected_pose,
    map_compliance,
    prismatic_twist,
    revolute_twist,
    spring_compliance,
    wrench_at,
)
from planner.dynamics.compensation import (
    COMPENSATION_ITERATE_TO,
    COMPENSATION_TOL_M,
    COMPENSATION_TOL_RAD,
    Compensation,
    compensate,
)
from planner.dynamics.payload import RigidPayload
from planner.kinematics import chain, parallel
from planner.robots.cabin8 import Cabin8

_EZ = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class LoadCase:
    """What loads the robot and which frame's deflection is read; the configuration is given apart.

    Attributes:
        payload: The payload carried by the tool (None: none); its weight acts at its centre of mass.
        T_tool_frame: The reference frame in the tool frame (4x4; None: the tool frame). The payload frame
            is the grasp ``T_tool_payload``.
        wrench: External wrench (6,) or (N, 6) at the frame origin, base axes (force [N], moment [N m]).
        gravity: Include the weight of the links, tool and payload.
    """

    payload: RigidPayload | None = None
    T_tool_frame: Array | None = None
    wrench: Array | None = None
    gravity: bool = True

    def frame(self) -> Array:
        """The reference frame in the tool frame (4x4).

        Raises:
            InvalidInput: not a finite 4x4 transform.
        """
        return _frame(self.T_tool_frame)

    def key(self) -> bytes:
        """The load case as bytes (payload inertia, frame, wrench, gravity): equal cases, equal keys."""
        parts = [b"g1" if self.gravity else b"g0"]
        if self.payload is not None:
            pay = self.payload
            parts += [np.float64(pay.mass).tobytes(), np.asarray(pay.com_tool, float).tobytes()]
            parts.append(np.asarray(pay.inertia_tool, float).tobytes())
        parts.append(b"T" + self.frame().tobytes())
        if self.wrench is not None:
            w = np.asarray(self.wrench, dtype=float)
            parts.append(b"W" + repr(w.shape).encode() + w.tobytes())
        return b"|".join(parts)


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
        #: Deflections of single configurations already evaluated, by (q, load case): a cycle asks the same
        #: ones several times (a load change's two sides in the plan, the gate and the events); the model
        #: costs 1-2 ms a call whatever the batch, so repeats are worth keeping (the last _MEMO of them).
        #: The model is shared by the threads of a process (:func:`stiffness_model`): the memo is thread-safe.
        self._memo: BoundedLRU[bytes, Array] = BoundedLRU(_MEMO)

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

    def deflections(self, q: Array, load: LoadCase) -> Array:
        """Static deflection twists (N, 6) of the load case's frame origin at joint vectors q (N, 8).

        The one entry of the load case: gravity on the links, tool and payload (``load.gravity``) and/or
        the external wrench at the frame origin (``load.wrench``).

        Returns:
            (N, 6): translation [m] and rotation [rad] of the frame origin, base frame.
        """
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        if q2.shape[0] != 1:
            return self._deflections(q2, load)
        key = q2.tobytes() + load.key()
        hit = self._memo.get(key)
        if hit is not None:
            return hit.copy()
        x = self._deflections(q2, load)
        x.flags.writeable = False
        self._memo.put(key, x)
        return x.copy()

    def _deflections(self, q2: Array, load: LoadCase) -> Array:
        n = q2.shape[0]
        P, elems, pts = self._elements(q2, load.frame())
        W = np.zeros((len(_LOAD_LEVEL_NAMES), n, 6))  # wrench at P of the loads at each level
        if load.gravity:
            g = self.gravity
            ms = self.masses
            pay = load.payload or RigidPayload()

            def weight(m: float, at: Array) -> Array:
                return wrench_at(np.broadcast_to(m * g, (n, 3)), at, P)

            com = pts["o6"] + np.einsum("nij,j->ni", pts["R6"], pay.com_tool)
            W[_LEVEL["tip"]] = weight(ms.tool, pts["o6"]) + weight(pay.mass, com)
            W[_LEVEL["o6"]] = weight(0.5 * ms.slide, pts["o6"])
            W[_LEVEL["o4"]] = weight(0.5 * (ms.arm + ms.slide), pts["o4"])
            W[_LEVEL["o3"]] = weight(0.5 * (ms.column + ms.arm), pts["o3"])
            stage_mass = ms.platform + 0.5 * (ms.link_ab + ms.link_cd + ms.link_ef) + 0.5 * ms.column
            W[_LEVEL["O"]] = weight(stage_mass, pts["O"])
        if load.wrench is not None:
            W[_LEVEL["tip"]] += np.broadcast_to(np.asarray(load.wrench, dtype=float), (n, 6))
        # Cumulative from the tip: the wrench carried by the elements proximal to each level.
        carried = np.cumsum(W[::-1], axis=0)[::-1]
        X = np.zeros((n, 6))
        for C_j, level in zip(elems, _ELEMENT_LEVEL, strict=True):
            X += np.einsum("nij,nj->ni", C_j, carried[level])
        return X

    def static_deflection(self, q: Array, load: LoadCase) -> StaticDeflection:
        """The static deflection of the load case's frame origin at one configuration q (8,)."""
        x = self.deflections(np.asarray(q, dtype=float)[None], load)[0]
        return StaticDeflection(x[:3].copy(), x[3:].copy())

    def static_deflections(self, qs: Array, load: LoadCase) -> list[StaticDeflection]:
        """:meth:`static_deflection` at each configuration of qs (N, 8), evaluated in one batched call.

        The same bits as one by one: every row is computed on its own (tests/dynamics/test_stiffness.py).
        """
        return [StaticDeflection(x[:3].copy(), x[3:].copy()) for x in self.deflections(qs, load)]

    # Thin forms of the common load case (gravity, a payload, a frame): what the gate, the report and the
    # assembly cycles ask.
    def deflection(
        self, q: Array, payload: RigidPayload | None = None, T_tool_frame: Array | None = None
    ) -> StaticDeflection:
        """Gravity deflection of the frame at one configuration q (8,) carrying the payload."""
        return self.static_deflection(q, LoadCase(payload, T_tool_frame))

    def deflection_along(
        self, q_samples: Array, payload: RigidPayload | None = None, T_tool_frame: Array | None = None
    ) -> Array:
        """Gravity deflection (N, 6) of the frame along a trajectory's joint samples (N, 8)."""
        return self.deflections(q_samples, LoadCase(payload, T_tool_frame))


#: Single-configuration deflections a model keeps (:meth:`StiffnessModel.deflections`).
_MEMO = 64

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


_MODELS: weakref.WeakKeyDictionary[Cabin8, StiffnessModel] = weakref.WeakKeyDictionary()


def stiffness_model(robot: Cabin8) -> StiffnessModel:
    """The (cached) stiffness model of a robot instance (released with the robot)."""
    model = _MODELS.get(robot)
    if model is None:
        model = _MODELS[robot] = StiffnessModel(robot)
    return model


# ----------------------------------------------------------------------------------------- thin public form
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
    """:func:`planner.dynamics.compensation.compensate` of the load case (payload, frame, wrench)."""
    load = LoadCase(payload, T_tool_frame, wrench)
    return compensate(model, T_base_frame_goal, q_goal, load, tol_m, tol_rad, max_iterations)


__all__ = [
    "COMPENSATION_TOL_M",
    "COMPENSATION_TOL_RAD",
    "LoadCase",
    "StaticDeflection",
    "StiffnessModel",
    "compensate_goal",
    "deflected_pose",
    "stiffness_model",
]
