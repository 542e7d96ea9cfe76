"""The requested clearance means what it says, on the tight bay.

Free space of requested + 2.5 mm plans, requested - 1 mm is refused with the distance, and the certified
motion adapts near tight states instead of refusing them.

The tight bay T1 leaves 12.5 mm around the payload at its goal (meshes/README.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.core.exceptions import GoalInCollision
from planner.plan.context import PlanContext
from planner.plan.goals import approach_lines
from planner.plan.motion import MIN_MARGIN_M, certify_motion
from planner.plan.pipeline import Planner
from planner.scenario.resolve import ResolvedScenario, load_scenario
from tests.plan.conftest import SCENARIOS

FREE_M = 0.0125  # free space around the payload at the tight bay's goal


def _tight(clearance_m: float) -> ResolvedScenario:
    sc = load_scenario(SCENARIOS / "tightbay-insert.yaml")
    options = sc.options.model_copy(update={"clearance_m": clearance_m})
    return dataclasses.replace(sc, options=options, spec=sc.spec.model_copy(update={"options": options}))


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "tightbay-insert.yaml")


def test_the_tight_bay_needs_no_hand_set_option(scenario: ResolvedScenario) -> None:
    assert scenario.spec.options.model_dump(exclude_unset=True).keys() <= {
        "time_limit_s",
        "seed",
        "sample_period_s",
    }
    assert scenario.options.clearance_m == pytest.approx(FREE_M - 0.0025)


def test_free_space_of_requested_plus_2_5_mm_plans(scenario: ResolvedScenario) -> None:
    result = Planner(scenario).plan()
    assert result.gate.passed, result.gate.summary()
    assert result.gate.min_clearance_m >= scenario.options.clearance_m
    # Checked again here, independently of the gate: the sampled polyline keeps the requested clearance.
    world = CollisionWorld(scenario.robot, scenario.cabin, scenario.payload)
    assert world.check_path(result.profile.joints, scenario.options.clearance_m, 0.0005).valid


def test_free_space_of_requested_minus_1_mm_is_refused_with_the_distance() -> None:
    sc = _tight(FREE_M + 0.001)
    with pytest.raises(GoalInCollision) as info:
        Planner(sc).plan()
    best = info.value.details["best"]
    assert best["cause"] == "clearance" and best["bodies"][0] == "payload"
    assert best["distance_m"] == pytest.approx(FREE_M, abs=5e-4)
    assert best["required_m"] > best["distance_m"]
    assert f"{1e3 * best['distance_m']:.1f} mm from the cabin" in info.value.message
    assert info.value.details["candidates"]


def test_the_certified_motion_adapts_its_margin_near_a_tight_state(scenario: ResolvedScenario) -> None:
    ctx = PlanContext.build(scenario)
    c = ctx.clearances
    lines, _ = approach_lines(
        ctx.world,
        scenario.T_base_tool_goal,
        scenario.approach_direction,
        scenario.approach_distance_m,
        c.planner_m,
        c.motion_margin_m,
        ctx.forces,
    )
    assert lines
    q_pre, q_goal = lines[0].line[0], lines[0].line[-1]
    fixed = ctx.world.check_motion(q_pre, q_goal, c.planner_m, c.motion_margin_m)
    adaptive = certify_motion(ctx.world, q_pre, q_goal, c.planner_m, c.motion_margin_m)
    assert not fixed.valid  # the 5 mm default margin alone cannot prove the line: its goal has 1 mm spare
    assert adaptive.valid and MIN_MARGIN_M <= adaptive.margin_m < c.motion_margin_m
    # What was certified holds: the exact clearance along the line stays above the planner's clearance.
    qs = np.linspace(q_pre, q_goal, 41)
    assert float(np.min(ctx.world.clearance_profile(qs, include_self=False))) >= c.planner_m
