"""Deflection compensation of pose-goal targets: each moved onto the command whose sag lands on the goal.

Uses :func:`~planner.dynamics.compensation.compensate_goals` under the plan's load case (payload,
grasp); a compensated target (and its approach line) must still pass the planner's own state and motion
checks, else it is dropped. When every
candidate is dropped the refusal (``compensation_failed``) carries the evidence of each rejected one (the
limit and its excess, the drive and its force ratio, or the closest bodies and their distance against the
required one) and names the one closest to passing, as the goal stage's refusals do.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.core.exceptions import DeflectionNotCompensated
from planner.core.types import Array
from planner.dynamics.compensation import Compensation, compensate_goals
from planner.dynamics.stiffness import LoadCase, stiffness_model
from planner.gate.requirements import compensates_deflection
from planner.plan.context import PlanContext
from planner.plan.evidence import collision_evidence, describe, dominant, force_evidence, limit_evidence
from planner.plan.goals import GoalCandidate
from planner.plan.motion import MIN_MARGIN_M, certify_motion, path_clear, spare_clearance

#: Rejected candidates explained in a refusal (each explanation costs a few exact distance queries).
EXPLAINED_CANDIDATES = 6
#: Largest joint step [m or rad] between the states sampled along a rejected line to find what blocks it
#: (the motion walk checks limits every 5 mm; the certified walk itself locates a clearance failure).
EXPLAIN_STEP = 0.005
#: Most states sampled along one segment of a rejected line.
EXPLAIN_STATES = 200


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
            LoadCase(ctx.payload, T_tool_payload),
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

    The first that applies, as the planner's own checks found it: a limit or margin outside its bound at a
    row of ``path`` or at a state sampled along it every :data:`EXPLAIN_STEP`; a row closer to the cabin (or
    a robot pair closer) than the planner's clearance, or a row whose static forces exceed the allowed
    fraction; along the line, the state of the largest static force ratio if it is over; then the first
    segment whose certified motion check (with its adaptive margin) fails, at the state where it failed,
    against the clearance a motion needs there (the planner's clearance, or the self-clearance, + the
    walk's smallest margin). Where the walk gives no state, the sampled state with the smallest spare
    clearance. "Where" is the share of the insertion line still ahead of the goal, measured along the tool's
    path. None when every check passes now (nothing to report).
    """
    world, c = ctx.world, ctx.clearances
    path = np.atleast_2d(np.asarray(path, dtype=float))
    tool = np.array([ctx.robot.fk(q)[:3, 3] for q in path])
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(tool, axis=0), axis=1))]
    total = float(along[-1])

    def where(k: int, t: float = 0.0) -> str:
        done = along[k] + (t * (along[k + 1] - along[k]) if k + 1 < len(along) else 0.0)
        remaining = 1.0 - done / total if total > 0.0 else 0.0
        if remaining <= 1e-9:
            return "at the compensated goal"
        return f"{100 * remaining:.0f}% of the compensated insertion line before the goal"

    # The rows, then states every EXPLAIN_STEP (largest joint change) along each segment, with their place.
    states: list[tuple[Array, int, float]] = [(q, k, 0.0) for k, q in enumerate(path)]
    for k in range(len(path) - 1):
        n = int(min(EXPLAIN_STATES, max(1, np.ceil(np.max(np.abs(path[k + 1] - path[k])) / EXPLAIN_STEP))))
        states += [(path[k] + t * (path[k + 1] - path[k]), k, t) for t in np.arange(1, n) / n]
    for q, k, t in states:
        violations = ctx.robot.violations(q)
        if violations:
            return limit_evidence(violations, q, where(k, t))
    for k in reversed(range(len(path))):  # the goal first
        q = path[k]
        if not world.is_valid(q, c.planner_m):
            return collision_evidence(world, q, c.planner_m, where(k))
        if not ctx.forces.ok(q):
            return force_evidence(ctx.forces, q, where(k))
    if len(path) == 1:
        return None
    ratios = ctx.forces.ratios(np.array([q for q, _, _ in states]))
    i = int(np.argmax(ratios))
    if ratios[i] > ctx.forces.fraction:
        q, k, t = states[i]
        return force_evidence(ctx.forces, q, where(k, t))
    for k in range(len(path) - 1):
        motion = certify_motion(world, path[k], path[k + 1], c.planner_m, c.motion_margin_m)
        if not motion.valid and motion.report.t_fail is not None:
            t = float(motion.report.t_fail)
            q = path[k] + t * (path[k + 1] - path[k])
            return collision_evidence(world, q, c.planner_m, where(k, t), margin_m=MIN_MARGIN_M)
    spare = [spare_clearance(world, q, c.planner_m) for q, _, _ in states]
    q, k, t = states[int(np.argmin(spare))]
    return collision_evidence(world, q, c.planner_m, where(k, t), margin_m=MIN_MARGIN_M)
