"""Transit postures: a compact posture rides the rail through the hatch where the start posture cannot."""

from __future__ import annotations

import numpy as np
import pytest

from planner.collision.world import CollisionWorld
from planner.dynamics.holding import StaticForceCheck
from planner.plan.motion import certify_motion
from planner.plan.shortcut import segment_times
from planner.plan.transit import DRAWS_KEPT, Transit, compactness, find_transit, ranked_pool, seeded_draw
from planner.redundancy.ik import random_admissible_joints
from planner.scenario.resolve import ResolvedScenario, load_scenario
from tests.plan.conftest import CLEARANCE_M, MOTION_MARGIN_M, SCENARIOS

HATCH_Z_M = 2.0  # the bulkhead of cabin-hatch


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(SCENARIOS / "hatch-pass.yaml")


def _transit(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, seed: int
) -> Transit | None:
    assert scenario.goal_q is not None
    return find_transit(
        world,
        np.array(scenario.start_q),
        np.array(scenario.goal_q),
        CLEARANCE_M,
        MOTION_MARGIN_M,
        forces.ok,
        forces.segment_ok,
        seed,
    )


@pytest.fixture(scope="module")
def transit(scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck) -> Transit:
    found = _transit(scenario, world, forces, seed=1)
    assert found is not None
    return found


def test_the_start_posture_cannot_ride_the_rail_through_the_hatch(
    scenario: ResolvedScenario, world: CollisionWorld
) -> None:
    assert scenario.goal_q is not None
    q_start = np.array(scenario.start_q)
    at_goal_d1 = q_start.copy()
    at_goal_d1[0] = scenario.goal_q[0]
    assert q_start[0] < HATCH_Z_M < at_goal_d1[0]
    assert not world.check_motion(q_start, at_goal_d1, CLEARANCE_M, MOTION_MARGIN_M).valid
    # A real contact, not conservatism: some state on the way (every 5 cm) is itself invalid.
    d1s = np.arange(q_start[0], at_goal_d1[0], 0.05)
    on_rail = np.repeat(q_start[None, :], len(d1s), axis=0)
    on_rail[:, 0] = d1s
    assert not all(world.is_valid(q, CLEARANCE_M) for q in on_rail)


def test_transit_posture_rides_the_rail_from_start_to_goal(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, transit: Transit
) -> None:
    assert scenario.goal_q is not None
    q_a, q_b = transit.q_a, transit.q_b
    assert q_a[0] == scenario.start_q[0] and q_b[0] == scenario.goal_q[0]
    assert np.array_equal(q_a[1:], q_b[1:])  # one posture, only the rail moves
    assert not scenario.robot.violations(q_a)
    assert world.check_motion(q_a, q_b, CLEARANCE_M, MOTION_MARGIN_M).valid
    assert forces.segment_ok(q_a, q_b)
    # Independent route: exact distances along the rail (through the hatch) never below the clearance.
    d1s = np.linspace(q_a[0], q_b[0], 23)
    qs = np.repeat(q_a[None, :], len(d1s), axis=0)
    qs[:, 0] = d1s
    assert np.min(world.clearance_profile(qs)) >= CLEARANCE_M - 1e-9
    assert transit.candidates_tried >= 3  # neither the start's nor the goal's own posture fits
    assert transit.state_checks >= transit.candidates_tried


def test_transit_posture_passes_where_the_start_posture_cannot(
    scenario: ResolvedScenario, world: CollisionWorld, transit: Transit
) -> None:
    """The start's own posture cannot ride through the hatch; the transit posture can.

    Riders are ranked by the time their posture changes need, not by compactness, so the transit posture
    need not be the more compact of the two.
    """
    assert scenario.goal_q is not None
    ride = np.array(scenario.start_q)
    ride_end = ride.copy()
    ride_end[0] = scenario.goal_q[0]
    assert not certify_motion(world, ride, ride_end, CLEARANCE_M, MOTION_MARGIN_M).valid
    assert certify_motion(world, transit.q_a, transit.q_b, CLEARANCE_M, MOTION_MARGIN_M).valid
    c = compactness(world, np.stack([transit.q_a, np.array(scenario.start_q)]))
    assert c.shape == (2,) and np.all(np.isfinite(c))
    # Compactness ignores the rail: the same posture anywhere along it is equally compact.
    np.testing.assert_allclose(compactness(world, transit.q_b[None, :]), c[:1], atol=1e-12)


def test_seeded_transit_is_reproducible(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, transit: Transit
) -> None:
    again = _transit(scenario, world, forces, seed=1)
    assert again is not None
    assert np.array_equal(again.q_a, transit.q_a) and np.array_equal(again.q_b, transit.q_b)
    assert (again.candidates_tried, again.state_checks) == (transit.candidates_tried, transit.state_checks)


