"""Goal configurations and approach lines: exact IK, straight joint-space insertion lines, force limits."""

from __future__ import annotations

import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.plan.goals import (
    GoalCandidate,
    StaticForceCheck,
    approach_lines,
    goal_configurations,
    line_speed_bounds,
)
from planner.plan.motion import certify_motion
from planner.redundancy.ik import normalised_margin
from planner.scenario.resolve import ResolvedScenario, load_scenario
from tests.conftest import admissible_joints
from tests.planning.conftest import CLEARANCE_M, MOTION_MARGIN_M, SCENARIOS


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "aisle-bay-insert.yaml")


@pytest.fixture(scope="module")
def lines(scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck) -> list[GoalCandidate]:
    assert scenario.T_base_tool_goal is not None and scenario.approach_direction is not None
    found, stats = approach_lines(
        world,
        scenario.T_base_tool_goal,
        scenario.approach_direction,
        scenario.approach_distance_m,
        CLEARANCE_M,
        MOTION_MARGIN_M,
        forces,
    )
    assert found, stats
    return found


def _payload_frames(scenario: ResolvedScenario, qs: np.ndarray) -> np.ndarray:
    assert scenario.payload is not None
    return scenario.robot.fk_batch(np.atleast_2d(qs)) @ scenario.payload.T_tool_payload


def test_approach_line_ends_are_the_goal_and_the_pre_insertion_pose(
    scenario: ResolvedScenario, lines: list[GoalCandidate]
) -> None:
    T_goal = scenario.T_base_payload_goal
    d, dist = scenario.approach_direction, scenario.approach_distance_m
    assert T_goal is not None and d is not None
    for cand in lines:
        assert cand.line is not None and cand.line.shape == (2, 8)
        assert cand.line_s is not None and np.array_equal(cand.line_s, [0.0, dist])
        assert np.array_equal(cand.line[1], cand.q)
        T_pre, T_end = _payload_frames(scenario, cand.line)
        np.testing.assert_allclose(T_end, T_goal, atol=1e-9)
        np.testing.assert_allclose(T_pre[:3, 3], T_goal[:3, 3] - dist * d, atol=1e-9)
        np.testing.assert_allclose(T_pre[:3, :3], T_end[:3, :3], atol=1e-9)


def test_approach_line_is_a_straight_joint_space_segment(
    scenario: ResolvedScenario, lines: list[GoalCandidate]
) -> None:
    """A pure translation with (gamma, d5) held is a straight line in joint space.

    Every interpolated configuration puts the payload on the Cartesian line, at the matching fraction,
    with fixed orientation.
    """
    robot = scenario.robot
    fixed = [robot.joint_names.index(n) for n in ("gamma", "theta3", "theta4", "d5", "theta6")]
    for cand in lines:
        assert cand.line is not None
        q_pre, q_goal = cand.line
        assert np.array_equal(q_pre[fixed], q_goal[fixed])
        tau = np.linspace(0.0, 1.0, 10)
        qs = q_pre + tau[:, None] * (q_goal - q_pre)
        T = _payload_frames(scenario, qs)
        T_pre, T_end = T[0], T[-1]
        expected = T_pre[:3, 3] + tau[:, None] * (T_end[:3, 3] - T_pre[:3, 3])
        np.testing.assert_allclose(T[:, :3, 3], expected, atol=1e-9)
        np.testing.assert_allclose(T[:, :3, :3], np.broadcast_to(T_end[:3, :3], (10, 3, 3)), atol=1e-9)


def test_approach_lines_are_best_margin_first_certified_and_holdable(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, lines: list[GoalCandidate]
) -> None:
    robot = scenario.robot
    margins = [c.min_margin for c in lines]
    assert margins == sorted(margins, reverse=True)
    keys = [c.q[[3, 6]] for c in lines]
    for cand in lines:
        assert cand.line is not None
        # The line's margin is the smallest along it (independent route: per-configuration margins).
        tau = np.linspace(0.0, 1.0, 11)
        qs = cand.line[0] + tau[:, None] * (cand.line[1] - cand.line[0])
        assert cand.min_margin == pytest.approx(min(normalised_margin(robot, q) for q in qs), abs=1e-9)
        assert cand.min_margin >= 0.0
        assert world.is_valid(cand.q, CLEARANCE_M)
        assert certify_motion(world, cand.line[0], cand.line[1], CLEARANCE_M, MOTION_MARGIN_M).valid
        dense = cand.line[0] + np.linspace(0, 1, 25)[:, None] * (cand.line[1] - cand.line[0])
        assert np.all(forces.ratios(dense) <= forces.fraction)
    for i in range(len(keys)):  # diverse redundancy: distinct (gamma, d5)
        for j in range(i):
            assert np.any(np.abs(keys[i] - keys[j]) >= np.array([0.05, 0.06]))


