"""Robot models: drives, units, limits and geometry summary of every registered robot."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from api.auth import CurrentPrincipal
from api.problems import Problem
from planner.robots import available_robots, load_robot

router = APIRouter(tags=["robots"])


@router.get("/robots", summary="Every registered robot model")
def list_robots(_principal: CurrentPrincipal) -> dict[str, Any]:
    """``{"items": [summary, ...]}``: one summary per registered robot (see ``GET /robots/{id}``)."""
    return {"items": [load_robot(name).summary() for name in available_robots()]}


@router.get("/robots/{robot_id}", summary="One robot model")
def get_robot(robot_id: str, _principal: CurrentPrincipal) -> dict[str, Any]:
    """The model summary: drives with units and limits, joints, frames, geometry, description hash."""
    if robot_id not in available_robots():
        raise Problem(404, "not_found", f"no robot {robot_id!r}; available: {', '.join(available_robots())}")
    summary: dict[str, Any] = load_robot(robot_id).summary()
    return summary
