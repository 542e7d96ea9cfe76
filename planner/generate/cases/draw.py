"""One draw of a case, in the order its generator is consumed.

The steps: goal kind, payload, section, goal, clutter, start (and a drive goal), hatch, file.

The order of the random draws is part of the contract: the same seed gives the same bytes, so a step
never draws more, less or earlier than before; a family changes the ranges a step draws from, and only
the families' own steps (a polygonal section, stringers) draw anything the mixed family does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.generate.cabins import CabinLayout
from planner.generate.cases.bay import place_bay
from planner.generate.cases.clutter import draw_brackets, draw_ducts, draw_rings, draw_stringers
from planner.generate.cases.common import Draw, Goal, Redraw, draw_payload, draw_section
from planner.generate.cases.endpoints import configuration, start_range
from planner.generate.cases.hatch import HatchWorld, hatch
from planner.generate.cases.shelf import place_shelf
from planner.generate.families import Family
from planner.generate.files import loaded_cabin, mesh_bytes, pose_doc
from planner.generate.options import (
    GOAL_KINDS,
    GRID_STEP_M,
    ROBOT_RAIL_M,
    START_EXTRA_M,
    GeneratedCase,
    GeneratorOptions,
    MeshFormat,
)
from planner.generate.reach import exact_solutions, robot_of, rot_z, tool_pose
from planner.kinematics import chain
from planner.meshes.generate import Bulkhead
from planner.plan.goals import StaticForceCheck


@dataclass
class _Ends:
    """The checked ends of a case and the world they were checked in."""

    layout: CabinLayout
    world: CollisionWorld
    q_start: Array
    q_goal: Array
    goal_d1: float


class _Checks:
    """The generator's own models for one draw: a collision world per layout and the static hold check."""

    def __init__(self, d: Draw) -> None:
        self.d = d
        self.forces = StaticForceCheck(Cabin8Dynamics.of(d.robot), d.payload.rigid_payload())

    def world(self, layout: CabinLayout) -> CollisionWorld:
        """The generator's collision world of ``layout``."""
        # A coarse bound grid: the verdicts are exact either way (FCL decides what the bounds do not).
        return CollisionWorld(self.d.robot, loaded_cabin(layout), self.d.payload, grid_step_m=GRID_STEP_M)

    def hatch_world(self, layout: CabinLayout) -> HatchWorld:
        """The world and hold check of ``layout`` with a candidate bulkhead (the hatch's sizing loop)."""
        return lambda spec: (self.world(layout.with_bulkhead(spec)), self.forces)


def goal_kind(rng: np.random.Generator, opts: GeneratorOptions, family: Family) -> str:
    """A goal kind drawn with the family's weights (renormalised over ``opts.goal_kinds`` if given)."""
    kinds = family.goal_kinds if opts.goal_kinds is None else opts.goal_kinds
    weights = np.array([family.goal_weights[family.goal_kinds.index(k)] for k in kinds])
    return kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]


def _place_goal(d: Draw, rail_max: float) -> Goal:
    if d.kind.startswith("bay"):
        return place_bay(d, rail_max)
    if d.kind == "shelf":
        return place_shelf(d, rail_max)
    return Goal()


def _layout(d: Draw, family: Family, goal: Goal) -> CabinLayout:
    rings = draw_rings(d, family, goal.keep_out)
    ducts = draw_ducts(d, family, goal.keep_out)
    brackets = draw_brackets(d, family, goal.keep_out)
    stringers = draw_stringers(d, family, goal.keep_out)
    return CabinLayout(
        section=d.section,
        rings=tuple(rings),
        bay_boxes=tuple((tuple(map(float, lo)), tuple(map(float, hi))) for lo, hi in goal.bay_boxes),
        end_opening=goal.end_opening,
        ducts=tuple(ducts),
        brackets=tuple(brackets),
        plates=tuple(goal.plates),
        stringers=tuple(stringers),
    )


def _goal_d1(d: Draw, goal: Goal, rail_max: float) -> float:
    """Where the goal is along the rail: the median d1 of its exact solutions (drawn for a drive goal)."""
    if goal.pose is None:
        return float(d.rng.uniform(0.3, rail_max - 0.3))
    T_tool = tool_pose(goal.pose, d.payload)
    goal.solutions = goal.solutions or exact_solutions(d.robot, T_tool, d.robot.home_drives, d.goal_solutions)
    return float(np.median([q[chain.D1] for q in goal.solutions])) if goal.solutions else 3.0


