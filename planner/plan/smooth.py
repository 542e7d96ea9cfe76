"""The smoothing stage: corners become certified C2 blends; legs split where the robot must stop.

The blends (:class:`~planner.timing.path.BlendPiece`, quintic Bezier) have zero curvature where they meet
the straight segments, so the drive accelerations of a jerk-limited law do not step there.

A corner's blend takes :data:`BLEND_FRACTIONS` of the shorter neighbouring segment, shrunk through the
sequence (and left sharp, the robot stopping there, at 0) until the blend is admissible, holdable and
certified clear with the blend clearance of :class:`~planner.plan.context.Clearances`.
"""

from __future__ import annotations

import numpy as np

from planner.core.types import Array
from planner.plan.context import PlanContext
from planner.timing.path import JointPath, LinePiece, blended_polyline, segment_time_length

#: Blend half-length as a fraction of the shorter neighbouring segment, then the shrink sequence.
BLEND_FRACTIONS = (0.45, 0.2, 0.08, 0.03, 0.01, 0.0)
#: Largest extra clearance of a certified run along a blend [m] (see CollisionWorld.check_path).
BLEND_MAX_EXTRA_M = 0.01


def smooth(ctx: PlanContext, waypoints: Array) -> list[JointPath]:
    """Blend corners where the blend is certified clear; split into legs at the remaining corners."""
    n_corners = len(waypoints) - 2
    if n_corners <= 0 or not ctx.simplify or not ctx.preset.blends:
        return [
            JointPath((LinePiece(a, b, segment_time_length(ctx.robot, a, b)),))
            for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)
        ]
    level = np.zeros(n_corners, dtype=int)
    # A corner's blend depends on its own fraction only (a blend takes at most 0.45 of each neighbouring
    # segment, so two never meet): a verdict holds while the other corners shrink.
    verdicts: dict[tuple[int, int], bool] = {}
    while True:
        frac = np.array([BLEND_FRACTIONS[k] for k in level])
        path, blend_index = blended_polyline(ctx.robot, waypoints, frac)
        failed = False
        for c, idx in enumerate(blend_index):
            if idx < 0:
                continue
            if verdicts.get((c, int(level[c]))):
                continue
            piece = path.pieces[idx]
            s = np.linspace(0.0, piece.length, 17)
            qs = piece.evaluate(s)[0]
            ok = bool(np.all(ctx.robot.admissible_batch(qs)))
            ok = ok and bool(np.all(ctx.forces.ratios(qs) <= ctx.forces.fraction))
            # A curved run deviates from its chord: runs with up to BLEND_MAX_EXTRA_M of extra
            # clearance (halved where that fails) take a few checks rather than one per piece.
            ok = (
                ok
                and ctx.world.check_path(
                    qs,
                    ctx.clearances.blend_m,
                    ctx.clearances.motion_margin_m,
                    max_extra_m=BLEND_MAX_EXTRA_M,
                ).valid
            )
            verdicts[c, int(level[c])] = ok
            if not ok:
                level[c] = min(level[c] + 1, len(BLEND_FRACTIONS) - 1)
                failed = True
        if not failed:
            break
    ctx.report["smoothing"] = {
        "corners": n_corners,
        "blended": int(np.sum(frac > 0)),
        "sharp": int(np.sum(frac == 0)),
    }
    # Split at sharp corners (the robot stops there): corner c is waypoint c + 1.
    legs: list[JointPath] = []
    start = 0
    for c in range(n_corners):
        if frac[c] == 0:
            legs.append(blended_polyline(ctx.robot, waypoints[start : c + 2], frac[start:c])[0])
            start = c + 1
    legs.append(blended_polyline(ctx.robot, waypoints[start:], frac[start:])[0])
    return legs
