"""A cycle's refusal names its true cause: the grasp chosen by force, the evidence a failing measurement.

Two defects of the cycle planner, found on generated cycles, and what replaced them:

* the grasp line was picked by clearance and margin among the first clear lines only, then refused as
  ``unit_not_holdable`` when none of those few could hold the unit, although other exact solutions of
  the same grasp pose could; now every admissible grasp configuration is held to the loaded static forces
  first, and ``unit_not_holdable`` names the drive and force ratio of the configuration closest to
  holding, when none can;
* a failed check was explained by the distance to the closest body whatever had failed (a limit, a
  margin, a drive), so refusals quoted distances above their own requirement; now the evidence is the
  measurement that fails (a limit outside its range, a distance below its requirement, or a drive over
  its share of the force limit), at the place it fails.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.core.exceptions import ApproachInfeasible, UnitNotHoldable
from planner.dynamics.holding import StaticForceCheck
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.kinematics.closed_form import redundant_family
from planner.plan.context import PlanContext
from planner.plan.evidence import collision_evidence, motion_evidence, state_evidence
from planner.plan.goals import approach_lines
from planner.plan.motion import MIN_MARGIN_M, certify_motion
from planner.task.cycle import plan_cycle
from planner.task.legs import leg, leg_scenario
from planner.task.resolve import ResolvedCycle, resolve_cycle
from planner.task.schema import cycle_from_dict
from tests.task.conftest import EXAMPLE, example_dict

#: A unit that only a few exact solutions of the example's grasp pose can hold (the example's is 60 kg).
HEAVY_KG = 100.0
#: A unit that no solution of the grasp pose can hold.
TOO_HEAVY_KG = 150.0


def _cycle(mass_kg: float) -> ResolvedCycle:
    data = example_dict()
    data["unit"]["mass"] = mass_kg
    return resolve_cycle(cycle_from_dict(data), base_dir=EXAMPLE.parent)


def _grasp_setting(cyc: ResolvedCycle) -> tuple[PlanContext, np.ndarray, StaticForceCheck]:
    """The grasp line's context, the tool's grasp pose and the loaded static check (as the planner's)."""
    ctx = PlanContext.build(leg_scenario(cyc, leg("grasp_line"), cyc.park_q, goal_q=cyc.park_q), None, None)
    T_tool_grasp = cyc.T_base_unit_dock @ np.linalg.inv(cyc.T_tool_unit)
    return ctx, T_tool_grasp, StaticForceCheck(Cabin8Dynamics.of(cyc.robot), cyc.unit_payload)


def _lines(cyc: ResolvedCycle, hold: bool) -> tuple[list[Any], dict[str, int], list[dict[str, Any]]]:
    ctx, T, loaded = _grasp_setting(cyc)
    c, line = ctx.clearances, cyc.grasp_line
    evidence: list[dict[str, Any]] = []
    lines, stats = approach_lines(
        ctx.world,
        T,
        line.direction,
        line.distance_m,
        c.planner_m,
        c.motion_margin_m,
        ctx.forces,
        max_lines=6,
        evidence=evidence,
        hold=loaded if hold else None,
    )
    return lines, stats, evidence


def _assert_failing(record: dict[str, Any], cyc: ResolvedCycle) -> None:
    """The record is a measurement that fails its own requirement, at its own configuration."""
    q = np.asarray(record["q"])
    if record["cause"] == "clearance":
        assert record["distance_m"] < record["required_m"], record
    elif record["cause"] == "limit":
        assert cyc.robot.violations(q), record
        assert record["value"] > record["upper"] or record["value"] < record["lower"], record
    else:
        assert record["cause"] == "force" and record["force_ratio"] > record["allowed_ratio"], record


def test_every_grasp_line_holds_the_unit_where_the_first_clear_lines_could_not() -> None:
    cyc = _cycle(HEAVY_KG)
    _, _, loaded = _grasp_setting(cyc)
    old, _, _ = _lines(cyc, hold=False)
    # The case of the defect: the best lines by margin and clearance are clear, and none holds the unit.
    assert old and not any(loaded.ok(x.q) for x in old)
    new, stats, _ = _lines(cyc, hold=True)
    assert new, "some exact solutions of the grasp pose hold the unit and are clear"
    ratios = loaded.ratios(np.array([x.q for x in new]))
    assert np.all(ratios <= loaded.fraction)
    assert 0 < stats["admissible"] - stats["hold"] and stats["hold"] > 0
    for x in new:  # each line is exact: the grasp pose reached, the pre-grasp on the straight line
        assert x.line is not None
        np.testing.assert_allclose(cyc.robot.fk(x.line[-1]), _grasp_setting(cyc)[1], atol=1e-9)


def test_the_heavy_cycle_is_refused_for_what_fails_not_as_unholdable() -> None:
    """The holdable grasps end their lift-off beyond a margin: that limit is the refusal, not the load."""
    cyc = _cycle(HEAVY_KG)
    with pytest.raises(ApproachInfeasible) as exc:
        plan_cycle(cyc)
    d = exc.value.details
    assert d["leg"] == "grasp_line" and d["hold"] < d["admissible"]
    assert d["candidates"] and d["best"] is not None
    for record in d["candidates"]:
        _assert_failing(record, cyc)
    _assert_failing(d["best"], cyc)
    # What the refusal used to quote there: the closest bodies, which keep their clearance.
    best = d["best"]
    assert best["cause"] == "limit" and "lift-off" in best["where"]
    lift = PlanContext.build(leg_scenario(cyc, leg("lift_off"), cyc.park_q, goal_q=cyc.park_q), None, None)
    old = collision_evidence(lift.world, np.asarray(best["q"]), lift.clearances.planner_m, best["where"])
    assert old["distance_m"] > old["required_m"]


def test_no_holdable_grasp_names_the_drive_and_ratio_of_the_best_candidate() -> None:
    cyc = _cycle(TOO_HEAVY_KG)
    with pytest.raises(UnitNotHoldable) as exc:
        plan_cycle(cyc)
    d = exc.value.details
    _, T, loaded = _grasp_setting(cyc)
    q_best = np.asarray(d["best"]["q"])
    # The named candidate is an exact, admissible grasp configuration with that drive at that ratio.
    np.testing.assert_allclose(cyc.robot.fk(q_best), T, atol=1e-9)
    assert not cyc.robot.violations(q_best)
    tau = loaded.dynamics.static_forces_batch(q_best[None, :], cyc.unit_payload)[0]
    ratios = np.abs(tau) / cyc.robot.limits.effort_max
    assert cyc.robot.drive_names[int(np.argmax(ratios))] == d["drive"]
    assert float(np.max(ratios)) == pytest.approx(d["force_ratio"], abs=1e-12)
    assert d["force_ratio"] > d["allowed_ratio"] and d["hold"] == d["admissible"] > 0
    # The refusal is true: no admissible solution of the grasp pose, on a grid twice as fine, holds it.
    ps = cyc.robot.desc.parallel_stage
    g, s = np.meshgrid(
        np.linspace(-ps.gamma_max, ps.gamma_max, 41),
        np.linspace(cyc.robot.limits.lower[6], cyc.robot.limits.upper[6], 41),
        indexing="ij",
    )
    Q = redundant_family(cyc.robot.desc.serial_chain, T, g.ravel(), s.ravel())
    Q = Q[cyc.robot.admissible_batch(Q)]
    assert len(Q) > 0 and float(np.min(loaded.ratios(Q))) > loaded.fraction


def test_a_state_beyond_a_limit_is_explained_by_the_limit_not_a_passing_distance(
    cycle: ResolvedCycle,
) -> None:
    ctx = PlanContext.build(leg_scenario(cycle, leg("park"), cycle.park_q, goal_q=cycle.park_q), None, None)
    c = ctx.clearances
    q = np.array(cycle.park_q, dtype=float)
    j = 0  # the rail: past its upper limit by 1 cm, the robot far from everything
    q[j] = cycle.robot.limits.upper[j] + 0.01
    assert cycle.robot.violations(q) and not ctx.world.is_valid(q, c.planner_m)
    old = collision_evidence(ctx.world, q, c.planner_m, "here")
    assert old["distance_m"] > old["required_m"]  # what the refusals used to quote
    ev = state_evidence(ctx.world, q, c.planner_m, "here", ctx.forces)
    assert ev is not None and ev["cause"] == "limit"
    _assert_failing(ev, cycle)
    # A clear, admissible, holdable state has nothing to report.
    assert ctx.state_ok(cycle.park_q)
    assert state_evidence(ctx.world, cycle.park_q, c.planner_m, "here", ctx.forces) is None


def test_a_refused_motion_is_explained_where_its_walk_failed(cycle: ResolvedCycle) -> None:
    ctx = PlanContext.build(leg_scenario(cycle, leg("park"), cycle.park_q, goal_q=cycle.park_q), None, None)
    c = ctx.clearances
    q_a = np.array(cycle.park_q, dtype=float)
    # Into a limit: the rail driven 1 cm past its upper limit.
    q_b = q_a.copy()
    q_b[0] = cycle.robot.limits.upper[0] + 0.01
    motion = certify_motion(ctx.world, q_a, q_b, c.planner_m, c.motion_margin_m)
    assert not motion.valid
    ev = motion_evidence(ctx.world, q_a, q_b, motion, c.planner_m, lambda t: f"{100 * t:.0f}% along")
    assert ev is not None and ev["cause"] == "limit"
    _assert_failing(ev, cycle)
    # Into the unit on its dock: the grasp line, walked in the pre-grasp's world (no allowed pair there).
    lines, _, _ = _lines(cycle, hold=True)
    assert lines and lines[0].line is not None
    q_pre, q_grasp = lines[0].line[0], lines[0].line[-1]
    pre = PlanContext.build(
        leg_scenario(cycle, leg("pre_grasp"), cycle.park_q, goal_q=cycle.park_q), None, None
    )
    motion = certify_motion(pre.world, q_pre, q_grasp, c.planner_m, c.motion_margin_m)
    assert not motion.valid
    ev = motion_evidence(pre.world, q_pre, q_grasp, motion, c.planner_m, lambda t: f"{100 * t:.0f}% along")
    assert ev is not None and ev["cause"] == "clearance" and cycle.unit_name in ev["bodies"]
    _assert_failing(ev, cycle)
    assert ev["required_m"] == pytest.approx(c.planner_m + MIN_MARGIN_M, abs=1e-12)
