"""Single-shot kinematics tools for operator UIs: forward and inverse kinematics of a robot.

Requests name the robot; its tools come from the robot registry
(:func:`planner.tools.kinematics_tools`), so a new mechanism needs no change here. The request models
document both pose forms (a tool pose for cabin8, a platform pose for pprs6); the robot's tools refuse the
form they do not take, naming the field.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter
from pydantic import BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from planner.core.schemas import Finite, Pose
from planner.scenario import MAX_SEED
from planner.tools import kinematics_tools

router = APIRouter(tags=["kinematics"])

DriveMap = dict[str, Finite]


class PlatformPose(BaseModel):
    """A moving-platform pose (pprs6): centre O1 in the fixed frame [m], RotZ(phi) RotY(theta) RotX(psi)."""

    model_config = ConfigDict(extra="forbid")

    x: Finite
    y: Finite
    z: Finite
    phi: Finite = 0.0
    theta: Finite = 0.0
    psi: Finite = 0.0


class FKRequest(BaseModel):
    """Forward kinematics: exactly one of ``drives`` and ``joints`` (m, rad)."""

    model_config = ConfigDict(extra="forbid")

    robot: Annotated[str, Field(max_length=64, description="Robot registry name, e.g. cabin8.")] = "cabin8"
    drives: Annotated[DriveMap | None, Field(description="Drive name -> position [m, rad].")] = None
    joints: Annotated[DriveMap | None, Field(description="Joint name -> value [m, rad].")] = None
    guess: Annotated[
        PlatformPose | None,
        Field(
            description="pprs6 only: the pose to start from; its forward kinematics has several assembly "
            "modes and the one connected to the guess is returned (default: the home pose)."
        ),
    ] = None


class IKRequest(BaseModel):
    """Inverse kinematics of a tool pose in the base frame (cabin8) or of a platform pose (pprs6)."""

    model_config = ConfigDict(extra="forbid")

    robot: Annotated[str, Field(max_length=64, description="Robot registry name, e.g. cabin8.")] = "cabin8"
    pose: Annotated[
        Pose | PlatformPose,
        Field(
            description="cabin8: tool frame in the base frame {position [m], orientation {w,x,y,z}}; "
            "pprs6: platform pose {x, y, z [m], phi, theta, psi [rad]}."
        ),
    ]
    near: Annotated[DriveMap | None, Field(description="Prefer the solution nearest these drives.")] = None
    seed: Annotated[int, Field(ge=0, le=MAX_SEED, description="Seed of the random restarts.")] = 0


@router.post("/kinematics/fk", summary="Forward kinematics")
def forward(body: FKRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """Joints, drives, ``T_base_tool`` (row-major 4x4), pose, and every violated limit or margin."""
    guess = None if body.guess is None else body.guess.model_dump()
    return kinematics_tools(body.robot).fk(body.robot, body.drives, body.joints, guess)


@router.post("/kinematics/ik", summary="Inverse kinematics of a tool pose")
def inverse(body: IKRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """One admissible solution (drives, joints) with its residuals; unreachable poses give 422."""
    return kinematics_tools(body.robot).ik(body.robot, body.pose.model_dump(), body.near, body.seed)
