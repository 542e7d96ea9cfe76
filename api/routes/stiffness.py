"""Cartesian stiffness and static deflection of one configuration (paper section 4).

``POST /stiffness``: a configuration (drives or joints), an optional payload and external wrench -> the
6x6 stiffness K and compliance C at the tool or payload frame and the deflection under gravity (payload
and links) and the wrench. The same document as ``cabinplan stiffness``
(:func:`planner.documents.stiffness.stiffness_document`).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter
from pydantic import BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from api.openapi import drive_map_schema, exact_variants
from api.routes.kinematics import NULL, doc_of, robot_variants
from planner.core.schemas import Finite
from planner.documents.stiffness import PayloadInput, stiffness_document
from planner.robots.base import RobotModel
from planner.robots.cabin8 import Cabin8

router = APIRouter(tags=["stiffness"])

DriveMap = dict[str, Finite]


class Wrench(BaseModel):
    """An external wrench at the frame origin, base axes: force [N] and moment [N m]."""

    model_config = ConfigDict(extra="forbid")

    force: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    moment: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)


def _stiffness_forms(name: str, model: RobotModel, p: dict[str, Any]) -> list[dict[str, Any]]:
    """Drives (within their limits) or joints (the serial ones within theirs), times the two frames."""
    if not isinstance(model, Cabin8):  # no tool-pose kinematics: no stiffness model
        return []
    lim = model.limits
    drives = {**doc_of(p["drives"]), **drive_map_schema(model.drive_names, lim.lower, lim.upper)}
    joints = drive_map_schema(model.joint_names)
    for k, joint in enumerate(model.drive_names):  # the serial joints are drives of the same name
        if joint in joints["properties"]:
            joints["properties"][joint].update(minimum=float(lim.lower[k]), maximum=float(lim.upper[k]))
    joints.update(doc_of(p["joints"]))
    common = {"wrench": p["wrench"]}
    frames = [
        ({"payload": p["payload"], "frame": {"const": "tool", **doc_of(p["frame"])}}, []),
        (
            {"payload": p["payload"]["anyOf"][0], "frame": {"const": "payload", **doc_of(p["frame"])}},
            ["payload", "frame"],
        ),
    ]
    out = []
    for config, form in (
        ({"drives": drives, "joints": NULL}, "drives"),
        ({"drives": NULL, "joints": joints}, "joints"),
    ):
        for frame_props, required in frames:
            out.append({"properties": {**config, **common, **frame_props}, "required": [form, *required]})
    return out


class StiffnessRequest(BaseModel):
    """Exactly one of ``drives`` and ``joints``; the payload frame needs a payload.

    The published schema is exact (:func:`api.routes.kinematics.robot_variants`): the robots with a
    stiffness model, every drive named once within its limits (or every joint), a payload with the
    payload frame. A body it accepts is refused only by physics: a stage that does not assemble (422
    ``outside_workspace``), slider positions implied by a platform pose beyond their travel
    (``limit_violation``).
    """

    model_config = ConfigDict(
        extra="forbid", json_schema_extra=exact_variants(lambda p: robot_variants(p, _stiffness_forms))
    )

    robot: Annotated[str, Field(max_length=64, description="Robot registry name.")] = "cabin8"
    drives: Annotated[DriveMap | None, Field(description="Drive name -> position [m, rad].")] = None
    joints: Annotated[DriveMap | None, Field(description="Joint name -> value [m, rad].")] = None
    wrench: Wrench | None = None
    payload: PayloadInput | None = None
    frame: Literal["tool", "payload"] = "tool"


@router.post("/stiffness", summary="Stiffness, compliance and deflection at a configuration")
def stiffness(body: StiffnessRequest, _principal: CurrentPrincipal) -> dict[str, Any]:
    """K and C (6x6 row-major, at the frame origin, base axes) and the gravity / wrench / total deflection.

    A configuration outside the limits or off the stage's working branch is 422 with the reason.
    """
    return stiffness_document(
        body.robot,
        drives=body.drives,
        joints=body.joints,
        wrench=None if body.wrench is None else body.wrench.model_dump(),
        payload=None if body.payload is None else body.payload.model_dump(),
        frame=body.frame,
    )
