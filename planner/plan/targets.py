"""The goal stage: the configurations the global search must reach, each with its approach line (or None).

A drive-space goal is one configuration. A pose goal becomes several exact goal configurations
(:func:`planner.plan.goals.goal_configurations`); with an approach, lines of fixed redundancy are tried
first (:func:`~planner.plan.goals.approach_lines`), then each candidate is tracked back along the line with
the redundancy free (:func:`~planner.plan.goals.track_approach`); the search targets the pre-insertion ends.
"""

from __future__ import annotations

from typing import Any

from planner.core.exceptions import ApproachInfeasible, GoalInCollision, GoalUnreachable
from planner.core.types import Array
from planner.plan.context import PlanContext
from planner.plan.endpoints import check_configuration
from planner.plan.evidence import describe, dominant
from planner.plan.goals import GoalCandidate, approach_lines, goal_configurations, track_approach

#: Goal candidates tracked back along the approach line when no line of fixed redundancy is clear.
TRACKED_CANDIDATES = 4


def goal_targets(ctx: PlanContext) -> tuple[list[Array], list[GoalCandidate | None]]:
    """Configurations the global search must reach, and for each its approach line (or None).

    Raises:
        GoalUnreachable, GoalInCollision, ApproachInfeasible: no target, with the counts that explain why.
    """
    sc, c = ctx.sc, ctx.clearances
    evidence: list[dict[str, Any]] = []
    if sc.goal_q is not None:
        check_configuration(ctx, sc.goal_q, "goal")
        return [sc.goal_q], [None]
    assert sc.T_base_tool_goal is not None
    if sc.approach_direction is not None:
        lines, line_stats = approach_lines(
            ctx.world,
            sc.T_base_tool_goal,
            sc.approach_direction,
            sc.approach_distance_m,
            c.planner_m,
            c.motion_margin_m,
            ctx.forces,
            evidence=evidence,
        )
        ctx.report["approach"] = {"method": "fixed_redundancy", "lines": len(lines), **line_stats}
        lines = [x for x in lines if x.line is not None]  # targets and their lines stay aligned
        if lines:
            return [x.line[0] for x in lines if x.line is not None], list(lines)
    cands, stats = goal_configurations(
        ctx.world, sc.T_base_tool_goal, c.planner_m, ctx.forces, sc.start_u, evidence=evidence
    )
    ctx.report["goal_candidates"] = {"found": len(cands), **stats}
    if not cands:
        if stats["family_points"] == 0:
            raise GoalUnreachable("goal pose: no admissible configuration of the robot reaches it", **stats)
        collided = stats["collision"] >= max(stats["force"], 1)
        best = dominant(evidence, "clearance" if collided else "force")
        cause = f"; closest: {describe(best)}" if best is not None else ""
        if collided:
            raise GoalInCollision(
                "goal pose: every configuration reaching it comes within the clearance of the cabin "
                f"or of itself{cause}",
                **stats,
                best=best,
                candidates=evidence,
                **({"q": best["q"]} if best is not None else {}),
            )
        raise GoalUnreachable(
            "goal pose: no configuration reaching it can hold the payload within the drive force limits"
            f"{cause}",
            **stats,
            best=best,
            candidates=evidence,
            **({"q": best["q"]} if best is not None else {}),
        )
    if sc.approach_direction is None:
        return [x.q for x in cands], [None] * len(cands)
    # Fallback: let the redundancy vary along the line (QP differential IK, step by step).
    tracked: list[GoalCandidate] = []
    for cand in cands[:TRACKED_CANDIDATES]:
        tr = track_approach(
            ctx.world,
            cand,
            sc.T_base_tool_goal,
            sc.approach_direction,
            sc.approach_distance_m,
            ctx.opts.approach_step_m,
            c.planner_m,
            c.motion_margin_m,
            ctx.forces,
            evidence=evidence,
        )
        if tr is not None:
            tracked.append(tr)
    if not tracked:
        best = dominant(evidence)
        cause = f"; closest: {describe(best)}" if best is not None else ""
        raise ApproachInfeasible(
            f"approach: no goal configuration can be tracked {sc.approach_distance_m} m back along the "
            f"line within limits, margins, force limits and clearance{cause}",
            tracked_candidates=len(cands[:TRACKED_CANDIDATES]),
            best=best,
            candidates=evidence,
            **({"q": best["q"]} if best is not None else {}),
        )
    tracked.sort(key=lambda x: -x.clearance_m)
    ctx.report["approach"].update(
        method="tracked",
        candidates_tracked=len(tracked),
        line_clearance_m=[round(x.clearance_m, 4) for x in tracked],
    )
    return [x.line[0] for x in tracked if x.line is not None], list(tracked)
