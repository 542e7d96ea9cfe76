"""The report stage: lower bounds of the duration and the predicted deflection along the profile."""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.core.types import Array
from planner.dynamics.compensation import Compensation
from planner.dynamics.stiffness import StaticDeflection, stiffness_model
from planner.gate.drive_checks import GateReport
from planner.gate.requirements import deflection_sample_indices, stiffness_provenance
from planner.plan.context import PlanContext
from planner.plan.goals import GoalCandidate
from planner.timing.profile import DriveProfile


def single_drive_lower_bound(robot: Any, u0: Array, u1: Array) -> float:
    """Rest-to-rest time of the slowest drive moving alone from u0 to u1 (v_max, a_max), a lower bound."""
    d = np.abs(np.asarray(u1) - np.asarray(u0))
    v, a = robot.limits.v_max, robot.limits.a_max
    t = np.where(d > v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))
    return float(np.max(t))


def duration_report(ctx: PlanContext, profile: DriveProfile, line: GoalCandidate | None) -> None:
    """The duration against its single-drive lower bound (and the staged bound of an insertion)."""
    robot = ctx.robot
    bound = single_drive_lower_bound(robot, profile.position[0], profile.position[-1])
    ctx.report.update(
        duration_s=profile.duration_s,
        single_drive_lower_bound_s=bound,
        duration_ratio=profile.duration_s / bound if bound > 0 else 1.0,
    )
    if line is not None and line.line is not None:
        # With an insertion the robot stops at the pre-insertion pose, so no trajectory of this shape
        # beats the single-drive bound to it plus the one along the line.
        u_pre = robot.drives_from_joints(line.line[0])
        staged = single_drive_lower_bound(robot, profile.position[0], u_pre) + single_drive_lower_bound(
            robot, u_pre, profile.position[-1]
        )
        ctx.report.update(
            staged_lower_bound_s=staged,
            staged_duration_ratio=profile.duration_s / staged if staged > 0 else 1.0,
        )


def deflection_report(
    ctx: PlanContext, profile: DriveProfile, comp: Compensation | None, gate: GateReport | None = None
) -> Array | None:
    """Predicted payload-frame deflection along the profile into the report; (N, 6) or None.

    The numbers the gate's sagging certificate used where it evaluated them (``gate.deflection``: the
    same model, load and samples), else the model's own evaluation.
    """
    sc = ctx.sc
    if ctx.robot.desc.stiffness is None or not sc.deflection_series:
        _goal_report(ctx, comp)
        return None
    T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
    # The deflection is a smooth function of the configuration: predicted at up to a few hundred samples
    # where the robot moves (deflection_sample_indices) and interpolated in between, for the report and plot.
    n = len(profile.joints)
    if gate is not None and gate.deflection is not None and len(profile.joints) == gate.samples:
        idx, x_at = gate.deflection
    else:
        idx = deflection_sample_indices(profile.joints)
        x_at = stiffness_model(ctx.robot).deflection_along(profile.joints[idx], ctx.payload, T_tool_payload)
    x = np.column_stack([np.interp(np.arange(n), idx, x_at[:, j]) for j in range(6)])
    tr, rot = np.linalg.norm(x[:, :3], axis=1), np.linalg.norm(x[:, 3:], axis=1)
    every = -(-len(idx) // 100)  # at most 100 points of the series in the report
    ctx.report["deflection"] = {
        "frame": "payload" if sc.payload is not None else "tool",
        "max_translation_m": float(tr.max()),
        "max_rotation_rad": float(rot.max()),
        "at_goal": StaticDeflection(x[-1, :3], x[-1, 3:]).to_dict(),
        "compensated": comp is not None,
        "stiffness": stiffness_provenance(sc),
        # The predicted deflection along the trajectory, at up to 100 of those samples.
        "along": {
            "t_s": profile.t[idx[::every]].round(4).tolist(),
            "translation_m": x_at[::every, :3].tolist(),
            "rotation_rad": x_at[::every, 3:].tolist(),
        },
    }
    _goal_report(ctx, comp)
    return x


def _goal_report(ctx: PlanContext, comp: Compensation | None) -> None:
    """The compensated goal into the report (nominal and commanded poses, residuals), if compensated."""
    if comp is not None:
        doc = comp.to_dict()
        ctx.report["goal"] = {
            "nominal": doc["nominal"],
            "compensated": doc["compensated"],
            "residual_m": comp.residual_m,
            "residual_rad": comp.residual_rad,
            "iterations": doc["iterations"],
        }
