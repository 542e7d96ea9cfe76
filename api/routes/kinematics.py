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
from planner.robots import available_robots, pprs6_tools
from planner.schemas import Pose

router = APIRouter(tags=["kinematics"])

Finite = Annotated[float, AllowInfNan(False)]
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
    seed: Annotated[int, Field(ge=0, le=2**31 - 1, description="Seed of the random restarts.")] = 0


FK = Callable[[str, DriveMap | None, DriveMap | None, PlatformPose | None], dict[str, Any]]
IK = Callable[[str, Pose | PlatformPose, DriveMap | None, int], dict[str, Any]]


def _wrong_pose(robot: str, expected: str) -> Problem:
    return Problem(
        422,
        "invalid_input",
        f"pose: robot {robot!r} takes {expected}",
        errors=[{"field": "pose", "reason": f"expected {expected}"}],
    )


def _cabin8_fk(
    robot: str, drives: DriveMap | None, joints: DriveMap | None, guess: PlatformPose | None
) -> dict[str, Any]:
    if guess is not None:
        raise Problem(
            422,
            "invalid_input",
            f"guess: robot {robot!r} has one forward kinematics solution; omit guess",
            errors=[{"field": "guess", "reason": "not used by this robot"}],
        )
    return tools.fk_document(robot, drives=drives, joints=joints)


def _cabin8_ik(robot: str, pose: Pose | PlatformPose, near: DriveMap | None, seed: int) -> dict[str, Any]:
    if not isinstance(pose, Pose):
        raise _wrong_pose(robot, "a tool pose {position, orientation}")
    return tools.ik_document(robot, pose, near=near, seed=seed)


def _pprs6_fk(
    robot: str, drives: DriveMap | None, joints: DriveMap | None, guess: PlatformPose | None
) -> dict[str, Any]:
    if drives is None:
        raise Problem(
            422,
            "invalid_input",
            "joints: pprs6 takes drives (w1, w2, beta, s1, s2, s3)",
            errors=[{"field": "joints", "reason": "pprs6 takes drives"}],
        )
    return pprs6_tools.fk_document(drives, None if guess is None else guess.model_dump())


def _pprs6_ik(robot: str, pose: Pose | PlatformPose, near: DriveMap | None, seed: int) -> dict[str, Any]:
    if not isinstance(pose, PlatformPose):
        raise _wrong_pose(robot, "a platform pose {x, y, z, phi, theta, psi}")
    if near is not None:
        raise Problem(
            422,
            "invalid_input",
            "near: pprs6's inverse kinematics has one solution (closed form); omit near",
            errors=[{"field": "near", "reason": "not used by pprs6"}],
        )
    return pprs6_tools.ik_document(pose.model_dump())


#: Kinematics tools by robot name.
TOOLS: dict[str, tuple[FK, IK]] = {"cabin8": (_cabin8_fk, _cabin8_ik), "pprs6": (_pprs6_fk, _pprs6_ik)}


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
    return fk(body.robot, body.drives, body.joints, body.guess)


@router.post("/kinematics/ik", summary="Inverse kinematics of a tool pose")
def inverse(body: IKRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """One admissible solution (drives, joints) with its residuals; unreachable poses give 422."""
    _, ik = _tools(body.robot)
    return ik(body.robot, body.pose, body.near, body.seed)
