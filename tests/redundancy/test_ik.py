"""Redundant IK: exact where reachable, limits hold, clear refusals, solver-independent QP steps."""

from __future__ import annotations

import numpy as np
import pytest

from planner.core.exceptions import GoalUnreachable, InvalidInput
from planner.core.so3 import pose_error
from planner.kinematics.closed_form import redundant_family
from planner.redundancy.configuration import Configuration
from planner.redundancy.ik import IKOptions, solve_pose_ik
from planner.redundancy.limits import AdmissibilityLimit, DriveVelocityLimit
from planner.redundancy.solve import build_problem, solve_problem, solve_step
from planner.redundancy.tasks import FrameTask, MarginTask, PostureTask
from planner.robots.cabin8 import Cabin8
from tests.conftest import admissible_joints


def test_fk_of_ik_matches_reachable_poses(robot: Cabin8) -> None:
    targets = admissible_joints(robot, 60, seed=99)
    for q_true in targets:
        T = robot.fk(q_true)
        sol = solve_pose_ik(robot, T)
        err = pose_error(T, robot.fk(sol.q))
        assert np.linalg.norm(err[:3]) < 1e-6 and np.linalg.norm(err[3:]) < 1e-6
        assert not robot.violations(sol.q), "every limit and singularity margin holds"
        np.testing.assert_allclose(sol.u, robot.drives_from_joints(sol.q))
        assert np.all(sol.u >= robot.limits.lower) and np.all(sol.u <= robot.limits.upper)


def test_redundant_family_is_exact_and_complete(robot: Cabin8, configs: np.ndarray) -> None:
    """Every (gamma, d5) member reaches the pose, and every configuration is the member of its own pair."""
    rng = np.random.default_rng(12)
    for q in configs[:50]:
        T = robot.fk(q)
        own = redundant_family(robot.desc.serial_chain, T, q[3:4], q[6:7])[0]
        np.testing.assert_allclose(own, q, atol=1e-12)
        others = redundant_family(
            robot.desc.serial_chain, T, rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.5, 0, 20)
        )
        for member in others:
            np.testing.assert_allclose(robot.fk(member), T, atol=1e-12)


def test_redundant_family_of_many_poses_at_once(robot: Cabin8, configs: np.ndarray) -> None:
    """One pose per (gamma, d5) pair (a batch): each configuration is recovered from its own pose."""
    q = configs[:50]
    T = robot.fk_batch(q)
    np.testing.assert_allclose(redundant_family(robot.desc.serial_chain, T, q[:, 3], q[:, 6]), q, atol=1e-12)


def test_near_selects_between_distinct_solutions(robot: Cabin8) -> None:
    """One pose, two admissible configurations far apart on the self-motion manifold: near decides."""
    q_a = robot.joints_from_drives(robot.home_drives)
    T = robot.fk(q_a)
    family = redundant_family(
        robot.desc.serial_chain,
        T,
        np.repeat(np.linspace(-0.3, 0.3, 13), 11),
        np.tile(np.linspace(-0.45, -0.05, 11), 13),
    )
    admissible = [q for q in family if not robot.violations(q)]
    u_b = max(
        (robot.drives_from_joints(q) for q in admissible), key=lambda u: np.linalg.norm(u - robot.home_drives)
    )
    assert np.linalg.norm(u_b - robot.home_drives) > 0.1
    for near in (robot.home_drives, u_b):
        sol = solve_pose_ik(robot, T, near_drives=near)
        other = u_b if near is robot.home_drives else robot.home_drives
        assert np.linalg.norm(sol.u - near) < 0.2 * np.linalg.norm(sol.u - other)
        np.testing.assert_allclose(robot.fk(sol.q), T, atol=1e-9)


def test_unreachable_pose_raises_with_evidence(robot: Cabin8) -> None:
    T = np.eye(4)
    T[:3, 3] = [2.5, 0.5, 1.0]  # 2.5 m lateral: beyond the arm
    with pytest.raises(GoalUnreachable) as err:
        solve_pose_ik(robot, T, options=IKOptions(n_seeds=4))
    assert err.value.details["best_position_error_m"] > 0.5
    assert err.value.details["seeds"] >= 4


def test_pose_beyond_the_rail_is_unreachable(robot: Cabin8) -> None:
    T = robot.fk(robot.joints_from_drives(robot.home_drives))
    T[2, 3] = robot.rail_length + 1.5
    with pytest.raises(GoalUnreachable):
        solve_pose_ik(robot, T, options=IKOptions(n_seeds=3))


