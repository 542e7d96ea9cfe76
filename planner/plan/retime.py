"""The timing-and-gate stage: time every leg, sample at the controller period, gate; re-time on a limit.

The timing stage comes from the context's factory (:class:`~planner.timing.stage.TimingStage`, the
scenario's stage from :mod:`planner.timing.stages`: jerk-limited by default when the robot has jerk limits);
a gate failure of a limit check (velocity, acceleration, force, consistency) re-times with that limit
tightened to the next of :data:`SAFETY_LEVELS`; any other failure refuses.
"""

from __future__ import annotations

import dataclasses

from planner.core.exceptions import ValidationFailed
from planner.gate.checks import GateReport, validate_profile
from planner.gate.requirements import GateRequirements
from planner.plan.context import PlanContext
from planner.timing.path import JointPath
from planner.timing.profile import DriveProfile, sample_legs
from planner.timing.stage import DEFAULT_SAFETY, TimedPath

#: Limit scalings (velocity, acceleration, force) tried when the gate finds a limit exceeded.
SAFETY_LEVELS = (DEFAULT_SAFETY, (0.98, 0.92, 0.92), (0.95, 0.85, 0.85))
#: The gate checks whose failure a re-timing can cure.
LIMIT_CHECKS = {"velocity", "acceleration", "effort", "consistency", "jerk"}


def time_and_validate(
    ctx: PlanContext, legs: list[JointPath], req: GateRequirements
) -> tuple[DriveProfile, GateReport, list[TimedPath]]:
    """Time every leg, sample and gate; re-time with tighter limits when only a limit check fails.

    Only the limits that failed are tightened (velocity, acceleration, force: the next of
    :data:`SAFETY_LEVELS` for each; a consistency or jerk failure tightens the acceleration, which also
    scales the jerk-limited stage's jerk target): the others keep
    their margin, so a drive holding a heavy payload near its force limit is not refused because an
    acceleration peak had to come down.
    """
    last: GateReport | None = None
    req = dataclasses.replace(req, path_legs=tuple(legs))  # the gate checks the samples stay on the path
    level = [0, 0, 0]  # velocity, acceleration, force
    for attempt in range(len(SAFETY_LEVELS)):
        safety = (
            SAFETY_LEVELS[level[0]][0],
            SAFETY_LEVELS[level[1]][1],
            SAFETY_LEVELS[level[2]][2],
        )
        stage = ctx.timing(ctx.robot, ctx.payload, safety)
        with ctx.stage(f"timing_{attempt}") as clock:
            timed = [stage.time_path(leg) for leg in legs]
        ctx.report["timing"] = {
            "stage": stage.name,
            "stage_s": round(clock.seconds, 6),
            "legs": len(legs),
            "duration_s": round(sum(tl.duration for tl in timed), 6),
        }
        ctx.progress("sample", 0.85)
        profile, ctx.leg_of, path_s = sample_legs(
            ctx.robot, timed, ctx.opts.sample_period_s, ctx.payload, ctx.dynamics
        )
        ctx.progress("validate", 0.9)
        with ctx.stage(f"validate_{attempt}"):
            sampled = dataclasses.replace(req, path_leg_of=ctx.leg_of, path_s=path_s)
            gate = validate_profile(profile, ctx.robot, ctx.world, sampled, ctx.dynamics)
        if gate.passed:
            return profile, gate, timed
        last = gate
        failed = {c.name for c in gate.failures}
        if not failed <= LIMIT_CHECKS:
            break
        for name, k in (
            ("velocity", 0),
            ("acceleration", 1),
            ("consistency", 1),
            ("jerk", 1),
            ("effort", 2),
        ):
            if name in failed:
                level[k] = min(level[k] + 1, len(SAFETY_LEVELS) - 1)
        ctx.report.setdefault("retimed", []).append({"failed": sorted(failed), "safety": list(safety)})
    assert last is not None
    raise ValidationFailed(f"validation gate: {last.summary()}", report=last.to_dict())