def _ends(
    d: Draw,
    family: Family,
    checks: _Checks,
    layout: CabinLayout,
    goal: Goal,
    rail_max: float,
    clearance: float,
) -> tuple[_Ends, bool]:
    """The checked goal and start configurations; whether a hatch is wanted between them."""
    goal_d1 = _goal_d1(d, goal, rail_max)
    far = d.rng.uniform() < family.far_probability
    pick = start_range(goal_d1, rail_max, far)
    hatch_wanted = far and d.rng.uniform() < family.hatch_probability and pick[1] - pick[0] > 0.3
    world = checks.world(layout)
    if d.kind == "drive":
        q_goal = configuration(d, world, checks.forces, (0.05, rail_max - 0.05), clearance + START_EXTRA_M)
        goal_d1 = float(q_goal[chain.D1])
        pick = start_range(goal_d1, rail_max, True)
    else:
        valid = [q for q in goal.solutions if world.is_valid(q, clearance) and checks.forces.ok(q)]
        if not valid:
            raise Redraw("no goal solution keeps the clearance and holds the payload")
        q_goal = valid[0]
    q_start = configuration(d, world, checks.forces, pick, clearance + START_EXTRA_M)
    return _Ends(layout, world, q_start, q_goal, goal_d1), hatch_wanted


def _add_hatch(d: Draw, checks: _Checks, ends: _Ends, clearance: float) -> None:
    """A bulkhead hatch between start and goal when they are more than 1.6 m apart along the rail."""
    d1_a, d1_b = sorted((float(ends.q_start[chain.D1]), ends.goal_d1))
    if d1_b - d1_a <= 1.6:
        return
    z_bh = float(d.rng.uniform(d1_a + 0.7, d1_b - 0.7))
    spec: Bulkhead | None = hatch(d, checks.hatch_world(ends.layout), z_bh, clearance)
    if spec is None:
        return
    ends.layout = ends.layout.with_bulkhead(spec)
    ends.world = checks.world(ends.layout)
    if not (
        ends.world.is_valid(ends.q_start, clearance + START_EXTRA_M)
        and ends.world.is_valid(ends.q_goal, clearance)
    ):
        raise Redraw("the hatch blocks the start or the goal")
    d.meta["bulkhead_z_m"] = spec.z_m


def _record(d: Draw, family: Family, ends: _Ends, rail_max: float) -> None:
    """The case's features after its checks (the witness goal configuration and its distance)."""
    layout = ends.layout
    d.meta.update(
        witness_goal_q=[float(v) for v in ends.q_goal],
        witness_goal_distance_m=float(np.round(ends.world.min_distance(ends.q_goal).distance_m, 5)),
        **layout.section.describe(),
        ring_frames=len(layout.rings),
        ducts=len(layout.ducts),
        brackets=len(layout.brackets),
    )
    if family.stringers is not None:
        d.meta["stringers"] = len({s.angle_rad for s in layout.stringers})  # pieces of one count once
    d.meta.update(
        rail_length_m=rail_max,
        start_to_goal_rail_m=float(np.round(abs(ends.goal_d1 - ends.q_start[chain.D1]), 3)),
    )
    if "free_per_side_m" in d.meta:
        d.meta["min_free_m"] = float(min(d.meta["free_per_side_m"]))


def _file_frame(d: Draw, index: int, opts: GeneratorOptions) -> tuple[MeshFormat, Literal["m", "mm"], Array]:
    """The mesh file's format (cycled by index), units and frame ``T_base_cabin`` (4, 4)."""
    rng = d.rng
    fmt = opts.formats[index % len(opts.formats)]
    units: Literal["m", "mm"] = "mm" if rng.uniform() < 0.4 else "m"
    shift = float(np.round(rng.uniform(-1.5, 1.5), 3)) if rng.uniform() < 0.6 else 0.0
    angle = float(
        rng.choice([0.0, math.pi / 2, math.pi, -math.pi / 2, float(np.round(rng.uniform(-3, 3), 3))])
    )
    T_base_cabin = np.eye(4)
    T_base_cabin[:3, :3] = rot_z(angle)
    T_base_cabin[:3, 3] = (0.0, d.section.shell.axis_y_m, shift)
    d.meta.update(format=fmt, units=units, cabin_shift_m=shift, cabin_rotation_rad=angle)
    return fmt, units, T_base_cabin


