"""Controller and tool exports of a succeeded plan: ``GET /plans/{id}/trajectory?format=...``.

The formats are :mod:`planner.documents.exports`': ``ros2-json`` and ``ros2-yaml`` (a
``control_msgs/action/FollowJointTrajectory`` goal), ``mcap`` (the ``.mcap`` file of a rosbag2 bag: joint
states, the trajectory, the exact clearance per frame, events). ``spacing_s`` thins the trajectory points
where the controller's quintic interpolation keeps every sample within 1e-5 and the drive limits.
409 while the plan is queued or running and for a refused plan (it has no trajectory); 422 for a bad
format or spacing. Exports are immutable for a finished plan and kept in a small in-process cache.
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Response

from api.auth import CurrentPrincipal
from api.problems import Problem
from api.routes.deps import Ctx
from api.routes.jobroutes import result_json
from api.routes.scene import _finished_job, _resolved
from planner.core.exceptions import InvalidInput
from planner.core.lru import BoundedLRU

router = APIRouter(tags=["exports"])

_EXPORTS: BoundedLRU[str, bytes] = BoundedLRU(8)
_FILE_SUFFIX = {"ros2-json": "json", "ros2-yaml": "yaml", "mcap": "mcap"}


@router.get(
    "/plans/{plan_id}/trajectory",
    summary="The plan as a ROS 2 FollowJointTrajectory goal (JSON/YAML) or a rosbag2 MCAP file",
    response_class=Response,
    responses={
        200: {"content": {"application/json": {}, "application/yaml": {}, "application/x-mcap": {}}},
    },
)
def get_trajectory(
    plan_id: str,
    ctx: Ctx,
    principal: CurrentPrincipal,
    format: Annotated[  # noqa: A002 - the query parameter's public name
        Literal["ros2-json", "ros2-yaml", "mcap"], Query(description="Export format.")
    ] = "ros2-json",
    spacing_s: Annotated[
        float | None,
        Query(gt=0.0, le=10.0, description="Thin the trajectory points to this spacing [s] (default: all)."),
    ] = None,
) -> Response:
    """The export of a succeeded plan (see :mod:`planner.documents.exports`)."""
    from planner.documents import exports

    row = _finished_job(ctx, principal.tenant, plan_id)
    if row.status != "succeeded":
        raise Problem(409, "plan_not_succeeded", f"plan {plan_id} is {row.status}: it has no trajectory")
    found = result_json(ctx, row) or b""
    digest = hashlib.sha256(found).hexdigest()
    key = f"{row.id}:{digest}:{format}:{spacing_s!r}"
    body = _EXPORTS.get(key)
    media = {"ros2-json": "application/json", "ros2-yaml": "application/yaml", "mcap": "application/x-mcap"}
    if body is None:
        doc: dict[str, Any] = json.loads(found)
        clearance = None
        if format == "mcap":
            try:  # the exact clearance per frame needs the plan's cabin; a deleted one leaves it out
                clearance = exports.clearance_series(_resolved(ctx, row), doc)
            except Problem:
                clearance = None
        try:
            body, _ = exports.export_bytes(
                doc, format, spacing_s=spacing_s, clearance=clearance, scratch=ctx.settings.data_dir
            )
        except InvalidInput as exc:
            raise Problem(
                422,
                "invalid_input",
                exc.message,
                errors=[{"field": str(exc.details.get("field", "format")), "reason": exc.message}],
            ) from None
        _EXPORTS.put(key, body)
    name = f"plan-{row.id}.{_FILE_SUFFIX[format]}"
    return Response(
        body, media_type=media[format], headers={"Content-Disposition": f'attachment; filename="{name}"'}
    )