def test_the_ranked_pool_is_drawn_once_per_world_and_is_the_seeded_draw_ranked(
    scenario: ResolvedScenario, world: CollisionWorld
) -> None:
    """A relay's rides and the transit search share one pool: the same rows as a fresh draw, ranked."""
    pool = ranked_pool(world, 5, 300)
    assert ranked_pool(world, 5, 300) is pool  # kept with the world
    assert ranked_pool(world, 6, 300) is not pool
    drawn = random_admissible_joints(world.robot, np.random.default_rng(5), 300, max_tries=1200)
    expected = drawn[np.argsort(compactness(world, drawn), kind="stable")]
    assert np.array_equal(pool, expected)
    assert not pool.flags.writeable  # a search that wrote into a posture would change the next one's pool


def test_the_seeded_draw_is_kept_per_robot_and_shared_by_its_worlds(
    scenario: ResolvedScenario, world: CollisionWorld
) -> None:
    """Every world of the robot ranks the same seeded draw (drawn once), each for its own payload."""
    drawn = seeded_draw(world.robot, 7, 300)
    assert seeded_draw(world.robot, 7, 300) is drawn and not drawn.flags.writeable
    fresh = random_admissible_joints(world.robot, np.random.default_rng(7), 300, max_tries=1200)
    assert np.array_equal(drawn, fresh)
    other = CollisionWorld(world.robot, None)  # another world of the same robot: no cabin
    pool = ranked_pool(other, 7, 300)
    assert np.array_equal(pool, drawn[np.argsort(compactness(other, drawn), kind="stable")])
    assert seeded_draw(world.robot, 7, 300) is drawn  # ranking it wrote nothing into the draw
    for seed in range(100, 100 + DRAWS_KEPT):  # the oldest draws go first, and come back the same
        seeded_draw(world.robot, seed, 300)
    again = seeded_draw(world.robot, 7, 300)
    assert again is not drawn and np.array_equal(again, drawn)


def test_the_ranked_pool_is_shared_by_the_worlds_that_carry_the_same_payload(
    scenario: ResolvedScenario, world: CollisionWorld
) -> None:
    """A sweep's next world (the same robot and payload, another cabin) ranks nothing: the same pool.

    Another payload, or the reference route, ranks its own (each equal to its fresh ranking).
    """
    from planner.collision.bodies import PayloadGeometry
    from planner.collision.oracle import ReferenceWorld
    from planner.meshes import REFERENCE_DIR
    from planner.meshio import load_mesh

    pool = ranked_pool(world, 8, 300)
    drawn = seeded_draw(world.robot, 8, 300)
    aisle = load_mesh(REFERENCE_DIR / "cabin-aisle.stl", units="m")
    other_cabin = CollisionWorld(world.robot, aisle, scenario.payload)  # the ranking ignores the cabin
    assert other_cabin.cover_digest() == world.cover_digest()
    assert ranked_pool(other_cabin, 8, 300) is pool
    grasp = np.eye(4)
    grasp[:3, 3] = [0.0, 0.0, 0.35]
    heavier = CollisionWorld(
        world.robot, None, PayloadGeometry((0.6, 0.3, 0.3), T_tool_payload=grasp, mass=80.0)
    )
    reference = ReferenceWorld(world.robot, None, scenario.payload)
    for w in (heavier, reference):
        assert w.cover_digest() != world.cover_digest()
        own = ranked_pool(w, 8, 300)
        assert own is not pool
        assert np.array_equal(own, drawn[np.argsort(compactness(w, drawn), kind="stable")])
    assert not np.array_equal(ranked_pool(heavier, 8, 300), pool)  # a longer payload ranks differently


def test_the_rides_extra_condition_is_asked_before_its_certification(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, transit: Transit
) -> None:
    """A rider the extra condition refuses costs no certified motion check.

    The rider taken is the first in order that passes both (a relay's change of posture refuses most).
    """
    assert scenario.goal_q is not None
    args = (world, np.array(scenario.start_q), np.array(scenario.goal_q), CLEARANCE_M, MOTION_MARGIN_M)
    calls = {"extra": 0, "walks": 0}
    walk = world.check_motion

    def counting_walk(*a: object, **k: object) -> object:
        calls["walks"] += 1
        return walk(*a, **k)  # type: ignore[arg-type]

    def refuse_all(q_a: np.ndarray, q_b: np.ndarray) -> bool:
        calls["extra"] += 1
        return False

    world.check_motion = counting_walk  # type: ignore[method-assign]
    try:
        assert find_transit(*args, forces.ok, refuse_all, 1) is None
    finally:
        del world.check_motion
    assert calls["extra"] > 0 and calls["walks"] == 0
    # Refusing the first rider the plain search takes: the next one passing both is taken instead.
    taken = transit.q_a.copy()

    def not_that_one(q_a: np.ndarray, q_b: np.ndarray) -> bool:
        return not np.array_equal(q_a, taken) and forces.segment_ok(q_a, q_b)

    other = find_transit(*args, forces.ok, not_that_one, 1)
    assert other is not None and not np.array_equal(other.q_a, taken)
    assert forces.segment_ok(other.q_a, other.q_b)
    assert certify_motion(world, other.q_a, other.q_b, CLEARANCE_M, MOTION_MARGIN_M).valid