def _scenario(
    d: Draw, name: str, mesh_name: str, T_base_cabin: Array, ends: _Ends, goal: Goal, opts: GeneratorOptions
) -> dict[str, Any]:
    """The scenario document (drives of the start and of a drive goal; a pose goal with its approach)."""
    robot, rail_max = d.robot, float(d.meta["rail_length_m"])
    scenario: dict[str, Any] = {
        "name": name,
        "robot": "cabin8",
        "cabin": {"mesh": mesh_name, "units": d.meta["units"], "pose": pose_doc(T_base_cabin)},
        "payload": {
            "box": list(d.size),
            "mass": d.meta["mass_kg"],
            "grasp": pose_doc(d.payload.T_tool_payload),
        },
        "start": {"drives": robot.drives_dict(robot.drives_from_joints(ends.q_start))},
        "options": {"clearance_m": opts.clearance_m, "time_limit_s": opts.time_limit_s, "seed": 0},
    }
    if rail_max < ROBOT_RAIL_M:
        scenario["rail_length"] = rail_max
    if d.kind == "drive":
        scenario["goal"] = {"drives": robot.drives_dict(robot.drives_from_joints(ends.q_goal))}
    else:
        assert goal.pose is not None
        goal_doc: dict[str, Any] = {"pose": pose_doc(goal.pose)}
        if goal.direction is not None:
            goal_doc["approach"] = {
                "direction": [float(v) for v in goal.direction],
                "distance": goal.distance,
            }
        scenario["goal"] = goal_doc
    scenario["start"]["drives"] = {k: float(v) for k, v in scenario["start"]["drives"].items()}
    if "drives" in scenario["goal"]:
        scenario["goal"]["drives"] = {k: float(v) for k, v in scenario["goal"]["drives"].items()}
    return scenario


def case_name(seed: int, index: int, family: Family) -> str:
    """``gen-<seed>-<index>`` (mixed family) or ``gen-<family>-<seed>-<index>``."""
    return f"gen-{seed}-{index:03d}" if family.tag is None else f"gen-{family.name}-{seed}-{index:03d}"


def draw_case(
    seed: int,
    index: int,
    rng: np.random.Generator,
    opts: GeneratorOptions,
    family: Family,
    kind: str | None = None,
) -> GeneratedCase:
    """One attempt at case ``index``; raises :class:`Redraw` when the draw does not make a valid case.

    ``kind``: the case's goal kind, drawn once for all its attempts (the families); ``None``: drawn at
    each attempt from ``rng`` (the mixed family: its kinds are then weighted by how often each succeeds).
    """
    kind = goal_kind(rng, opts, family) if kind is None else kind
    assert kind in GOAL_KINDS
    size, payload, meta = draw_payload(rng, family.mass_range_kg)
    meta = ({} if family.tag is None else {"family": family.name}) | meta
    meta["goal"] = kind
    rail_max = opts.rail_length_m
    if kind == "bay-end-far":
        rail_max = float(np.round(rng.uniform(opts.rail_length_m - 2.0, opts.rail_length_m), 3))
    robot = robot_of(rail_max)
    section = draw_section(rng, family, -0.5, opts.rail_length_m + 0.5)
    d = Draw(rng, robot, payload, size, kind, section, meta, family.goal_solutions)
    goal = _place_goal(d, rail_max)
    checks = _Checks(d)
    ends, hatch_wanted = _ends(d, family, checks, _layout(d, family, goal), goal, rail_max, opts.clearance_m)
    if hatch_wanted:
        _add_hatch(d, checks, ends, opts.clearance_m)
    _record(d, family, ends, rail_max)
    fmt, units, T_base_cabin = _file_frame(d, index, opts)
    name = case_name(seed, index, family)
    mesh_name = f"{name}-cabin.{fmt}"
    data = mesh_bytes(ends.layout, fmt, units, T_base_cabin, name)
    scenario = _scenario(d, name, mesh_name, T_base_cabin, ends, goal, opts)
    return GeneratedCase(
        name, scenario, mesh_name, data, d.meta, ends.q_start, ends.q_goal, ends.layout, T_base_cabin
    )


__all__ = ["case_name", "draw_case", "goal_kind"]
