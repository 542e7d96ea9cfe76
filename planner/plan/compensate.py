"""Deflection compensation of pose-goal targets: each moved onto the command whose sag lands on the goal.

Uses the stiffness model's :func:`~planner.dynamics.stiffness.compensate_goals`; a compensated target (and
its approach line) must still pass the planner's own state and motion checks, else it is dropped.
"""

from __future__ import annotations

import numpy as np

from planner.core.types import Array
from planner.dynamics.stiffness import Compensation, compensate_goals, stiffness_model
from planner.gate.requirements import compensates_deflection
from planner.plan.context import PlanContext
from planner.plan.goals import GoalCandidate
from planner.plan.motion import path_clear


def compensate_targets(
    ctx: PlanContext, targets: list[Array], lines: list[GoalCandidate | None]
) -> list[Compensation]:
    """Move pose-goal targets onto their deflection-compensated commands (in place); [] when off."""
    sc = ctx.sc
    if not compensates_deflection(sc) or sc.goal_q is not None:
        return []
    assert sc.T_base_payload_goal is not None

    def accept(path: Array) -> bool:
        if len(path) == 1:
            return ctx.state_ok(path[0])
        if any(ctx.robot.violations(qi) for qi in path):
            return False
        if len(path) == 2:
            return ctx.state_ok(path[0]) and ctx.state_ok(path[1]) and ctx.motion_ok(*path)
        return path_clear(ctx.world, path, ctx.clearances.planner_m, ctx.clearances.motion_margin_m)

    T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
    res = compensate_goals(
        stiffness_model(ctx.robot),
        targets,
        lines,
        sc.T_base_payload_goal,
        ctx.payload,
        T_tool_payload,
        accept,
    )
    targets[:], lines[:] = res.targets, res.lines
    ctx.report["compensation"] = {"candidates": len(res.targets), "rejected": res.rejected}
    return res.compensations
