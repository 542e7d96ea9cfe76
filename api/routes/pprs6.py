"""The pprs6 platform's own tools: workspace at an orientation, and pose path -> validated drive profile.

FK and IK of pprs6 go through the generic ``/kinematics`` routes (``"robot": "pprs6"``). Both tools here are
synchronous and bounded: the workspace grid step has a floor (a 5 mm search takes a few seconds) and
results are cached per request body, and a pose path has at most :data:`MAX_WAYPOINTS` waypoints. Add
``?format=png`` for the picture (three orthogonal views of the workspace; the six drive displacements
against time, paper Fig. 7) instead of the JSON document.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Response
from pydantic import BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from api.problems import SafeJSONResponse
from api.routes.kinematics import PlatformPose
from planner.core.schemas import Finite
from planner.tools import pprs6 as pprs6_tools

router = APIRouter(tags=["pprs6"])

#: Waypoints of one pose path (a request is bounded, not only by the body size limit).
MAX_WAYPOINTS = 100
Format = Annotated[Literal["json", "png"], Query(description="json: the document; png: the picture.")]


class Orientation(BaseModel):
    """Platform orientation R = RotZ(phi) RotY(theta) RotX(psi) [rad]."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    phi: Finite = 0.0
    theta: Finite = 0.0
    psi: Finite = 0.0


class WorkspaceRequest(BaseModel):
    """Reachable positions of the platform centre at a fixed orientation (boundary search)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    orientation: Orientation = Orientation()
    step_m: Annotated[float, Field(ge=0.004, le=0.02, description="Grid step of the fine pass [m].")] = 0.005


class Waypoint(PlatformPose):
    """A platform pose on the path (centre [m], angles [rad]) with an optional label."""

    name: Annotated[str | None, Field(max_length=40)] = None


class PosePath(BaseModel):
    """A polyline of platform poses, time-parameterised rest to rest at every waypoint."""

    model_config = ConfigDict(extra="forbid")

    name: Annotated[str | None, Field(max_length=100)] = None
    closed: bool = False
    max_condition: Annotated[
        Finite | None, Field(gt=1.0, le=1e6, description="Refuse worse-conditioned poses.")
    ] = None
    sample_period_s: Annotated[float | None, Field(gt=0.0, le=0.1, description="Controller period [s].")] = (
        None
    )
    waypoints: Annotated[list[Waypoint], Field(min_length=2, max_length=MAX_WAYPOINTS)]


class ProfileRequest(BaseModel):
    """A pose path; without one, the paper's closed path E-F-G-H-E (Fig. 6)."""

    model_config = ConfigDict(extra="forbid")

    path: PosePath | None = None


@lru_cache(maxsize=32)
def _workspace(body: WorkspaceRequest, png: bool) -> tuple[dict[str, Any], bytes]:
    return pprs6_tools.workspace_document(body.orientation.model_dump(), body.step_m, png=png)


#: The two answers of an operation with ``?format=json|png`` (both documented: a client reads either).
_JSON_OR_PNG: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/json": {}, "image/png": {}}, "description": "JSON, or PNG with format=png"}
}


@router.post(
    "/robots/pprs6/workspace",
    summary="pprs6 workspace at an orientation (JSON or PNG)",
    response_class=Response,
    responses=_JSON_OR_PNG,
)
def workspace(body: WorkspaceRequest, _principal: CurrentPrincipal, format: Format = "json") -> Response:
    """Volume [m^3], extents [m], sizes and conditioning over the reachable grid; or the three views.

    An orientation with no reachable position gives a volume of 0 (and an empty picture), not an error.
    """
    if format == "png":
        return Response(_workspace(body, True)[1], media_type="image/png")
    doc = _workspace(body, False)[0]
    return SafeJSONResponse(doc)


@router.post(
    "/robots/pprs6/profiles",
    summary="pprs6 pose path -> validated drive profile (JSON or PNG)",
    response_class=Response,
    responses=_JSON_OR_PNG,
)
def profile(body: ProfileRequest, _principal: CurrentPrincipal, format: Format = "json") -> Response:
    """Drive positions, velocities and accelerations at the controller period, every sample validated.

    A path that leaves the workspace, nears a singularity or has no admissible time law is refused (422
    with the reason); a profile that fails the validation gate is never returned.
    """
    spec = None if body.path is None else body.path.model_dump(exclude_none=True)
    doc = pprs6_tools.profile_document(spec)
    if format == "png":
        return Response(pprs6_tools.profile_png(doc), media_type="image/png")
    return SafeJSONResponse(doc)
