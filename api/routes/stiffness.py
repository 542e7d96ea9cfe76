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
from planner.core.schemas import Finite
from planner.documents.stiffness import PayloadInput, stiffness_document

router = APIRouter(tags=["stiffness"])

DriveMap = dict[str, Finite]


class Wrench(BaseModel):
    """An external wrench at the frame origin, base axes: force [N] and moment [N m]."""

    model_config = ConfigDict(extra="forbid")

    force: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    moment: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)


class StiffnessRequest(BaseModel):
    """Exactly one of ``drives`` and ``joints``; the payload frame needs a payload."""

    model_config = ConfigDict(extra="forbid")

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