def test_rail_length_limits_ik(robot: Cabin8) -> None:
    short = Cabin8(rail_length=2.0)
    q = robot.joints_from_drives(robot.home_drives)
    q[0] = 4.0
    with pytest.raises(GoalUnreachable):
        solve_pose_ik(short, robot.fk(q), options=IKOptions(n_seeds=3))
    assert solve_pose_ik(robot, robot.fk(q)).u[0] <= robot.rail_length


@pytest.mark.parametrize(
    "T",
    [np.full((4, 4), np.nan), np.diag([2.0, 1.0, 1.0, 1.0]), np.eye(3)],
)
def test_malformed_target_is_invalid_input(robot: Cabin8, T: np.ndarray) -> None:
    with pytest.raises(InvalidInput):
        solve_pose_ik(robot, T)


def test_ik_is_reproducible(robot: Cabin8) -> None:
    q = admissible_joints(robot, 1, seed=5)[0]
    a = solve_pose_ik(robot, robot.fk(q), options=IKOptions(seed=3))
    b = solve_pose_ik(robot, robot.fk(q), options=IKOptions(seed=3))
    np.testing.assert_array_equal(a.q, b.q)


def test_qp_solvers_agree_and_limits_hold(robot: Cabin8, configs: np.ndarray) -> None:
    rng = np.random.default_rng(2)
    for q in configs[:20]:
        cfg = Configuration(robot, q)
        T = cfg.T_base_tool.copy()
        T[:3, 3] += rng.uniform(-0.1, 0.1, 3)
        tasks = [FrameTask(T, lm_damping=1e-3), PostureTask(q, 0.05)]
        limits = [AdmissibilityLimit(0.9), DriveVelocityLimit(dt=0.1)]
        problem = build_problem(cfg, tasks, limits, step_max=np.full(8, 0.2))
        steps = {s: solve_problem(problem, s) for s in ("daqp", "quadprog", "osqp")}
        for s in ("quadprog", "osqp"):
            np.testing.assert_allclose(steps[s], steps["daqp"], atol=1e-6)
        dq = steps["daqp"]
        assert np.all(problem.G @ dq <= problem.h + 1e-9)
        du = cfg.dc_dq[:8] @ dq
        assert np.all(np.abs(du) <= robot.limits.v_max * 0.1 + 1e-9)


def test_margin_task_moves_away_from_a_bound(robot: Cabin8) -> None:
    q = robot.joints_from_drives(robot.home_drives)
    q[5] = robot.limits.upper[5] - 0.01  # theta4 close to its upper limit
    cfg = Configuration(robot, q)
    comfort = np.full(len(robot.constraint_specs), 0.05)
    dq = solve_step(cfg, [MarginTask(comfort, 1.0)], [AdmissibilityLimit()], step_max=np.full(8, 0.1))
    assert dq[5] < -1e-3
    assert robot.margins(q + dq).min() > robot.margins(q).min()


def test_compiled_step_equals_the_generic_task_qp(robot: Cabin8, configs: np.ndarray) -> None:
    """The IK hot loop's compiled QP is the same QP the task/limit classes assemble."""
    from planner.redundancy.compiled_step import IKStep, StepWeights
    from planner.redundancy.ik import comfort_margins

    rng = np.random.default_rng(21)
    comfort = comfort_margins(robot)
    step = IKStep(robot, comfort)
    w = StepWeights(2.0, 0.7, 1e-3, 0.05, 0.3, 0.9)
    step_max = np.full(8, 0.1)
    for q in configs[:30]:
        cfg = Configuration(robot, q)
        T = cfg.T_base_tool.copy()
        T[:3, 3] += rng.uniform(-0.05, 0.05, 3)
        q_ref = q + rng.normal(size=8) * 0.05
        tasks = [
            FrameTask(T, position_cost=2.0, orientation_cost=0.7, lm_damping=1e-3),
            PostureTask(q_ref, 0.05),
            MarginTask(comfort, 0.3),
        ]
        generic = build_problem(cfg, tasks, [AdmissibilityLimit(0.9)], step_max=step_max)
        fast = step.problem(q, pose_error(T, cfg.T_base_tool), q_ref, w, step_max)
        np.testing.assert_allclose(fast.P, generic.P, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fast.q, generic.q, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(solve_problem(fast), solve_problem(generic), atol=1e-9)
