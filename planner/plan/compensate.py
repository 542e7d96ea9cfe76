"""Deflection compensation of pose-goal targets: each moved onto the command whose sag lands on the goal.

Uses the stiffness model's :func:`~planner.dynamics.stiffness.compensate_goals`; a compensated target (and
its approach line) must still pass the planner's own state and motion checks, else it is dropped. When every
candidate is dropped the refusal (``compensation_failed``) carries the evidence of each rejected one (the
limit and its excess, the drive and its force ratio, or the closest bodies and their distance against the
required one) and names the one closest to passing, as the goal stage's refusals do.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.core.exceptions import DeflectionNotCompensated
from planner.core.types import Array
from planner.dynamics.stiffness import Compensation, compensate_goals, stiffness_model
from planner.gate.requirements import compensates_deflection
from planner.plan.context import PlanContext
from planner.plan.goals import (
    GoalCandidate,
    collision_evidence,
    describe,
    dominant,
    force_evidence,
    limit_evidence,
)
from planner.plan.motion import MIN_MARGIN_M, path_clear

#: Rejected candidates explained in a refusal (each explanation costs a few exact distance queries).
EXPLAINED_CANDIDATES = 6
#: Largest joint step [m or rad] between the states sampled along a rejected line to find what blocks it.
EXPLAIN_STEP = 0.01
#: Most states sampled along one rejected line.
EXPLAIN_STATES = 60


def compensate_targets(
    ctx: PlanContext, targets: list[Array], lines: list[GoalCandidate | None]
) -> list[Compensation]:
    """Move pose-goal targets onto their deflection-compensated commands (in place); [] when off.

    Raises:
        DeflectionNotCompensated: no candidate survives; ``details['best']`` and ``details['candidates']``
            hold the evidence of the rejected ones (see the module doc).
    """
    sc = ctx.sc
    if not compensates_deflection(sc) or sc.goal_q is not None:
        return []
    assert sc.T_base_payload_goal is not None
    rejected: list[Array] = []

    def accept(path: Array) -> bool:
        ok = _accepted(ctx, path)
        if not ok:
            rejected.append(np.array(path, dtype=float))
        return ok

    T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
    try:
        res = compensate_goals(
            stiffness_model(ctx.robot),
            targets,
            lines,
            sc.T_base_payload_goal,
            ctx.payload,
            T_tool_payload,
            accept,
        )
    except DeflectionNotCompensated as exc:
        records = [explain_rejection(ctx, p) for p in rejected[:EXPLAINED_CANDIDATES]]
        evidence = [e for e in records if e is not None]
        best = dominant(evidence)
        if best is None:
            raise
        raise DeflectionNotCompensated(
            f"{exc.message}; closest: {describe(best)}",
            **exc.details,
            best=best,
            candidates=evidence,
            q=best["q"],
        ) from None
    targets[:], lines[:] = res.targets, res.lines
    ctx.report["compensation"] = {"candidates": len(res.targets), "rejected": res.rejected}
    return res.compensations


def _accepted(ctx: PlanContext, path: Array) -> bool:
    """The planner's own checks of a moved goal: the configuration, or the whole moved approach line."""
    if len(path) == 1:
        return ctx.state_ok(path[0])
    if any(ctx.robot.violations(qi) for qi in path):
        return False
    if len(path) == 2:
        return ctx.state_ok(path[0]) and ctx.state_ok(path[1]) and ctx.motion_ok(*path)
    return path_clear(ctx.world, path, ctx.clearances.planner_m, ctx.clearances.motion_margin_m)


def explain_rejection(ctx: PlanContext, path: Array) -> dict[str, Any] | None:
    """Why a moved goal (one configuration, or an approach line ending at the goal) was rejected.

    The first that applies: a limit or margin outside its bound at a row of ``path``; a row closer to the
    cabin (or a pair of bodies closer) than the planner's clearance, or a row whose static forces exceed the
    allowed fraction; then, along the line sampled every :data:`EXPLAIN_STEP`, the state of the largest
    static force ratio if it is over, else the state of the smallest exact distance, against the clearance
    a motion needs there (the planner's clearance + the certified walk's smallest margin). None when every
    check passes now (nothing to report).
    """
    world, c = ctx.world, ctx.clearances
    path = np.atleast_2d(path)
    steps = np.r_[0.0, np.cumsum(np.max(np.abs(np.diff(path, axis=0)), axis=1))] if len(path) > 1 else [0.0]
    total = float(steps[-1])

    def where(done: float) -> str:
        remaining = 1.0 - done / total if total > 0.0 else 0.0
        if remaining <= 1e-9:
            return "at the compensated goal"
        return f"{100 * remaining:.0f}% of the compensated insertion line before the goal"

    for k, q in enumerate(path):
        violations = ctx.robot.violations(q)
        if violations:
            return limit_evidence(violations, q, where(float(steps[k])))
    for k in reversed(range(len(path))):  # the goal first
        q = path[k]
        if not world.is_valid(q, c.planner_m):
            return collision_evidence(world, q, c.planner_m, where(float(steps[k])))
        if not ctx.forces.ok(q):
            return force_evidence(ctx.forces, q, where(float(steps[k])))
    if len(path) == 1:
        return None
    n = int(min(EXPLAIN_STATES, max(2, np.ceil(total / EXPLAIN_STEP) + 1)))
    s = np.linspace(0.0, total, n)
    dense = np.stack([np.interp(s, steps, path[:, j]) for j in range(path.shape[1])], axis=1)
    ratios = ctx.forces.ratios(dense)
    k = int(np.argmax(ratios))
    if ratios[k] > ctx.forces.fraction:
        return force_evidence(ctx.forces, dense[k], where(float(s[k])))
    distances = [world.min_distance(q).distance_m for q in dense]
    k = int(np.argmin(distances))
    return collision_evidence(world, dense[k], c.planner_m + MIN_MARGIN_M, where(float(s[k])))
