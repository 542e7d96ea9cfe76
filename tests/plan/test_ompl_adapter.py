"""OMPL adapter: every offered planner returns a certified, exact-ended, reproducible path, or None."""

from __future__ import annotations

import typing
from pathlib import Path

import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.plan.connect import joint_box
from planner.plan.motion import certify_motion
from planner.plan.ompl_adapter import PLANNERS, SearchResult, joint_scale, plan_joint_path
from planner.scenario.resolve import ResolvedScenario, load_scenario
from planner.scenario.schema import PlannerName

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
CLEARANCE_M = 0.01
MOTION_MARGIN_M = 0.005
#: Motion-check budget: the optimising planners (RRT*, AORRTC) run until it is spent, so it bounds the
#: test time; every planner finds the path below within it for SEED (measured).
BUDGET = 200
SEED = 1


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "aisle-bay-insert.yaml")


@pytest.fixture(scope="module")
def problem(scenario: ResolvedScenario, world: CollisionWorld) -> tuple[np.ndarray, np.ndarray]:
    """The scenario's start and the same posture with the column turned to theta3 = -1.2 rad.

    Turning the column through theta3 = 0 swings the arm into the rack: the straight motion is blocked.
    """
    q_start = np.array(scenario.start_q)
    q_goal = q_start.copy()
    q_goal[scenario.robot.joint_names.index("theta3")] = -1.2
    return q_start, q_goal


def _plan(world: CollisionWorld, q_start: np.ndarray, q_goal: np.ndarray, planner: str, **kw: object):
    lo, hi = joint_box(world)
    options: dict[str, object] = {
        "clearance": CLEARANCE_M,
        "motion_margin": MOTION_MARGIN_M,
        "time_limit_s": 60.0,
        "seed": SEED,
        "planner": planner,
        "joint_lower": lo,
        "joint_upper": hi,
        "max_motion_checks": BUDGET,
    }
    options.update(kw)
    return plan_joint_path(world, q_start, [q_goal], **options)  # type: ignore[arg-type]


def test_offered_planners_are_the_scenario_schema_names() -> None:
    assert set(PLANNERS) == set(typing.get_args(PlannerName))
    assert len(PLANNERS) == len(typing.get_args(PlannerName))


def test_the_problem_needs_a_planner(world: CollisionWorld, problem: tuple[np.ndarray, np.ndarray]) -> None:
    q_start, q_goal = problem
    assert world.is_valid(q_start, CLEARANCE_M) and world.is_valid(q_goal, CLEARANCE_M)
    assert not certify_motion(world, q_start, q_goal, CLEARANCE_M, MOTION_MARGIN_M).valid


def _assert_certified(
    world: CollisionWorld, res: SearchResult, q_start: np.ndarray, q_goal: np.ndarray
) -> None:
    wp = res.waypoints
    assert wp.ndim == 2 and wp.shape[1] == 8 and len(wp) >= 3  # the straight motion is blocked
    assert np.array_equal(wp[0], q_start) and np.array_equal(wp[-1], q_goal)
    assert res.goal_index == 0
    lo, hi = joint_box(world)
    assert np.all(wp >= lo - 1e-12) and np.all(wp <= hi + 1e-12)
    for a, b in zip(wp[:-1], wp[1:], strict=True):
        assert certify_motion(world, a, b, CLEARANCE_M, MOTION_MARGIN_M).valid


@pytest.mark.parametrize("planner", sorted(PLANNERS))
def test_each_planner_finds_a_certified_reproducible_path(
    world: CollisionWorld, problem: tuple[np.ndarray, np.ndarray], planner: str
) -> None:
    q_start, q_goal = problem
    first = _plan(world, q_start, q_goal, planner)
    second = _plan(world, q_start, q_goal, planner)
    assert first is not None and second is not None, f"{planner} found no path within {BUDGET} checks"
    assert first.planner == planner
    _assert_certified(world, first, q_start, q_goal)
    # The same seed in the same process: the very same path (bit for bit) and the same work.
    assert np.array_equal(first.waypoints, second.waypoints)
    assert first.raw_waypoints == second.raw_waypoints
    assert first.motion_checks == second.motion_checks


def test_another_seed_also_gives_a_certified_path(
    world: CollisionWorld, problem: tuple[np.ndarray, np.ndarray]
) -> None:
    """A different seed may give a different path, but it must be just as certified."""
    q_start, q_goal = problem
    res = _plan(world, q_start, q_goal, "RRTConnect", seed=SEED + 1)
    assert res is not None
    _assert_certified(world, res, q_start, q_goal)


def test_a_budget_too_small_for_the_problem_gives_none(
    world: CollisionWorld, problem: tuple[np.ndarray, np.ndarray]
) -> None:
    """The straight motion is blocked, so any path needs at least two certified motions: one is not enough."""
    q_start, q_goal = problem
    assert _plan(world, q_start, q_goal, "RRTConnect", max_motion_checks=1) is None


def test_joint_scale_is_the_joint_speed_at_the_drive_limits(world: CollisionWorld) -> None:
    robot = world.robot
    w = joint_scale(world)
    v = robot.limits.v_max
    assert w.shape == (8,) and np.all(np.isfinite(w)) and np.all(w > 0)
    # Joints that are drives themselves move at their drive's limit.
    for name in ("d1", "theta3", "theta4", "d5", "theta6"):
        i = robot.joint_names.index(name)
        assert w[i] == v[robot.drive_names.index(name)]
    # Platform coordinates, an independent route (finite differences of the drive map at home): moving
    # joint j alone at w_j, the fastest slider runs exactly at its velocity limit.
    q0 = robot.joints_from_drives(robot.home_drives)
    h = 1e-6
    for j in (1, 2, 3):
        e = np.zeros(8)
        e[j] = h
        du_dq = (robot.drives_from_joints(q0 + e) - robot.drives_from_joints(q0 - e)) / (2 * h)
        assert np.max(np.abs(du_dq) * w[j] / v) == pytest.approx(1.0, abs=1e-6)
