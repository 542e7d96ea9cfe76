"""The planning pipeline: resolved scenario in, validated drive profile out (or a clear refusal).

A short sequence of stage calls over one :class:`~planner.plan.context.PlanContext`, each inside the
context's stopwatch (``with ctx.stage(name, fraction):`` reports it through the ``progress`` callback and
times it in ``report["stages_s"]``):

1. ``check_start`` (:mod:`planner.plan.endpoints`): admissible, clear, holdable.
2. ``goals`` (:mod:`planner.plan.targets`): the configurations to reach, with their approach lines;
   deflection-compensated where the model is trusted (:mod:`planner.plan.compensate`).
3. ``search`` (:mod:`planner.plan.search`): certified waypoints, corners cut for time.
4. ``smooth`` (:mod:`planner.plan.smooth`): certified blends; legs split at sharp corners, the insertion line
   its own leg.
5. ``timing`` / ``sample`` / ``validate`` (:mod:`planner.plan.retime`): the timing stage per leg, sampled at
   the controller period, through the gate (:mod:`planner.gate`); each try is timed as ``timing_k`` and
   ``validate_k`` (a limit the gate finds exceeded is tightened and the legs timed again).
6. the report (:mod:`planner.plan.report`): lower bounds and the predicted deflection.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.core.types import Array, IntArray
from planner.gate.checks import GateReport
from planner.gate.requirements import requirements_for
from planner.plan.compensate import compensate_targets
from planner.plan.context import PRODUCT, PlanContext, Progress, SearchPreset
from planner.plan.endpoints import check_configuration
from planner.plan.report import deflection_report, duration_report
from planner.plan.retime import time_and_validate
from planner.plan.search import search
from planner.plan.smooth import smooth
from planner.plan.targets import goal_targets
from planner.timing.path import JointPath, LinePiece, SplinePiece, segment_time_length
from planner.timing.profile import DriveProfile
from planner.timing.stage import TimingFactory

if TYPE_CHECKING:
    from planner.scenario.resolve import ResolvedScenario


@dataclass(frozen=True)
class PlanResult:
    """A validated drive profile and everything that explains it."""

    profile: DriveProfile
    gate: GateReport
    report: dict[str, Any] = field(repr=False)
    waypoints: Array = field(repr=False)
    #: Predicted static deflection of the payload frame at every sample (N, 6), or None (no stiffness data).
    deflection: Array | None = field(default=None, repr=False)
    #: The leg index of every sample (N,): the legs of ``report["leg_durations_s"]``, the insertion line
    #: (with an approach) the last.
    leg_of: IntArray | None = field(default=None, repr=False)


def run_stages(ctx: PlanContext) -> PlanResult:
    """Every stage over ``ctx`` (see the module docstring); the validated result, or the refusal raised."""
    sc = ctx.sc
    with ctx.stage("check_start", 0.0):
        check_configuration(ctx, sc.start_q, "start")

    with ctx.stage("goals", 0.05):
        targets, lines = goal_targets(ctx)
        compensations = compensate_targets(ctx, targets, lines)

    with ctx.stage("search", 0.15, until=0.7):
        waypoints, k = search(ctx, sc.start_q, targets)

    with ctx.stage("smooth", 0.7):
        legs = smooth(ctx, waypoints)
        line = lines[k]
        if line is not None and line.line is not None and line.line_s is not None:
            legs.append(_insertion_leg(ctx, line.line, line.line_s))
            waypoints = np.vstack([waypoints, line.line[1:]])

    compensation = compensations[k] if compensations else None
    commanded = compensation.T_base_frame_commanded if compensation is not None else None
    ctx.progress("timing", 0.75)  # each try of timing and gate is its own stage (timing_0, validate_0, ...)
    profile, gate, timed = time_and_validate(ctx, legs, requirements_for(sc, ctx.payload, commanded))

    deflection = deflection_report(ctx, profile, compensation, gate)
    ctx.report.update(legs=len(legs), leg_durations_s=[round(tp.duration, 4) for tp in timed])
    duration_report(ctx, profile, line)
    ctx.report["planning_time_s"] = ctx.elapsed()
    ctx.progress("done", 1.0)
    return PlanResult(profile, gate, ctx.report, waypoints, deflection, ctx.leg_of)


def _insertion_leg(ctx: PlanContext, line: Array, line_s: Array) -> JointPath:
    """The insertion line (K, 8) from the pre-insertion configuration to the goal as its own leg."""
    if len(line) == 2:
        a, b = line
        return JointPath((LinePiece(a, b, segment_time_length(ctx.robot, a, b)),))
    return JointPath((SplinePiece.through(line_s, line),))


class Planner:
    """Plans one resolved scenario: builds its :class:`PlanContext`, then :meth:`plan` runs the stages.

    Args:
        scenario: The resolved scenario.
        progress: Called with (stage name, fraction done) as the stages start.
        timing: Factory of the timing stage, ``(robot, payload, safety) -> TimingStage`` (default: the
            scenario's stage from :mod:`planner.timing.stages`, jerk-limited when the robot has jerk limits).
        preset: The search preset (:data:`~planner.plan.context.PRODUCT`; the benchmark's baseline is
            :data:`~planner.plan.context.BASELINE`).
    """

    def __init__(
        self,
        scenario: ResolvedScenario,
        progress: Progress | None = None,
        timing: TimingFactory | None = None,
        preset: SearchPreset = PRODUCT,
    ) -> None:
        self.ctx = PlanContext.build(scenario, progress, timing, preset)
        self.world = self.ctx.world
        self.dynamics = self.ctx.dynamics
        self.payload = self.ctx.payload

    @property
    def report(self) -> dict[str, Any]:
        """What the stages did so far."""
        return self.ctx.report

    def plan(self) -> PlanResult:
        """Run every stage; returns the validated result or raises the refusal."""
        return run_stages(self.ctx)


def plan_scenario(
    scenario: ResolvedScenario,
    progress: Progress | None = None,
    timing: TimingFactory | None = None,
    preset: SearchPreset = PRODUCT,
) -> PlanResult:
    """Plan a resolved scenario; raises a :class:`~planner.core.exceptions.PlannerError` refusal."""
    return Planner(scenario, progress, timing, preset).plan()
