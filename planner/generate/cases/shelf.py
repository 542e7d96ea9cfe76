"""Shelf goals: a pose goal without approach, the payload set down just above a shelf plate.

The payload's orientation is one of the bay orientations (insertion axis +x, +z or -z, rolled or not), its
position drawn until the inverse kinematics has an exact, admissible solution; the plate is 20 mm thick,
12-40 mm below the payload, 30-120 mm wider than it along x and z.
"""

from __future__ import annotations

import numpy as np

from planner.generate.cabins import aabb
from planner.generate.cases.common import Draw, Goal, Redraw
from planner.generate.options import FREE_RANGE_M
from planner.generate.reach import exact_solutions, payload_rotation, pose, tool_pose


def place_shelf(d: Draw, rail_max: float) -> Goal:
    """A reachable pose goal just above a shelf plate, and the keep-out around the plate and above it."""
    rng, robot, size = d.rng, d.robot, d.size
    for _ in range(40):
        kind = ("bay-side", "bay-end-far", "bay-end-near")[int(rng.integers(3))]
        R = payload_rotation(kind, int(rng.integers(2)))
        p = np.array([rng.uniform(-0.3, 0.9), rng.uniform(0.45, 1.2), rng.uniform(0.8, rail_max - 0.2)])
        T_goal = pose(R, p)
        sols = exact_solutions(robot, tool_pose(T_goal, d.payload), robot.home_drives, d.goal_solutions)
        if not sols:
            continue
        lo, hi = aabb(R, p, -np.array(size) / 2, np.array(size) / 2)
        gap = float(np.round(rng.uniform(*FREE_RANGE_M), 4))
        margin = rng.uniform(0.03, 0.12, size=2)
        plate = (
            (lo[0] - margin[0], lo[1] - gap - 0.02, lo[2] - margin[1]),
            (hi[0] + margin[0], lo[1] - gap, hi[2] + margin[1]),
        )
        d.meta.update(shelf_gap_m=gap, free_per_side_m=[gap])
        keep = (np.array(plate[0]) - 0.45, np.array(plate[1]) + np.array([0.45, 0.8, 0.45]))
        return Goal(pose=T_goal, solutions=sols, plates=[plate], keep_out=[keep])
    raise Redraw("no reachable shelf pose")


__all__ = ["place_shelf"]
