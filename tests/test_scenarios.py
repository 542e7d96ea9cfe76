"""The scenario suite: every reference cabin, plus the refusals a user must get instead of a trajectory.

Each feasible scenario's profile is checked here *independently of the gate*: limits on every sample,
at rest at both ends, start and goal, the insertion line, the parallel stage's margins, and the certified
collision check of the sampled polyline, recomputed from the profile's drive positions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.collision.world import CollisionWorld
from planner.core.exceptions import PlannerError
from planner.core.schemas import Pose
from planner.core.so3 import pose_error
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.stiffness import StiffnessModel, deflected_pose
from planner.gate.requirements import GATE_MOTION_MARGIN_M
from planner.plan.pipeline import Planner, PlanResult
from planner.scenario.resolve import ResolvedScenario, load_scenario

HERE = Path(__file__).parent / "scenarios"
EXPECTED = yaml.safe_load((HERE / "expected.yaml").read_text())
FEASIBLE = sorted(k for k, v in EXPECTED.items() if v["status"] == "succeeded")
REFUSED = sorted(k for k, v in EXPECTED.items() if v["status"] == "failed")


def test_every_scenario_file_has_an_expectation() -> None:
    files = {p.stem for p in HERE.glob("*.yaml")} - {"expected"}
    assert files == set(EXPECTED)


_cache: dict[str, tuple[ResolvedScenario, PlanResult]] = {}


def _plan(name: str) -> tuple[ResolvedScenario, PlanResult]:
    if name not in _cache:
        sc = load_scenario(HERE / f"{name}.yaml")
        _cache[name] = (sc, Planner(sc).plan())
    return _cache[name]


#: Largest jerk-limited / acceleration-limited duration on the suite (bench.timing: 1.09 measured; the
#: issue's target 1.15).
JERK_COST = 1.15


@pytest.mark.parametrize("name", FEASIBLE)
def test_feasible_scenario_gives_a_profile_that_respects_every_limit(name: str) -> None:
    sc, res = _plan(name)
    robot, prof = sc.robot, res.profile
    lim = robot.limits
    tol = 1.01
    u, ud, udd = prof.position, prof.velocity, prof.acceleration
    assert res.gate.passed, res.gate.summary()
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(prof.effort))
    assert np.allclose(np.diff(prof.t), sc.options.sample_period_s, atol=1e-9)
    assert np.all(u >= lim.lower - 1e-9) and np.all(u <= lim.upper + 1e-9)
    assert np.all(np.abs(ud) <= tol * lim.v_max)
    assert np.all(np.abs(udd) <= tol * lim.a_max)
    assert np.all(np.abs(np.diff(ud, axis=0)) / sc.options.sample_period_s <= tol * lim.a_max)
    # The default time law is jerk-limited (cabin8's description has jerk limits): the jerk, the change of
    # the sampled acceleration over each period, within its limit on every sample; zero acceleration at
    # both ends; every sample on the certified path.
    assert res.report["timing"]["stage"] == "jerk_limited"
    assert lim.j_max is not None
    assert np.all(np.abs(np.diff(udd, axis=0)) / sc.options.sample_period_s <= tol * lim.j_max)
    assert np.array_equal(udd[-1], np.zeros(8)) and np.all(np.abs(udd[0]) <= 1e-9)
    on_path = next(c for c in res.gate.checks if c.name == "on_path")
    assert on_path.passed and on_path.worst is not None and on_path.worst <= 1e-6
    # Efforts recomputed from the joint motion (an independent route: finite differences of the joints).
    dyn = Cabin8Dynamics(robot)
    q = robot.joints_from_drives(u)
    dt = sc.options.sample_period_s
    qd = np.gradient(q, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    tau = dyn.drive_forces_batch(
        q[1:-1], qd[1:-1], qdd[1:-1], sc.payload.rigid_payload() if sc.payload else None
    )
    assert np.all(np.abs(tau) <= 1.02 * lim.effort_max)
    assert np.all(np.abs(prof.effort) <= tol * lim.effort_max)
    # At rest at both ends, starting exactly at the start.
    assert np.array_equal(ud[0], np.zeros(8)) and np.array_equal(ud[-1], np.zeros(8))
    assert np.max(np.abs(u[0] - sc.start_u)) <= 1e-9
    # Margins at every sample.
    assert not any(robot.violations(qi) for qi in q[:: max(1, len(q) // 400)])
    # Goal.
    T_tool_payload = sc.payload.T_tool_payload if sc.payload is not None else np.eye(4)
    T_pay = robot.fk_batch(q) @ T_tool_payload
    T_goal = sc.T_base_payload_goal
    if T_goal is not None and "goal" in res.report:
        # Deflection-compensated: the rigid final pose is the command, the deflected one the request.
        cmd = res.report["goal"]["compensated"]
        T_goal = Pose.model_validate({k: cmd[k] for k in ("position", "orientation")}).matrix()
        pay = sc.payload.rigid_payload() if sc.payload else None
        x = StiffnessModel(robot).deflection(q[-1], pay, T_tool_payload)
        e = pose_error(sc.T_base_payload_goal, deflected_pose(T_pay[-1], x.twist))
        assert np.linalg.norm(e[:3]) <= 1e-5 and np.linalg.norm(e[3:]) <= 1e-5
    if T_goal is not None:
        assert np.linalg.norm(T_pay[-1][:3, 3] - T_goal[:3, 3]) <= 1e-3
        R_err = T_goal[:3, :3].T @ T_pay[-1][:3, :3]
        assert np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)) <= np.deg2rad(0.1)
    else:
        assert np.max(np.abs(u[-1] - sc.goal_u)) <= 1e-6
    # The insertion: from the last sample at the pre-insertion distance on, within 1 mm of the line.
    if sc.approach_direction is not None:
        assert sc.T_base_payload_goal is not None
        d = sc.approach_direction
        rel = T_pay[:, :3, 3] - T_goal[:3, 3]
        back = -(rel @ d)
        k = int(np.flatnonzero(back >= sc.approach_distance_m - 1e-3)[-1])
        off = np.linalg.norm(rel[k:] - np.outer(rel[k:] @ d, d), axis=1)
        assert off.max() <= 1e-3
        assert k < len(q) - 10  # the insertion takes many samples
    # Certified clearance between consecutive samples, with a fresh world.
    world = CollisionWorld(robot, sc.cabin, sc.payload)
    # (The gate's certification margin: the scenario's motion_margin_m is the planner's, not the gate's; the
    # jerk-limited law's denser samples near blends can land within it of a tight spot the path passes.)
    rep = world.check_path(q, sc.options.clearance_m, GATE_MOTION_MARGIN_M)
    assert rep.valid, rep.contacts
    assert res.gate.min_clearance_m >= sc.options.clearance_m
    # Near time-optimal: never faster than the slowest drive alone allows.
    assert prof.duration_s >= res.report["single_drive_lower_bound_s"] - 1e-9
    if sc.approach_direction is not None:  # stopping at the pre-insertion pose costs its own bound
        assert res.report["staged_lower_bound_s"] >= res.report["single_drive_lower_bound_s"] - 1e-9
        assert prof.duration_s >= res.report["staged_lower_bound_s"] - 1e-9
    # ... and not far above it: posture changes overlap the rail move (measured 1.01-1.24 on the suite with
    # TOPP-RA's law); the jerk-limited law adds its acceleration ramps (at most 1.15 times TOPP-RA's).
    bound = res.report.get("staged_lower_bound_s", res.report["single_drive_lower_bound_s"])
    assert prof.duration_s <= 1.3 * JERK_COST * bound, (prof.duration_s, bound)


@pytest.mark.parametrize("name", REFUSED)
def test_infeasible_scenario_is_refused_with_its_reason(name: str) -> None:
    sc = load_scenario(HERE / f"{name}.yaml")
    with pytest.raises(PlannerError) as info:
        Planner(sc).plan()
    assert info.value.reason == EXPECTED[name]["reason"]
    assert info.value.message


def test_a_seeded_plan_is_reproducible() -> None:
    sc = load_scenario(HERE / "aisle-bay-insert.yaml")
    a = Planner(sc).plan()
    b = Planner(sc).plan()
    assert np.array_equal(a.profile.position, b.profile.position)
    assert np.array_equal(a.waypoints, b.waypoints)


def test_a_start_inside_the_planning_margin_is_refused_at_once_with_the_reason() -> None:
    """aisle-transfer's start is 40 mm from the cabin: asking 38.5 mm leaves it inside the planner's 3 mm."""
    import dataclasses

    sc = load_scenario(HERE / "aisle-transfer.yaml")
    options = sc.options.model_copy(update={"clearance_m": 0.0385})
    tight = dataclasses.replace(sc, options=options, spec=sc.spec.model_copy(update={"options": options}))
    with pytest.raises(PlannerError) as info:
        Planner(tight).plan()
    assert info.value.reason == "start_in_collision"
    assert "beyond the requested" in info.value.message


def test_tight_blends_pass_the_gate_at_the_first_timing() -> None:
    """A 3% corner blend (cluttered-bay-insert, seed 3) passes the gate at the first timing.

    A tight blend turns fast (its curvature changes as 1 / lam^2 along it): the jerk-limited law, whose
    LP sees the blend's middle and both its ends, crosses it within every limit at the first timing.
    """
    import dataclasses

    base = load_scenario(HERE / "cluttered-bay-insert.yaml")
    options = base.options.model_copy(update={"seed": 3})
    sc = dataclasses.replace(base, options=options, spec=base.spec.model_copy(update={"options": options}))
    planner = Planner(sc)
    res = planner.plan()
    assert res.gate.passed
    assert "retimed" not in planner.report, planner.report.get("retimed")


@pytest.mark.slow
@pytest.mark.parametrize("name", FEASIBLE)
def test_min_clearance_is_the_minimum_over_every_sample(name: str) -> None:
    """The report's clearance against exact FCL distances at every sample (and midpoints near the worst)."""
    sc, res = _plan(name)
    q = sc.robot.joints_from_drives(res.profile.position)
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    exact = world.clearance_profile(q)  # every body to the cabin and every checked pair, every sample
    gate = res.gate
    at = gate.min_clearance_at
    assert at is not None and gate.min_clearance_bound_m is not None
    k, tol = at["sample"], at["tolerance_m"]
    assert tol >= 1e-4  # the search's tolerance, or what its query budget reached (flat distances)
    # The reported figure is the exact distance at the reported sample ...
    assert gate.min_clearance_m == pytest.approx(exact[k], abs=tol + 1e-9)
    assert world.min_distance(q[k]).distance_m <= gate.min_clearance_m + 1e-9
    assert at["t_s"] == res.profile.t[k]
    assert at["bodies"][1] == "cabin" or at["bodies"][1] in world.names
    # ... no sample is closer by more than the tolerance, and the bound is below every sample ...
    assert gate.min_clearance_m <= float(exact.min()) + tol + 1e-9
    assert gate.min_clearance_bound_m <= float(exact.min()) + 1e-9
    # ... and below the exact distance between samples (midpoints of the pieces around the worst sample).
    lo, hi = max(0, k - 40), min(len(q) - 1, k + 40)
    mid = 0.5 * (q[lo:hi] + q[lo + 1 : hi + 1])
    assert float(world.clearance_profile(mid).min()) >= gate.min_clearance_bound_m - 1e-9
