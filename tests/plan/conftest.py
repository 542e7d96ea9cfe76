"""Fixtures of the planning tests: the collision world and static-force check of each module's scenario.

Every test module defines its own module-scoped ``scenario`` fixture; these build on it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from planner.collision.world import CollisionWorld
from planner.dynamics.holding import StaticForceCheck
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.plan.context import PLANNER_SLACK_M
from planner.scenario.resolve import ResolvedScenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
#: The pipeline's planning clearance for the reference scenarios (the requested 0.01 m plus its slack).
CLEARANCE_M = 0.01 + PLANNER_SLACK_M
MOTION_MARGIN_M = 0.005


@pytest.fixture(scope="module")
def world(scenario: ResolvedScenario) -> CollisionWorld:
    return CollisionWorld(scenario.robot, scenario.cabin, scenario.payload)


@pytest.fixture(scope="module")
def forces(scenario: ResolvedScenario) -> StaticForceCheck:
    assert scenario.payload is not None
    return StaticForceCheck(Cabin8Dynamics.of(scenario.robot), scenario.payload.rigid_payload())