def test_the_pools_posture_condition_batched_gives_the_same_transit(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, transit: Transit
) -> None:
    """``states_ok`` (the static forces of the swept pool at once) decides as ``state_ok`` one by one."""
    assert scenario.goal_q is not None
    assert transit.candidates_tried > 2  # the pool was swept, so the batched verdicts were used
    asked: list[int] = []

    def batched(qs: np.ndarray) -> np.ndarray:
        asked.append(len(qs))
        return forces.ratios(qs) <= forces.fraction

    args = (world, np.array(scenario.start_q), np.array(scenario.goal_q), CLEARANCE_M, MOTION_MARGIN_M)
    found = find_transit(*args, forces.ok, forces.segment_ok, 1, states_ok=batched)
    assert found is not None and asked == [398]  # once, on the swept part of the pool (n_sweep - 2)
    assert np.array_equal(found.q_a, transit.q_a) and np.array_equal(found.q_b, transit.q_b)
    assert (found.candidates_tried, found.state_checks) == (transit.candidates_tried, transit.state_checks)
    # The batched verdicts are the ones used: a pool nothing of which is holdable gives no pool rider.
    none = find_transit(*args, forces.ok, forces.segment_ok, 1, states_ok=lambda qs: np.zeros(len(qs), bool))
    assert none is None


def test_of_the_riding_postures_the_one_quickest_to_reach_is_taken(
    scenario: ResolvedScenario, world: CollisionWorld, forces: StaticForceCheck, transit: Transit
) -> None:
    """Ranking the riders by the posture change they need beats taking the most compact one."""
    assert scenario.goal_q is not None
    q_start, q_goal = np.array(scenario.start_q), np.array(scenario.goal_q)
    compact = find_transit(
        world, q_start, q_goal, CLEARANCE_M, MOTION_MARGIN_M, forces.ok, forces.segment_ok, 1, n_riders=1
    )
    assert compact is not None

    def change(t: Transit) -> float:
        robot = scenario.robot
        return float(
            segment_times(robot, q_start, q_start, t.q_a)[0] + segment_times(robot, q_goal, t.q_b, q_goal)[0]
        )

    assert change(transit) <= change(compact)
    assert compactness(world, compact.q_a[None, :])[0] <= compactness(world, transit.q_a[None, :])[0]


def test_a_start_posture_that_rides_only_at_the_sweep_samples_does_not_end_the_search() -> None:
    """The start's own posture passes the sampled sweep but its ride is not certified: the pool is swept.

    The posture is home with the platform 15 cm to the side; along the rail it clears a 2 mm plate by
    12.9 mm at best: at every sampled d1 by the clearance (12.6 mm), but not by the clearance plus the
    certified walk's smallest margin (:data:`planner.plan.motion.MIN_MARGIN_M`).
    """
    from planner.collision.bodies import PayloadGeometry
    from planner.plan.motion import motion_clear
    from planner.robots.cabin8 import Cabin8
    from tests.collision.test_check_path import home, plate_mesh

    robot = Cabin8()
    grasp = np.eye(4)
    grasp[2, 3] = 0.30
    world = CollisionWorld(robot, plate_mesh(robot), PayloadGeometry((0.45, 0.35, 0.5), T_tool_payload=grasp))
    clearance, margin = 0.0126, 0.005
    q_start, q_goal = home(robot, d1=1.0), home(robot, d1=4.0)
    q_start[1] -= 0.15
    on_rail = np.repeat(q_start[None, :], 61, axis=0)
    on_rail[:, 0] = np.linspace(1.0, 4.0, 61)  # the sweep's rail positions (5 cm)
    assert all(world.is_valid(q, clearance) for q in on_rail)
    ride_end = q_start.copy()
    ride_end[0] = 4.0
    assert not motion_clear(world, q_start, ride_end, clearance, margin)
    found = find_transit(world, q_start, q_goal, clearance, margin, lambda q: True, lambda a, b: True, seed=0)
    assert found is not None and found.candidates_tried > 2
    assert motion_clear(world, found.q_a, found.q_b, clearance, margin)