def test_goal_configurations_are_exact_valid_and_holdable(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck
) -> None:
    assert scenario.T_base_tool_goal is not None
    cands, stats = goal_configurations(
        world, scenario.T_base_tool_goal, CLEARANCE_M, forces, np.array(scenario.start_u)
    )
    assert cands, stats
    assert len(cands) <= 6
    assert stats["family_points"] >= len(cands)
    robot = scenario.robot
    for cand in cands:
        np.testing.assert_allclose(robot.fk(cand.q), scenario.T_base_tool_goal, atol=1e-9)
        assert not robot.violations(cand.q)
        assert world.is_valid(cand.q, CLEARANCE_M)
        assert forces.ok(cand.q)
        assert cand.min_margin == pytest.approx(normalised_margin(robot, cand.q), abs=1e-12)
    margins = [c.min_margin for c in cands]
    assert margins == sorted(margins, reverse=True)


def test_static_force_ratios_equal_inverse_dynamics_at_rest(
    scenario: ResolvedScenario, forces: StaticForceCheck
) -> None:
    """Static ratios equal the Lagrangian gravity torques mapped to the drives by virtual work.

    Independent route: tau_q = G^T tau_u with G = du/dq. Both the row-by-row (small) and the mapped
    (large) batch paths of the dynamics are exercised.
    """
    robot = scenario.robot
    assert scenario.payload is not None
    payload = scenario.payload.rigid_payload()
    dyn = Cabin8Dynamics(robot)
    qs = admissible_joints(robot, 30, seed=5)
    expected = []
    for q in qs:
        tau_q = dyn.inverse_dynamics_lagrange(q, np.zeros(8), np.zeros(8), payload)
        G, _ = robot.drive_map_jacobian(q)
        tau_u = np.linalg.solve(G.T, np.ravel(tau_q))
        expected.append(np.max(np.abs(tau_u) / robot.limits.effort_max))
    expected_arr = np.array(expected)
    np.testing.assert_allclose(forces.ratios(qs), expected_arr, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(forces.ratios(qs[:5]), expected_arr[:5], rtol=1e-9, atol=1e-12)
    for q, r in zip(qs[:5], expected_arr[:5], strict=True):
        assert forces.ok(q) == (r <= forces.fraction)
    # The payload's weight shows: holding it changes the drive forces (the check is not the bare arm's).
    bare = StaticForceCheck(dyn, None)
    assert np.max(np.abs(forces.ratios(qs) - bare.ratios(qs))) > 0.01


def test_line_speed_bounds_hold_the_planned_line_and_the_rail(
    scenario: ResolvedScenario, lines: list[GoalCandidate]
) -> None:
    """The linear programs' speeds are attainable and are upper bounds.

    The planned line's own speed at full drive velocity never exceeds the bound; the rail cannot move
    while the payload is on this line; along the rail, the rail alone moves the payload at its v_max.
    """
    assert scenario.payload is not None and scenario.approach_direction is not None
    robot, T_tp = scenario.robot, scenario.payload.T_tool_payload
    line = lines[0].line
    assert line is not None
    qs = line[0] + np.linspace(0.0, 1.0, 5)[:, None] * (line[1] - line[0])
    b = line_speed_bounds(robot, qs, T_tp, scenario.approach_direction)
    # The planned (straight joint-space) line at its fastest: the drive nearest its limit at v_max.
    G, _ = robot.drive_map_jacobian(qs[0])
    du = G @ (line[1] - line[0])
    planned = scenario.approach_distance_m / float(np.max(np.abs(du) / robot.limits.v_max))
    assert np.all(b.line_m_s >= planned - 1e-9) and np.all(b.line_m_s < 1.0)
    np.testing.assert_allclose(b.rail_m_s, 0.0, atol=1e-9)
    along_rail = line_speed_bounds(robot, qs[:1], T_tp, np.array([0.0, 0.0, 1.0]))
    assert along_rail.line_m_s[0] >= robot.limits.v_max[0] - 1e-9
    assert along_rail.rail_m_s[0] >= robot.limits.v_max[0] - 1e-9


def test_a_limit_refusal_names_the_limit_furthest_outside_and_by_how_much(robot) -> None:  # noqa: ANN001
    """limit_evidence picks the worst violation relative to its range; describe and dominant read it."""
    from planner.plan.goals import describe, dominant, limit_evidence

    q = admissible_joints(robot, 1, 0)[0]
    q[0] = robot.limits.upper[0] + 0.05  # the rail 50 mm past its end
    q[6] = robot.limits.lower[6] - 0.001  # d5 1 mm short: a smaller share of its range
    violations = robot.violations(q)
    names = {v["name"] for v in violations}
    assert len(names) >= 2
    e = limit_evidence(violations, q, "at the compensated goal")
    rail = next(v for v in violations if v["value"] == pytest.approx(q[0]))
    assert e["cause"] == "limit" and e["limit"] == rail["name"]
    assert e["excess"] == pytest.approx(0.05, abs=1e-12)
    assert e["span"] == pytest.approx(robot.limits.upper[0] - robot.limits.lower[0])
    text = describe(e)
    assert text.startswith(f"{rail['name']} = ") and "by 0.05 at the compensated goal" in text
    # Ranked against clearance records by relative shortfall: 50 mm of a 6 m rail is 0.83% of its range,
    # 0.05 mm short of 10 mm is 0.5% (closer to passing), 1 mm short is 10% (further).
    close = {"cause": "clearance", "bodies": ["payload", "cabin"], "distance_m": 0.00995, "required_m": 0.01}
    far = {**close, "distance_m": 0.009}
    assert dominant([e, close]) is close
    assert dominant([e, far]) is e
    assert dominant([e, close], "limit") is e
    not_finite = [{"name": "finite", "value": [float("nan")], "lower": None, "upper": None}]
    nan = limit_evidence(not_finite, q, "here")
    assert nan["excess"] is None and describe(nan) == "finite is not finite here"
    assert dominant([nan, e]) is e


class _Distances:
    """A stand-in world whose exact distances are given: the cabin's, and the robot pairs'."""

    def __init__(self, cabin_m: float, pair_m: float, self_clearance: float = 0.005) -> None:
        from planner.collision.reports import Distance

        nan3 = np.full(3, np.nan)
        self.cabin = object()
        self.obstacles = None
        self.self_clearance = self_clearance
        self._cabin = Distance(cabin_m, ("payload", "cabin"), nan3, nan3)
        self._pair = Distance(pair_m, ("link_ef", "platform"), nan3, nan3)

    def is_environment(self, name: str) -> bool:
        return name == "cabin"

    def min_distance(self, q: np.ndarray, include_self: bool = True, include_cabin: bool = True):  # noqa: ANN201
        options = ([self._cabin] if include_cabin else []) + ([self._pair] if include_self else [])
        return min(options, key=lambda d: d.distance_m)


@pytest.mark.parametrize(
    ("cabin_m", "pair_m", "self_clearance", "blocking"),
    [
        (0.009, 0.008, 0.005, "cabin"),  # the closer pair passes (8 > 5.5 mm); the cabin fails (9 < 10.5)
        (0.020, 0.0052, 0.005, "platform"),  # the pair fails its 5.5 mm
        (0.009, 0.0052, 0.005, "cabin"),  # both fail: the cabin by more
        (0.009, 0.012, 0.015, "platform"),  # self-clearance above the clearance: the farther pair fails more
    ],
)
def test_collision_evidence_reports_the_kind_furthest_short(
    cabin_m: float, pair_m: float, self_clearance: float, blocking: str
) -> None:
    """A robot pair that passes never hides a cabin distance that fails, nor the other way round."""
    from planner.plan.goals import collision_evidence

    world = _Distances(cabin_m, pair_m, self_clearance)
    e = collision_evidence(world, np.zeros(8), 0.010, "at the goal", margin_m=0.0005)  # type: ignore[arg-type]
    assert e["bodies"][1] == blocking
    if blocking == "cabin":
        assert e["distance_m"] == cabin_m and e["required_m"] == pytest.approx(0.0105)
    else:
        assert e["distance_m"] == pair_m and e["required_m"] == pytest.approx(self_clearance + 0.0005)
