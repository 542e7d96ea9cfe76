"""Bay goals: a bay in the side wall (``bay-side``) or recessed into the far or near end wall.

The payload's goal pose is drawn first (axis-aligned, where the robot's inverse kinematics has exact,
admissible solutions at the goal and at the pre-insertion pose); the bay is then built *around* it with
the drawn free space per side (12-40 mm to each side wall, top, bottom and back panel), the payload 0-30
mm behind the opening, the approach out of the bay plus 30-80 mm. A side bay opens towards -x (the arm
cannot point to -x: theta3 is within +-105 deg); an end bay's wall is a wall across the cabin with the
bay's opening, the section ending just behind the cavity, the rail shortened so the carriage stays clear.
"""

from __future__ import annotations

import math

import numpy as np

from planner.core.types import Array
from planner.generate.cabins import PANEL_M, BayLayout, bay_boxes
from planner.generate.cases.common import Draw, Goal, Redraw
from planner.generate.options import FREE_RANGE_M
from planner.generate.reach import exact_solutions, payload_rotation, pose, tool_pose


def _bay_position(d: Draw, half: Array, free_back: float, rail_max: float) -> Array:
    """One drawn payload position (3,) for the bay (NaN where the wall leaves no room)."""
    rng, size = d.rng, d.size
    if d.kind == "bay-side":
        y = rng.uniform(0.35, 1.25)
        z = rng.uniform(0.8, rail_max - 0.3)
        x_wall = d.section.wall_x(y - half[1], y + half[1])
        x_hi = x_wall - (size[2] / 2 + free_back + PANEL_M)
        x = rng.uniform(0.55, x_hi) if x_hi > 0.55 else math.nan
        return np.array([x, y, z])
    p = np.array([rng.uniform(-0.45, 0.55), rng.uniform(0.35, 1.15), math.nan])
    # along the rail: as far towards the end as the arm reaches from the rail's end
    reach = rng.uniform(0.55, 1.05)
    p[2] = rail_max + reach if d.kind == "bay-end-far" else -reach
    return p


def goal_bay(d: Draw, rail_max: float) -> tuple[Array, Array, BayLayout, float, list[Array]]:
    """A reachable bay goal: (T_base_payload, approach direction, layout, distance, goal solutions)."""
    rng, robot, size = d.rng, d.robot, d.size
    roll = int(rng.integers(2))
    R = payload_rotation(d.kind, roll)
    f = [float(np.round(rng.uniform(*FREE_RANGE_M), 4)) for _ in range(5)]
    free = (f[0], f[1], f[2], f[3], f[4])
    recess = float(np.round(rng.uniform(0.0, 0.03), 4))
    bay = BayLayout(d.kind, free, recess)
    e = R[:, 2]
    distance = float(np.round(recess + size[2] + rng.uniform(0.03, 0.08), 3))
    half = np.abs(R) @ (np.array(size) / 2 + 0.06)  # half-extent of the bay in the base frame
    for _ in range(40):
        p = _bay_position(d, half, free[4], rail_max)
        if not np.all(np.isfinite(p)):
            continue
        T_goal = pose(R, p)
        sols = exact_solutions(robot, tool_pose(T_goal, d.payload), robot.home_drives, d.goal_solutions)
        if not sols:
            continue
        pre = exact_solutions(robot, tool_pose(pose(R, p - distance * e), d.payload), robot.home_drives, 1)
        if not pre:
            continue
        d.meta.update(roll=roll, free_per_side_m=list(free), recess_m=recess)
        return T_goal, e, bay, distance, sols
    raise Redraw("no reachable bay pose")


def _end_wall(d: Draw, goal: Goal, cavity: tuple[Array, Array], z_open: float, rail_max: float) -> None:
    """The end wall with the bay's opening; the section ends just behind the cavity."""
    assert goal.pose is not None
    lo_all = np.min([b[0] for b in goal.bay_boxes], axis=0)
    hi_all = np.max([b[1] for b in goal.bay_boxes], axis=0)
    R, p = goal.pose[:3, :3], goal.pose[:3, 3]
    wall_z = float(p[2] + (R @ np.array([0.0, 0.0, z_open]))[2])
    lo_c, hi_c = cavity
    opening = (lo_c[0], hi_c[0], lo_c[1], hi_c[1])
    z_min, z_max = d.section.shell.z_min_m, d.section.shell.z_max_m
    if d.kind == "bay-end-far":
        z_max = float(np.round(hi_all[2] + 0.06, 3))
        goal.end_opening = ("far", wall_z, opening)
        if wall_z - 0.2 - 0.06 < rail_max:
            raise Redraw("the end wall cuts the rail")
    else:
        z_min = float(np.round(lo_all[2] - 0.06, 3))
        goal.end_opening = ("near", wall_z - d.section.shell.wall_m, opening)
        if wall_z - d.section.shell.wall_m > -0.2 - 0.06:
            raise Redraw("the end wall cuts the rail")
    d.section = d.section.over(z_min, z_max)


def place_bay(d: Draw, rail_max: float) -> Goal:
    """A bay goal with its panels, the keep-out around the bay and its approach, an end wall if any."""
    T_goal, direction, bay, distance, sols = goal_bay(d, rail_max)
    goal = Goal(pose=T_goal, direction=direction, distance=distance, solutions=sols)
    goal.bay_boxes, cavity, (_, _, _, _, z_open) = bay_boxes(T_goal, d.size, bay)
    lo_all = np.min([b[0] for b in goal.bay_boxes], axis=0)
    hi_all = np.max([b[1] for b in goal.bay_boxes], axis=0)
    p_pre = T_goal[:3, 3] - distance * direction
    corridor_lo = np.minimum(lo_all, p_pre - np.max(d.size) - 0.1)
    corridor_hi = np.maximum(hi_all, p_pre + np.max(d.size) + 0.1)
    goal.keep_out.append((corridor_lo, corridor_hi))
    if d.kind != "bay-side":
        _end_wall(d, goal, cavity, z_open, rail_max)
    return goal


__all__ = ["goal_bay", "place_bay"]
