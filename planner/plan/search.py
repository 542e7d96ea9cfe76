"""The search stage: certified waypoints from the start to one of the targets, corners cut for time.

The cascade of the plan's :class:`~planner.plan.context.SearchPreset`: a target equal to the start; the
straight joint motion when it is certified clear; for a long rail move a transit posture
(:func:`planner.plan.connect.via_transit`: cheap, and it solves narrow passages such as a hatch); then the
sampling planner with a budget counted in motion checks (reproducible), two straight motions through a
configuration off the rail position (:func:`planner.plan.connect.detour`), and the sampling planner again
with the rest of the time. Where no transit posture rode the whole rail move, two postures one after the
other (:func:`planner.plan.connect.via_relay`) come right after the detour, before the budgeted attempt:
the relay is built for that case, and the attempt before it spent its whole budget in vain on the
generated cabins where the relay then succeeded (0.25 s of a 0.68 s plan, gen-cluttered-0-002). The path
found is cut at its corners for time (:func:`planner.plan.shortcut.cut_corners`).
"""

from __future__ import annotations

import numpy as np

from planner.core.types import Array
from planner.plan import connect
from planner.plan.connect import ompl_attempt, via_transit
from planner.plan.context import PlanContext
from planner.plan.shortcut import cut_corners

#: Rail moves at least this long may use a transit posture [m].
TRANSIT_MIN_RAIL_M = 0.5


def search(ctx: PlanContext, q_start: Array, targets: list[Array]) -> tuple[Array, int]:
    """Certified waypoints from the start to one of the targets (and which), corners cut for time."""
    waypoints, k = _cascade(ctx, q_start, targets)
    if len(waypoints) > 2 and ctx.simplify:
        waypoints, stats = cut_corners(ctx.robot, waypoints, ctx.motion_ok, deadline=ctx.out_of_time)
        ctx.report.setdefault("search", {})["corner_cuts"] = {
            "cuts": stats.cuts,
            "checks": stats.checks,
            "estimated_saving_s": round(stats.saved_s, 3),
        }
    return waypoints, k


def _cascade(ctx: PlanContext, q_start: Array, targets: list[Array]) -> tuple[Array, int]:
    """The search cascade of the preset: identical, straight, transit, OMPL quick, detour, OMPL.

    A long rail move whose transit found no ride: identical, straight, transit, detour, relay, OMPL quick,
    OMPL.
    """
    for k, q in enumerate(targets):
        if np.allclose(q, q_start, rtol=0.0, atol=1e-12):
            return np.array([q_start, q]), k
    preset = ctx.preset
    if preset.straight:  # free when it is clear
        for k, q in enumerate(targets):
            if ctx.motion_ok(q_start, q):
                ctx.report["search"] = {"method": "straight"}
                return np.array([q_start, q]), k
    relay = False  # no transit ride was found (and connected): two rides, one after the other, may be
    if preset.transit and ctx.simplify and abs(float(targets[0][0] - q_start[0])) >= TRANSIT_MIN_RAIL_M:
        via = via_transit(ctx, q_start, targets)
        if via is not None:
            return via
        relay = True
    if preset.quick_attempt and not relay:
        res = ompl_attempt(ctx, q_start, targets, max_checks=preset.quick_motion_checks)
        if res is not None:
            return res
    if preset.straight:  # two straight motions through a configuration off the rail position (a few checks)
        detour = connect.detour(ctx, q_start, targets[0])
        if detour is not None:
            ctx.report["search"] = {"method": "detour"}
            return detour, 0
    if relay:  # before the sampling planner, which may take thousands of certified motions
        via = connect.via_relay(ctx, q_start, targets)
        if via is not None:
            return via
        if preset.quick_attempt:
            res = ompl_attempt(ctx, q_start, targets, max_checks=preset.quick_motion_checks)
            if res is not None:
                return res
    res = ompl_attempt(ctx, q_start, targets, max_checks=preset.full_motion_checks)
    if res is not None:
        return res
    raise ctx.no_path()
