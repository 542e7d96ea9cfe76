"""Corner cutting: posture changes move into the rail move, every new segment certified, time saved."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.dynamics.holding import StaticForceCheck
from planner.kinematics import chain
from planner.plan.motion import certify_motion, motion_clear
from planner.plan.shortcut import MIN_GAIN_S, cut_corners, segment_times
from planner.robots.cabin8 import Cabin8
from planner.scenario.resolve import ResolvedScenario, load_scenario
from tests.plan.conftest import CLEARANCE_M, MOTION_MARGIN_M, SCENARIOS


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "aisle-transfer.yaml")


Motion = Callable[[np.ndarray, np.ndarray], bool]


def polyline_time(robot: Cabin8, waypoints: np.ndarray) -> float:
    """Estimated time of a polyline: its segments' times summed (the cutter's own estimate)."""
    return float(
        sum(segment_times(robot, a, a, b)[0] for a, b in zip(waypoints[:-1], waypoints[1:], strict=True))
    )


def _checker(
    world: CollisionWorld, forces: StaticForceCheck, calls: list[tuple[np.ndarray, np.ndarray]]
) -> Motion:
    def ok(q_a: np.ndarray, q_b: np.ndarray) -> bool:
        calls.append((q_a.copy(), q_b.copy()))
        return motion_clear(world, q_a, q_b, CLEARANCE_M, MOTION_MARGIN_M) and forces.segment_ok(q_a, q_b)

    return ok


def _standstill_then_rail(scenario: ResolvedScenario) -> np.ndarray:
    """Start -> (wrist and column turned, same d1) -> (same posture, 1.2 m along the rail)."""
    q0 = np.array(scenario.start_q)
    q1 = q0.copy()
    q1[chain.THETA6] += 0.8
    q1[chain.THETA3] += 0.3
    q2 = q1.copy()
    q2[chain.D1] += 1.2
    return np.stack([q0, q1, q2])


def test_a_standstill_posture_change_moves_into_the_rail_move(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck
) -> None:
    path = _standstill_then_rail(scenario)
    for a, b in zip(path[:-1], path[1:], strict=True):
        assert motion_clear(world, a, b, CLEARANCE_M, MOTION_MARGIN_M)
    calls: list[tuple[np.ndarray, np.ndarray]] = []
    cut, stats = cut_corners(scenario.robot, path, _checker(world, forces, calls))
    assert stats.cuts >= 1 and stats.checks == len(calls)
    np.testing.assert_array_equal(cut[0], path[0])
    np.testing.assert_array_equal(cut[-1], path[-1])
    before, after = polyline_time(scenario.robot, path), polyline_time(scenario.robot, cut)
    assert after <= before - MIN_GAIN_S
    # The posture change now overlaps the rail move: the whole thing takes about the rail's time alone.
    rail_alone = float(segment_times(scenario.robot, path[1], path[1], path[2])[0])
    assert after <= 1.05 * rail_alone
    # Every segment of the result is certified (independently of what the cutter was told).
    for a, b in zip(cut[:-1], cut[1:], strict=True):
        assert certify_motion(world, a, b, CLEARANCE_M, MOTION_MARGIN_M).valid


def test_corner_cutting_is_deterministic_and_keeps_a_path_with_nothing_to_gain(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck
) -> None:
    path = _standstill_then_rail(scenario)
    a, _ = cut_corners(scenario.robot, path, _checker(world, forces, []))
    b, _ = cut_corners(scenario.robot, path, _checker(world, forces, []))
    np.testing.assert_array_equal(a, b)
    straight = np.stack([path[0], 0.5 * (path[0] + path[2]), path[2]])  # collinear: no corner to cut
    calls: list[tuple[np.ndarray, np.ndarray]] = []
    same, stats = cut_corners(scenario.robot, straight, _checker(world, forces, calls))
    np.testing.assert_array_equal(same, straight)
    assert stats.cuts == 0 and not calls


def test_a_cut_that_is_not_certified_is_not_taken(scenario: ResolvedScenario) -> None:
    path = _standstill_then_rail(scenario)
    calls: list[tuple[np.ndarray, np.ndarray]] = []

    def refuse(q_a: np.ndarray, q_b: np.ndarray) -> bool:
        calls.append((q_a, q_b))
        return False

    same, stats = cut_corners(scenario.robot, path, refuse)
    np.testing.assert_array_equal(same, path)
    assert stats.cuts == 0 and stats.checks == len(calls) > 0


def test_the_longest_certified_cut_is_found_with_one_certified_check_per_end(
    scenario: ResolvedScenario,
) -> None:
    """Fractions are tried longest first, and the first certified one is taken.

    Even where validity is not monotone in alpha (here only the longest and the shortest chords are
    certified: a bisection from the middle would settle for the shortest cut), and no other chord of that
    end is walked after it.
    """
    from planner.plan.shortcut import CUT_ENDS, CUT_FRACTIONS

    path = _standstill_then_rail(scenario)
    p, c = path[0], path[1]
    longest, shortest = CUT_FRACTIONS[0], CUT_FRACTIONS[-1]
    certified: list[float] = []
    refused: list[float] = []

    def only_the_extremes(q_a: np.ndarray, q_b: np.ndarray) -> bool:
        alpha = float(np.linalg.norm(q_a - c) / np.linalg.norm(p - c))  # where the chord starts on P -> C
        ok = min(abs(alpha - longest), abs(alpha - shortest)) < 1e-9
        (certified if ok else refused).append(alpha)
        return ok

    cut, stats = cut_corners(scenario.robot, path[:3], only_the_extremes)
    assert stats.cuts == 1
    np.testing.assert_array_equal(cut[0], p)  # alpha = 1: the chord starts at P itself
    assert not refused  # the longest was tried first and was certified
    assert len(certified) <= len(CUT_ENDS)  # one certified walk per end, and nothing tried after it
    assert all(abs(a - longest) < 1e-9 for a in certified)


def test_a_tight_insertion_is_certified_by_one_adaptive_walk() -> None:
    """tightbay-insert has segments a walk at the scenario's margin refuses: one adaptive walk certifies them.

    A fixed margin certifies such a segment only once halved far enough (the walks the planner used to run
    one after the other); the adaptive walk halves it only near the tight states, in fewer states than that
    chain of walks, and still keeps at least MIN_MARGIN_M (tests/collision/test_kernels.py checks the
    clearance it certifies against exact distances).
    """
    from planner.plan.context import PlanContext
    from planner.plan.motion import MIN_MARGIN_M
    from planner.plan.pipeline import Planner

    sc = load_scenario(SCENARIOS / "tightbay-insert.yaml")
    planner = Planner(sc)
    res = planner.plan()
    ctx: PlanContext = planner.ctx
    c = ctx.clearances
    w = res.waypoints
    pieces = list(zip(w[:-1], w[1:], strict=True))
    tight = [
        (a, b) for a, b in pieces if not ctx.world.check_motion(a, b, c.planner_m, c.motion_margin_m).valid
    ]
    assert tight, "no segment of the plan needed a smaller margin"
    for a, b in tight:
        motion = certify_motion(ctx.world, a, b, c.planner_m, c.motion_margin_m)
        assert motion.valid and ctx.motion_ok(a, b)
        margin, states = c.motion_margin_m, 0
        for _ in range(12):
            rep = ctx.world.check_motion(a, b, c.planner_m, margin)
            states += rep.states_checked
            if rep.valid or margin <= MIN_MARGIN_M:
                break
            margin = max(MIN_MARGIN_M, margin / 2)
        assert rep.valid and motion.report.states_checked < states
