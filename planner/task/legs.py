"""The legs of an assembly cycle as data: each leg's payload state and cabin state, and its scenario.

One table (:data:`LEGS`) says, for every leg in order, whether the robot moves or rests, whether the unit
is held, which obstacles the cabin has (the unit waiting on its dock, or installed in its bay) and which
pair may come within the clearance:

=============  ======  ======  ====================================  ===========================
leg            kind    unit    obstacles (besides installed units)   allowed pair
=============  ======  ======  ====================================  ===========================
pre_grasp      motion  --      fixture, unit on its dock             --
grasp_line     motion  --      fixture, unit on its dock             gripper ~ unit (dock)
grasp          dwell   held    fixture                               unit ~ fixture
lift_off       motion  held    fixture                               unit ~ fixture
transit        motion  held    fixture                               --
insertion      motion  held    fixture                               --
release        dwell   --      fixture, unit in its bay              gripper ~ unit (bay)
retract        motion  --      fixture, unit in its bay              gripper ~ unit (bay)
park           motion  --      fixture, unit in its bay              --
=============  ======  ======  ====================================  ===========================

The unit is attached at the start of the grasp dwell (its weight taken: the tool sinks) and detached at the
start of the release dwell (the tool springs back; the unit stays at its installed pose, an obstacle from
then on). Planning (:mod:`planner.task.cycle`) and the independent check (:mod:`planner.task.check`) both
build every leg's world from this table, so they cannot disagree on what a leg may touch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.collision.obstacles import Obstacle
from planner.collision.world import DEFAULT_SELF_CLEARANCE_M, CollisionWorld
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.robots.geometry import PAYLOAD
from planner.scenario.resolve import ResolvedScenario
from planner.task.resolve import Line, ResolvedCycle

LegKind = Literal["motion", "dwell"]
Scene = Literal["dock", "carry", "bay"]
Allowed = Literal["gripper_dock", "unit_fixture", "gripper_bay"] | None


@dataclass(frozen=True)
class LegState:
    """What one leg is: name, motion or dwell, whether the unit is held, the cabin, the allowed pair."""

    name: str
    kind: LegKind
    held: bool
    scene: Scene
    allowed: Allowed = None


#: The legs of a cycle in order (see the module docstring).
LEGS: tuple[LegState, ...] = (
    LegState("pre_grasp", "motion", False, "dock"),
    LegState("grasp_line", "motion", False, "dock", "gripper_dock"),
    LegState("grasp", "dwell", True, "carry", "unit_fixture"),
    LegState("lift_off", "motion", True, "carry", "unit_fixture"),
    LegState("transit", "motion", True, "carry"),
    LegState("insertion", "motion", True, "carry"),
    LegState("release", "dwell", False, "bay", "gripper_bay"),
    LegState("retract", "motion", False, "bay", "gripper_bay"),
    LegState("park", "motion", False, "bay"),
)
LEG_NAMES: tuple[str, ...] = tuple(leg.name for leg in LEGS)
#: The straight legs and the line each follows.
LINE_LEGS = ("grasp_line", "lift_off", "insertion", "retract")


def leg(name: str) -> LegState:
    """The leg of that name."""
    return LEGS[LEG_NAMES.index(name)]


def obstacles(cyc: ResolvedCycle, scene: Scene) -> tuple[Obstacle, ...]:
    """The cabin's obstacles in a scene: installed units, the fixture, and the unit where it rests."""
    if scene == "dock":
        return (*cyc.installed, cyc.fixture, cyc.dock_unit)
    if scene == "carry":
        return (*cyc.installed, cyc.fixture)
    return (*cyc.installed, cyc.fixture, cyc.bay_unit)


def allowed_pair(cyc: ResolvedCycle, allowed: Allowed) -> tuple[str, str] | None:
    """The ``(world body, obstacle)`` pair a leg allows (world names), or None."""
    if allowed is None:
        return None
    if allowed == "unit_fixture":
        return (PAYLOAD, cyc.fixture.name)
    return (cyc.gripper_body, cyc.unit_name)


def allowed_label(cyc: ResolvedCycle, allowed: Allowed) -> tuple[str, str] | None:
    """The pair as reports name it: ``("gripper", "unit A3")``, ``("unit A3", "fixture of A3")``."""
    if allowed is None:
        return None
    if allowed == "unit_fixture":
        return (cyc.unit_name, cyc.fixture.name)
    return (cyc.gripper_label, cyc.unit_name)


