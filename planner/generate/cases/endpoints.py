"""Start and drive-goal configurations: clear by the requested clearance (+ 20 mm), holdable, on the rail.

Half of the draws perturb the home posture, half are uniform admissible joints; the rail travel d1 is
drawn in the range the case asks for (near the goal, or well away from it: > 1.5 m along the rail).
"""

from __future__ import annotations

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.generate.cases.common import Draw, Redraw
from planner.kinematics import chain
from planner.plan.goals import StaticForceCheck
from planner.redundancy.ik import random_admissible_joints

#: Standard deviations of the home-posture perturbation per joint (d1 is drawn apart) [m or rad].
_HOME_NOISE = np.array([0, 0.08, 0.04, 0.08, 0.4, 0.25, 0.1, 0.6])


def configuration(
    d: Draw, world: CollisionWorld, forces: StaticForceCheck, d1_range: tuple[float, float], clearance: float
) -> Array:
    """A start-like configuration in ``d1_range``: clear by ``clearance``, holdable; near home or uniform."""
    rng, robot = d.rng, d.robot
    if d1_range[1] - d1_range[0] < 0.05:
        raise Redraw("no room on the rail")
    q_home = robot.joints_from_drives(robot.home_drives)
    for _ in range(8):
        if rng.uniform() < 0.5:
            qs = q_home + rng.normal(0.0, 1.0, size=(60, 8)) * _HOME_NOISE
            qs = qs[robot.admissible_batch(qs)]
        else:
            qs = random_admissible_joints(robot, rng, 60, 400)
        if len(qs) == 0:
            continue
        qs[:, chain.D1] = rng.uniform(*d1_range, size=len(qs))
        for q in qs:
            if robot.violations(q):
                continue
            if world.is_valid(q, clearance) and forces.ok(q):
                return np.array(q)
    raise Redraw("no clear, holdable configuration")


def start_range(goal_d1: float, rail_max: float, far: bool) -> tuple[float, float]:
    """Where the start's d1 is drawn: well away from the goal (``far``) or within 1.2 m of it."""
    span = (0.0, rail_max)
    if far:
        lo_side = (span[0] + 0.05, goal_d1 - 1.5)
        hi_side = (goal_d1 + 1.5, span[1] - 0.05)
        return lo_side if lo_side[1] - lo_side[0] > hi_side[1] - hi_side[0] else hi_side
    return (max(span[0] + 0.05, goal_d1 - 1.2), min(span[1] - 0.05, goal_d1 + 1.2))


__all__ = ["configuration", "start_range"]
