"""Single-shot kinematics tools for operator UIs: forward and inverse kinematics of a robot.

Requests name the robot; its tools come from the robot registry
(:func:`planner.tools.kinematics_tools`), so a new mechanism needs no change here. The request models
document both pose forms (a tool pose for cabin8, a platform pose for pprs6); the robot's tools refuse the
form they do not take, naming the field.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter
from pydantic import BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from api.openapi import drive_map_schema, exact_variants
from planner.core.schemas import Finite, Pose
from planner.robots import available_robots, load_robot
from planner.robots.base import RobotModel
from planner.robots.cabin8 import Cabin8
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


DEFAULT_ROBOT = "cabin8"
NULL: dict[str, Any] = {"type": "null"}


def _robot_property(name: str, given: dict[str, Any]) -> dict[str, Any]:
    return {**{k: v for k, v in given.items() if k in ("description", "title")}, "const": name}


def robot_variants(
    properties: dict[str, Any], forms: Callable[[str, RobotModel, dict[str, Any]], list[dict[str, Any]]]
) -> list[dict[str, Any]]:
    """One exact body per robot of the registry and per form it takes (see :func:`exact_variants`).

    ``forms(name, model, properties)`` gives the robot's variants without ``robot``; it is added here,
    required unless the robot is the default one.
    """
    out = []
    for name in available_robots():
        for variant in forms(name, load_robot(name), properties):
            props = {"robot": _robot_property(name, properties["robot"]), **variant["properties"]}
            required = list(variant.get("required", []))
            if name != DEFAULT_ROBOT:
                required.insert(0, "robot")
            out.append(
                {"type": "object", "properties": props, "required": required, "additionalProperties": False}
            )
    return out


def _fk_forms(name: str, model: RobotModel, p: dict[str, Any]) -> list[dict[str, Any]]:
    drives = {**doc_of(p["drives"]), **drive_map_schema(model.drive_names)}
    if isinstance(model, Cabin8):  # drives or joints; one assembly: no guess
        joints = {**doc_of(p["joints"]), **drive_map_schema(model.joint_names)}
        return [
            {"properties": {"drives": drives, "joints": NULL, "guess": NULL}, "required": ["drives"]},
            {"properties": {"drives": NULL, "joints": joints, "guess": NULL}, "required": ["joints"]},
        ]
    return [{"properties": {"drives": drives, "joints": NULL, "guess": p["guess"]}, "required": ["drives"]}]


def _ik_forms(name: str, model: RobotModel, p: dict[str, Any]) -> list[dict[str, Any]]:
    poses = p["pose"]["anyOf"]  # [Pose (tool pose), PlatformPose]
    if isinstance(model, Cabin8):
        near = {"anyOf": [drive_map_schema(model.drive_names), NULL], **doc_of(p["near"])}
        return [{"properties": {"pose": poses[0], "near": near, "seed": p["seed"]}, "required": ["pose"]}]
    return [{"properties": {"pose": poses[1], "near": NULL, "seed": {"const": 0}}, "required": ["pose"]}]


def doc_of(prop: dict[str, Any]) -> dict[str, Any]:
    """The description and title of a generated property schema (kept on its exact replacement)."""
    return {k: v for k, v in prop.items() if k in ("description", "title")}


class FKRequest(BaseModel):
    """Forward kinematics: exactly one of ``drives`` and ``joints`` (m, rad), named as the robot names them.

    The published schema is exact (:func:`robot_variants`): one variant per robot and form, every drive
    (joint) of the robot named once. A body it accepts is refused only by physics: a configuration the
    mechanism cannot assemble (422 ``outside_workspace``, pprs6 ``fk_not_converged``).
    """

    model_config = ConfigDict(
        extra="forbid", json_schema_extra=exact_variants(lambda p: robot_variants(p, _fk_forms))
    )

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
    """Inverse kinematics of a tool pose in the base frame (cabin8) or of a platform pose (pprs6).

    The published schema is exact per robot (:func:`robot_variants`); a body it accepts is refused only
    by physics (a pose out of reach).
    """

    model_config = ConfigDict(
        extra="forbid", json_schema_extra=exact_variants(lambda p: robot_variants(p, _ik_forms))
    )

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
