"""Obstacles added to a cabin: certified state and motion checks against exact FCL distances."""

from __future__ import annotations

import numpy as np
import pytest

from planner.collision.bodies import PayloadGeometry
from planner.collision.obstacles import Obstacle
from planner.collision.world import CollisionWorld
from planner.robots.cabin8 import Cabin8
from tests.conftest import admissible_joints


@pytest.fixture(scope="module")
def worlds(robot: Cabin8) -> tuple[CollisionWorld, CollisionWorld]:
    payload = PayloadGeometry(size=(0.3, 0.3, 0.2), T_tool_payload=np.diag([1.0, 1, 1, 1]))
    T = np.eye(4)
    T[:3, 3] = [0.25, 0.45, 0.3]
    obstacles = (Obstacle.box("unit X", (0.2, 0.2, 0.2), T),)
    plain = CollisionWorld(robot, None, payload)
    return plain, CollisionWorld(robot, None, payload, obstacles=obstacles)


def test_states_proven_clear_keep_the_clearance(
    worlds: tuple[CollisionWorld, CollisionWorld], robot: Cabin8
) -> None:
    plain, world = worlds
    qs = admissible_joints(robot, 300, seed=3)
    clearance = 0.01
    seen = {True: 0, False: 0}
    for q in qs:
        if not plain.is_valid(q, clearance):
            continue
        d = world.obstacle_distance(world.flat_poses(q)).distance_m
        valid = world.is_valid(q, clearance)
        seen[valid] += 1
        if valid:
            assert d >= clearance, d
        else:  # refused only when a body really is within the clearance (boxes grown as boxes: sqrt(3))
            assert d <= np.sqrt(3) * clearance + 1e-9, d
        assert world.check_state(q, clearance).valid == valid
    assert seen[True] > 10 and seen[False] > 5, seen


def test_certified_motions_keep_the_clearance_between_samples(
    worlds: tuple[CollisionWorld, CollisionWorld], robot: Cabin8
) -> None:
    _, world = worlds
    qs = admissible_joints(robot, 120, seed=5)
    clearance, checked = 0.01, 0
    for q_a, q_b in zip(qs[::2], qs[1::2], strict=True):
        q_b = q_a + 0.3 * (q_b - q_a)
        rep = world.check_motion(q_a, q_b, clearance, 0.002)
        if not rep.valid:
            continue
        checked += 1
        for t in np.linspace(0.0, 1.0, 41):
            q = q_a + t * (q_b - q_a)
            assert world.obstacle_distance(world.flat_poses(q)).distance_m >= clearance
    assert checked > 10


def test_an_allowed_pair_is_left_out_and_measured(robot: Cabin8) -> None:
    payload = PayloadGeometry(size=(0.3, 0.3, 0.2))
    q = admissible_joints(robot, 1, seed=7)[0]
    T = robot.fk(q)
    T[:3, 3] += T[:3, 2] * 0.11  # a 1 cm plate 5 mm past the payload's face (at tool z = 0.1)
    plate = Obstacle.box("unit Y", (0.1, 0.1, 0.01), T)
    strict = CollisionWorld(robot, None, payload, obstacles=(plate,))
    allowed = CollisionWorld(
        robot, None, payload, obstacles=(plate,), allowed=frozenset({("payload", "unit Y")})
    )
    pair = ("payload", "unit Y")
    assert pair in [c.bodies for c in strict.check_state(q, 0.01, all_contacts=True).contacts]
    assert pair not in [c.bodies for c in allowed.check_state(q, 0.01, all_contacts=True).contacts]
    d = allowed.obstacle_distance(allowed.flat_poses(q), obstacle="unit Y", body="payload")
    assert d.distance_m == pytest.approx(0.005, abs=1e-6) and d.bodies == pair
    assert allowed.obstacle_distance(allowed.flat_poses(q)).bodies != pair  # left out of the world's own
