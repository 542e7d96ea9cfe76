"""Single-shot kinematics tools (forward and inverse kinematics documents) shared by the CLI and the API.

Each function takes parsed inputs (mappings of drive or joint names to values in m / rad, a
:class:`~planner.core.schemas.Pose`), calls the robot model, and returns the JSON-ready document both
front ends print or serve. Robot-specific tool sets (e.g. a second mechanism) live next to their model
and are dispatched by robot name by the callers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from planner.core.exceptions import InvalidInput
from planner.core.schemas import Pose
from planner.robots.registry import tool_pose_robot


def pose_document(T_base_tool: NDArray[np.float64]) -> dict[str, Any]:
    """``{"position": [x, y, z], "orientation": {w, x, y, z}}`` of a 4x4 rigid transform (m)."""
    pose = Pose.from_matrix(T_base_tool)
    return {"position": list(pose.position), "orientation": pose.orientation.model_dump()}


def fk_document(
    robot_name: str,
    drives: Mapping[str, Any] | None = None,
    joints: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Forward kinematics: drives (or joints) -> joints, drives, ``T_base_tool`` (row-major 4x4) and pose.

    Args:
        robot_name: Registry name of a cabin8-type robot.
        drives: Drive name -> position [m, rad]; exactly one of ``drives`` and ``joints``.
        joints: Joint name -> value [m, rad] (the parallel stage as platform pose x, y, gamma).

    Returns:
        ``{"robot", "joints", "drives", "T_base_tool", "pose", "violations"}``; ``violations`` lists every
        drive limit and singularity margin the configuration violates (empty when admissible).

    Raises:
        InvalidInput: both or neither of drives/joints, unknown or missing names (fields ``drives``,
            ``joints``).
        OutsideWorkspace: the stage does not assemble (drives) or no slider positions reach the platform
            pose (joints).
    """
    model = tool_pose_robot(robot_name)
    if (drives is None) == (joints is None):
        raise InvalidInput("fk: give exactly one of drives or joints", field="drives")
    if drives is not None:
        u = model.drives_from_dict(dict(drives), field="drives")
        q = model.joints_from_drives(u)
    else:
        assert joints is not None
        q = model.joints_from_dict(dict(joints), field="joints")
        u = model.drives_from_joints(q)
    T = model.fk(q)
    return {
        "robot": model.name,
        "joints": model.joints_dict(q),
        "drives": model.drives_dict(u),
        "T_base_tool": [float(v) for v in T.reshape(-1)],
        "pose": pose_document(T),
        "violations": model.violations(q),
    }


def ik_document(
    robot_name: str,
    pose: Pose,
    near: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Inverse kinematics of a tool pose (base frame): one admissible solution with its residuals.

    Args:
        robot_name: Registry name of a cabin8-type robot.
        pose: Tool frame in the base frame (m, unit quaternion).
        near: Drive name -> position [m, rad]: the solution nearest these is preferred (default: home).
        seed: Seed of the random restarts (the same seed gives the same solution).

    Returns:
        ``{"robot", "drives", "joints", "T_base_tool", "position_error_m", "orientation_error_rad",
        "min_margin", "iterations"}``.

    Raises:
        GoalUnreachable: no admissible configuration reaches the pose (details name the blocking limits).
        InvalidInput: bad ``near`` names (field ``near``).
    """
    from planner.redundancy.ik import IKOptions, solve_pose_ik

    model = tool_pose_robot(robot_name)
    near_u = None if near is None else model.drives_from_dict(dict(near), field="near")
    sol = solve_pose_ik(model, pose.matrix(), near_drives=near_u, options=IKOptions(seed=seed))
    T = model.fk(sol.q)
    return {
        "robot": model.name,
        "drives": model.drives_dict(sol.u),
        "joints": model.joints_dict(sol.q),
        "T_base_tool": [float(v) for v in T.reshape(-1)],
        "position_error_m": sol.position_error_m,
        "orientation_error_rad": sol.orientation_error_rad,
        "min_margin": sol.min_margin,
        "iterations": sol.iterations,
    }


__all__ = ["fk", "fk_document", "ik", "ik_document", "pose_document", "tool_pose_robot"]


def fk(
    robot_name: str,
    drives: Mapping[str, Any] | None,
    joints: Mapping[str, Any] | None,
    guess: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """:class:`~planner.robots.base.KinematicsTools` forward kinematics (see :func:`fk_document`)."""
    if guess is not None:
        raise InvalidInput(f"guess: robot {robot_name!r} has one forward kinematics solution", field="guess")
    return fk_document(robot_name, drives=drives, joints=joints)


def ik(robot_name: str, pose: Any, near: Mapping[str, Any] | None, seed: int) -> dict[str, Any]:
    """:class:`~planner.robots.base.KinematicsTools` inverse kinematics of a tool pose (JSON form)."""
    try:
        target = pose if isinstance(pose, Pose) else Pose.model_validate(pose)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        field = f"pose.{where}" if where else "pose"
        raise InvalidInput(f"{field}: {first['msg']}", field=field) from None
    return ik_document(robot_name, target, near=near, seed=seed)
