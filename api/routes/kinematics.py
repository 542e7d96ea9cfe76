"""Single-shot kinematics tools for operator UIs: forward and inverse kinematics of a robot.

Requests name the robot; the tool set is chosen by robot name (:data:`TOOLS`), so a mechanism with its
own kinematics adds an entry (or its own router module, ``api/routes/<robot>.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter
from pydantic import AllowInfNan, BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from api.problems import Problem
from planner import tools
from planner.robots import available_robots
from planner.schemas import Pose

router = APIRouter(tags=["kinematics"])

DriveMap = dict[str, Annotated[float, AllowInfNan(False)]]


class FKRequest(BaseModel):
    """Forward kinematics: exactly one of ``drives`` and ``joints`` (m, rad)."""

    model_config = ConfigDict(extra="forbid")

    robot: Annotated[str, Field(max_length=64, description="Robot registry name, e.g. cabin8.")] = "cabin8"
    drives: Annotated[DriveMap | None, Field(description="Drive name -> position [m, rad].")] = None
    joints: Annotated[DriveMap | None, Field(description="Joint name -> value [m, rad].")] = None


class IKRequest(BaseModel):
    """Inverse kinematics of a tool pose in the base frame."""

    model_config = ConfigDict(extra="forbid")

    robot: Annotated[str, Field(max_length=64, description="Robot registry name, e.g. cabin8.")] = "cabin8"
    pose: Annotated[Pose, Field(description="Tool frame in the base frame (m, unit quaternion {w,x,y,z}).")]
    near: Annotated[DriveMap | None, Field(description="Prefer the solution nearest these drives.")] = None
    seed: Annotated[int, Field(ge=0, le=2**31 - 1, description="Seed of the random restarts.")] = 0


FK = Callable[[str, DriveMap | None, DriveMap | None], dict[str, Any]]
IK = Callable[[str, Pose, DriveMap | None, int], dict[str, Any]]


def _cabin8_fk(robot: str, drives: DriveMap | None, joints: DriveMap | None) -> dict[str, Any]:
    return tools.fk_document(robot, drives=drives, joints=joints)


def _cabin8_ik(robot: str, pose: Pose, near: DriveMap | None, seed: int) -> dict[str, Any]:
    return tools.ik_document(robot, pose, near=near, seed=seed)


#: Kinematics tools by robot name.
TOOLS: dict[str, tuple[FK, IK]] = {"cabin8": (_cabin8_fk, _cabin8_ik)}


def _tools(robot: str) -> tuple[FK, IK]:
    if robot not in available_robots():
        raise Problem(
            422,
            "unknown_robot",
            f"robot: unknown robot {robot!r}; available: {', '.join(available_robots())}",
            errors=[{"field": "robot", "reason": "unknown robot"}],
        )
    if robot not in TOOLS:
        raise Problem(
            422,
            "invalid_input",
            f"robot: {robot!r} has no kinematics tools on this route",
            errors=[{"field": "robot", "reason": "no kinematics tools"}],
        )
    return TOOLS[robot]


@router.post("/kinematics/fk", summary="Forward kinematics")
def forward(body: FKRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """Joints, drives, ``T_base_tool`` (row-major 4x4), pose, and every violated limit or margin."""
    fk, _ = _tools(body.robot)
    if (body.drives is None) == (body.joints is None):
        raise Problem(
            422,
            "invalid_input",
            "give exactly one of drives or joints",
            errors=[{"field": "drives", "reason": "exactly one of drives and joints"}],
        )
    return fk(body.robot, body.drives, body.joints)


@router.post("/kinematics/ik", summary="Inverse kinematics of a tool pose")
def inverse(body: IKRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """One admissible solution (drives, joints) with its residuals; unreachable poses give 422."""
    _, ik = _tools(body.robot)
    return ik(body.robot, body.pose, body.near, body.seed)
