"""Fixtures of the planning tests: the collision world and static-force check of each module's scenario.

Every test module defines its own module-scoped ``scenario`` fixture; these build on it.
"""

from __future__ import annotations

import pytest

from planner.collision.world import CollisionWorld
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.planning.goals import StaticForceCheck
from planner.scenario import ResolvedScenario


@pytest.fixture(scope="module")
def world(scenario: ResolvedScenario) -> CollisionWorld:
    return CollisionWorld(scenario.robot, scenario.cabin, scenario.payload)


@pytest.fixture(scope="module")
def forces(scenario: ResolvedScenario) -> StaticForceCheck:
    assert scenario.payload is not None
    return StaticForceCheck(Cabin8Dynamics.of(scenario.robot), scenario.payload.rigid_payload())
