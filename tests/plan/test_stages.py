"""Each planning stage alone, over a PlanContext: endpoints, targets, search, smooth, retime.

The scenario is the aisle-bay insertion (a rail move, a posture change and a straight insertion), so every
stage has work to do; the stages are called one by one, as the pipeline calls them, and each result is
checked for the property the next stage relies on.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.core.exceptions import RetimingFailed, StartInvalid, ValidationFailed
from planner.gate.requirements import requirements_for
from planner.plan.context import BASELINE, PLANNER_SLACK_M, Clearances, PlanContext
from planner.plan.endpoints import check_configuration
from planner.plan.retime import time_and_validate
from planner.plan.search import search
from planner.plan.smooth import smooth
from planner.plan.targets import goal_targets
from planner.scenario.resolve import ResolvedScenario, load_scenario
from planner.timing.path import BlendPiece
from planner.timing.toppra import ToppraStage
from tests.plan.conftest import SCENARIOS


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "aisle-bay-insert.yaml")


@pytest.fixture(scope="module")
def ctx(scenario: ResolvedScenario) -> PlanContext:
    return PlanContext.build(scenario)


def test_clearances_are_one_value_from_the_options(scenario: ResolvedScenario) -> None:
    c = Clearances.of(scenario.options)
    assert c.requested_m == scenario.options.clearance_m
    assert c.motion_margin_m == scenario.options.motion_margin_m
    assert c.planner_m == pytest.approx(c.requested_m + PLANNER_SLACK_M, abs=1e-15)
    assert c.blend_m > c.planner_m


def test_endpoints_refuse_a_start_inside_the_planner_slack(ctx: PlanContext) -> None:
    check_configuration(ctx, ctx.sc.start_q, "start")  # the reference start is fine
    wide = dataclasses.replace(ctx, clearances=dataclasses.replace(ctx.clearances, slack_m=0.2))
    with pytest.raises(StartInvalid) as info:
        check_configuration(wide, ctx.sc.start_q, "start")
    assert "the planner keeps 200 mm beyond" in info.value.message
    assert info.value.details["contacts"]


def test_targets_end_on_certified_insertion_lines(ctx: PlanContext) -> None:
    targets, lines = goal_targets(ctx)
    assert targets and len(targets) == len(lines)
    for q, cand in zip(targets, lines, strict=True):
        assert cand is not None and cand.line is not None
        assert np.array_equal(q, cand.line[0])  # the search ends where the insertion line starts
        assert ctx.state_ok(q)


def test_search_gives_certified_waypoints_then_smooth_certified_blends(ctx: PlanContext) -> None:
    targets, _ = goal_targets(ctx)
    waypoints, k = search(ctx, ctx.sc.start_q, targets)
    assert np.array_equal(waypoints[0], ctx.sc.start_q) and np.array_equal(waypoints[-1], targets[k])
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        assert ctx.motion_ok(a, b)
    legs = smooth(ctx, waypoints)
    assert np.allclose(legs[0].start, waypoints[0], rtol=0, atol=1e-12)
    assert np.allclose(legs[-1].end, waypoints[-1], rtol=0, atol=1e-12)
    for leg in legs:
        for piece in leg.pieces:
            if isinstance(piece, BlendPiece):
                qs = piece.evaluate(np.linspace(0.0, piece.length, 33))[0]
                report = ctx.world.check_path(qs, ctx.clearances.blend_m, ctx.clearances.motion_margin_m)
                assert report.valid


def test_the_baseline_preset_stops_at_every_waypoint(scenario: ResolvedScenario) -> None:
    base = PlanContext.build(scenario, preset=BASELINE)
    waypoints = np.array([scenario.start_q, scenario.start_q + 0.01, scenario.start_q + 0.02])
    legs = smooth(base, waypoints)
    assert len(legs) == 2 and all(len(leg.pieces) == 1 for leg in legs)


def test_retime_passes_the_gate_and_a_stage_that_ignores_limits_is_refused(ctx: PlanContext) -> None:
    targets, _ = goal_targets(ctx)
    waypoints, _ = search(ctx, ctx.sc.start_q, targets)
    legs = smooth(ctx, waypoints)
    req = requirements_for(ctx.sc, ctx.payload)
    req = dataclasses.replace(req, T_base_payload_goal=None, approach_direction=None, goal_u=None)
    profile, gate, timed = time_and_validate(ctx, legs, req)
    assert gate.passed and len(timed) == len(legs)
    assert np.all(np.abs(profile.velocity) <= 1.01 * ctx.robot.limits.v_max)

    def reckless(robot: object, payload: object, safety: tuple[float, float, float]) -> ToppraStage:
        return ToppraStage(ctx.robot, ctx.payload, (3.0 * safety[0], 3.0 * safety[1], 3.0 * safety[2]))

    fast = dataclasses.replace(ctx, timing=reckless)
    with pytest.raises((ValidationFailed, RetimingFailed)) as info:
        time_and_validate(fast, legs, req)
    if isinstance(info.value, ValidationFailed):
        failed = {c["name"] for c in info.value.details["report"]["checks"] if not c["passed"]}
        assert failed & {"velocity", "acceleration", "effort"}


def test_the_pipeline_runs_its_stages_in_order_each_timed_and_announced(scenario: ResolvedScenario) -> None:
    """The stopwatch: every stage of the docstring's list announced in order, timed in stages_s."""
    from planner.plan.pipeline import Planner

    events: list[tuple[str, float]] = []
    planner = Planner(scenario, progress=lambda name, fraction: events.append((name, fraction)))
    result = planner.plan()
    assert list(result.report["stages_s"]) == [
        "check_start",
        "goals",
        "search",
        "smooth",
        "timing_0",
        "validate_0",
    ]
    assert all(s >= 0.0 for s in result.report["stages_s"].values())
    assert result.report["timing"]["stage_s"] == result.report["stages_s"]["timing_0"]
    fractions = [f for _, f in events]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] == 1.0
    names = [n for n, _ in events]
    first = [n for i, n in enumerate(names) if n not in names[:i]]
    assert first == ["check_start", "goals", "search", "smooth", "timing", "sample", "validate", "done"]
    # Ticks (the search's progress between 0.15 and 0.7) come from the search only.
    assert all(0.15 <= f <= 0.7 for n, f in events if n == "search")


def test_a_stage_that_raises_is_not_recorded_and_ticks_only_inside_a_ticking_stage(ctx: PlanContext) -> None:
    events: list[tuple[str, float]] = []
    quiet = dataclasses.replace(ctx, progress=lambda n, f: events.append((n, f)), report={"stages_s": {}})
    quiet.last_tick = -1e9
    quiet.tick()  # outside any stage: nothing to report
    assert events == []
    with pytest.raises(RuntimeError), quiet.stage("boom", 0.3):
        raise RuntimeError("refused")
    assert "boom" not in quiet.report["stages_s"] and events == [("boom", 0.3)]
    with quiet.stage("walk", 0.2, until=0.6) as watch:
        quiet.last_tick = -1e9
        quiet.tick()
    assert events[-1][0] == "walk" and 0.2 <= events[-1][1] <= 0.6
    assert quiet.report["stages_s"]["walk"] == round(watch.seconds, 6) and watch.seconds > 0.0
    quiet.last_tick = -1e9
    quiet.tick()  # the ticking stage has ended
    assert events[-1][0] == "walk" and len(events) == 3