def payload_geometry(cyc: ResolvedCycle, state: LegState) -> PayloadGeometry | None:
    """The body fixed to the tool on a leg: the held unit (with the gripper), else the gripper (or none)."""
    return cyc.held if state.held else cyc.gripper


def payload_inertia(cyc: ResolvedCycle, state: LegState) -> RigidPayload | None:
    """The tool's load on a leg (the unit's inertial data when held, else none: the gripper is the tool's)."""
    return cyc.unit_payload if state.held else None


def body_label(cyc: ResolvedCycle, state: LegState, name: str) -> str:
    """A world body's name in reports: the payload body is the unit (held) or the gripper."""
    if name != PAYLOAD:
        return name
    return cyc.unit_name if state.held else "gripper"


def leg_scenario(
    cyc: ResolvedCycle,
    state: LegState,
    start_q: Array,
    *,
    goal_q: Array | None = None,
    T_base_unit_goal: Array | None = None,
    approach: Line | None = None,
) -> ResolvedScenario:
    """One leg as an ordinary resolved scenario: start, goal, payload state and cabin state.

    The goal is a configuration (``goal_q``) or the unit frame's pose (``T_base_unit_goal``, with an
    optional approach line); the scenario's payload is the leg's tool body, its obstacles the leg's scene,
    its allowed pairs the leg's.
    """
    robot = cyc.robot
    geom = payload_geometry(cyc, state)
    pair = allowed_pair(cyc, state.allowed)
    start_q = np.asarray(start_q, dtype=float)
    goal_u = robot.drives_from_joints(goal_q) if goal_q is not None else None
    T_goal_tool = T_goal_payload = None
    if T_base_unit_goal is not None:
        T_goal_tool = T_base_unit_goal @ np.linalg.inv(cyc.T_tool_unit)
        # The scenario's pose goal is its payload frame's: the unit frame when held (grasp T_tool_unit).
        T_goal_payload = T_base_unit_goal if state.held else T_goal_tool @ _tool_payload(geom)
    return dataclasses.replace(
        cyc.base,
        payload=geom,
        start_u=robot.drives_from_joints(start_q),
        start_q=start_q,
        goal_u=goal_u,
        goal_q=None if goal_q is None else np.asarray(goal_q, dtype=float),
        T_base_payload_goal=T_goal_payload,
        T_base_tool_goal=T_goal_tool,
        approach_direction=None if approach is None else approach.direction,
        approach_distance_m=0.0 if approach is None else approach.distance_m,
        obstacles=obstacles(cyc, state.scene),
        allowed_pairs=frozenset() if pair is None else frozenset({pair}),
        scenario_sha256=cyc.sha256,
    )


def leg_world(
    cyc: ResolvedCycle, state: LegState, self_clearance: float = DEFAULT_SELF_CLEARANCE_M
) -> CollisionWorld:
    """The collision world of a leg (cabin caches shared; obstacles and allowed pair the leg's).

    ``self_clearance``: the requested one (the cycle gate's world) or the planner's
    (:data:`planner.plan.context.PLANNER_SELF_CLEARANCE_M`, for the cycle planner's own checks).
    """
    pair = allowed_pair(cyc, state.allowed)
    return CollisionWorld(
        cyc.robot,
        cyc.base.cabin,
        payload_geometry(cyc, state),
        self_clearance=self_clearance,
        obstacles=obstacles(cyc, state.scene),
        allowed=frozenset() if pair is None else frozenset({pair}),
    )


def _tool_payload(geom: PayloadGeometry | None) -> Array:
    return np.eye(4) if geom is None else geom.T_tool_payload


def line_joints(q_start: Array, offset: Array) -> Array:
    """The joint configuration reached by translating the tool by ``offset`` (3,) [m] from q_start.

    cabin8's closed-form redundant family q(gamma, d5) keeps theta3, theta4, theta6 for a fixed tool
    orientation and shifts (d1, x, y) by the translation (z, x, y) when (gamma, d5) are held
    (:func:`planner.plan.goals.approach_lines`): a straight tool line is a straight joint segment.
    """
    q = np.array(q_start, dtype=float)
    q[[0, 1, 2]] += np.array([offset[2], offset[0], offset[1]])
    return q
