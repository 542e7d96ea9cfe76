"""What the robot reaches: the model per rail length, exact IK solutions, payload orientations, postures.

The generator places goals where the robot's own inverse kinematics has exact, admissible solutions
(:func:`planner.redundancy.ik.family_candidates`, then :func:`~planner.redundancy.ik.track_pose`), never
where the planner happens to succeed. Frame: the robot base frame; transforms (4, 4), joints (8,).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.core.types import Array
from planner.kinematics import chain
from planner.redundancy.ik import IKOptions, family_candidates, track_pose
from planner.robots.cabin8 import Cabin8

#: The tucked posture of ``planner/meshes/README.md`` (arm along +z), apart from d1.
_TUCKED = np.array([0.0, 0.0, 0.20, 0.0, -math.pi / 2, math.radians(15.0), -0.25, math.pi / 2])
_FAMILY = IKOptions(grid_gamma=11, grid_d5=11)


@functools.cache
def robot_of(rail_length_m: float) -> Cabin8:
    """The cabin8 model with this rail length (built once per length: its CasADi functions take a while)."""
    return Cabin8(rail_length=rail_length_m)


def payload_rotation(kind: str, roll: int) -> Array:
    """Axis-aligned payload orientation: its z axis is the insertion direction, ``roll`` in {0, 1}.

    ``roll`` 1 turns the payload 90 deg about its own z axis (its x axis vertical).
    """
    z = {"bay-side": (1.0, 0.0, 0.0), "bay-end-far": (0.0, 0.0, 1.0), "bay-end-near": (0.0, 0.0, -1.0)}[kind]
    ez = np.array(z)
    ex = np.array([0.0, 1.0, 0.0]) if roll else np.cross(np.array([0.0, 1.0, 0.0]), ez)
    ey = np.cross(ez, ex)
    return np.column_stack([ex, ey, ez])


def pose(R: Array, p: Array) -> Array:
    """The transform (4, 4) of a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def rot_z(angle: float) -> Array:
    """Rotation (3, 3) by ``angle`` [rad] about z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def tool_pose(T_base_payload: Array, payload: PayloadGeometry) -> Array:
    """``T_base_tool`` that puts the payload at ``T_base_payload``."""
    return T_base_payload @ np.linalg.inv(payload.T_tool_payload)


def tucked(d1: float) -> Array:
    """The tucked posture (8,) at rail travel ``d1`` [m]."""
    q = _TUCKED.copy()
    q[chain.D1] = d1
    return q


def exact_solutions(robot: Cabin8, T_base_tool: Array, u_ref: Array, count: int = 3) -> list[Array]:
    """Up to ``count`` exact, admissible, distinct IK solutions of a tool pose (best margin first)."""
    good, _ = family_candidates(robot, T_base_tool, u_ref, 0.3, _FAMILY)
    out: list[Array] = []
    for cand in good:
        if len(out) >= count:
            break
        if any(np.all(np.abs(cand.q[[3, 6]] - q[[3, 6]]) < np.array([0.08, 0.08])) for q in out):
            continue
        sol = track_pose(robot, cand.q, T_base_tool, cand.q)
        if sol is not None:
            out.append(sol.q)
    return out


__all__ = ["exact_solutions", "payload_rotation", "pose", "robot_of", "rot_z", "tool_pose", "tucked"]
