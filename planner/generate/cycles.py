"""Seeded generator of assembly campaigns (and single cycles) nobody tuned the planner for.

A generated campaign is a cabin of the scenario generator's kind (:mod:`planner.generate`, its ``mixed``
family: a cylindrical shell with the floor deck and end walls, optional ring frames) with 3-8 units to
install:

* **Bays**: rack bays in the +x side wall (insertion along +x; the arm cannot point to -x) at distinct
  stations along the cabin (one per station), and with some probability one bay recessed into
  the far end wall (insertion along the rail, +z). Each bay is built around its unit's installed pose
  with the drawn free space per side (the clearance + 5 mm to 40 mm: the witnesses' extra, see
  :func:`_free_range`), as the scenario generator builds its bays.
* **Blocking pairs**: a *front* unit mounted in the aisle in front of a side bay, in the corridor its
  *deep* unit must pass through: installed first, the front unit blocks the deep unit's insertion (its
  pre-insertion pose overlaps the front unit), while the deep unit installed first leaves the front
  unit's mount free (a 30-50 mm gap to the bay's face plate). So some orders fail and others succeed,
  for a reason the generator knows (``meta["precedence"]``: deep before front).
* **Dock**: every unit waits on its transport fixture at the cabin entrance (a pedestal beside the rail's
  lane, 0.8-1.4 m along it), a gap of clearance + 8 mm above the pedestal, held along +x as a side unit is
  installed (an end-wall unit too: the robot turns it on the way; held along the rail it can be reached
  only from the lane, where its fixture would stop the robot from ever passing the dock); the tool
  approaches along the held unit's axis and lifts off upwards. No fixture comes within the clearance of
  the robot's park posture anywhere along the rail (the lane stays open: a dock never blocks the way in).
* **Park**: the robot's home posture at the rail's start (clear by the clearance + 20 mm).

Every key configuration of every unit alone in the cabin has an exact, admissible inverse-kinematics
solution that keeps the requested clearance from the cabin (and the pedestal) and holds the unit within
the drive force limits (the dock grasp, the pre-grasp, the lift-off end, the installed pose and the
pre-insertion pose): the *witnesses* that make each cycle solvable in the empty cabin. Whether an order
is feasible is for the planner to find (the benchmark's ground truth is an exhaustive order search).

Each campaign is drawn from ``numpy.random.default_rng([seed, index, STREAM])``: campaign ``i`` of a seed
is the same whatever the count, and the same seed gives the same bytes. Pure (numpy in, bytes and dicts
out) except :func:`write_campaign` at the edge.

Frame (as in ``planner/meshes/README.md``): z along the cabin axis and the rail, y up, x lateral; SI units.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.collision.obstacles import Obstacle
from planner.collision.world import CollisionWorld
from planner.core.types import Array
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.generate.cabins import PANEL_M, BayLayout, CabinLayout, RingFrame, bay_boxes, cabin_parts, merge
from planner.generate.cases.common import Redraw, draw_payload, draw_section, first_valid, ring_depth_max
from planner.generate.families import FAMILIES
from planner.generate.files import commented_yaml, loaded_cabin, pose_doc, write_generated
from planner.generate.options import FREE_RANGE_M, GRID_STEP_M, ROBOT_RAIL_M
from planner.generate.reach import exact_solutions, payload_rotation, pose, robot_of
from planner.generate.sections import Section
from planner.kinematics import chain
from planner.meshes.generate import binary_stl_bytes
from planner.plan.goals import StaticForceCheck
from planner.robots.cabin8 import Cabin8

__all__ = [
    "STREAM",
    "CycleGeneratorOptions",
    "GeneratedCampaign",
    "campaign_yaml",
    "cycle_document_of",
    "generate_campaign",
    "generate_campaigns",
    "write_campaign",
]

#: The scenario generator's family whose cabins (round shells) and payloads the campaigns share.
MIXED = FAMILIES["mixed"]
#: Unit masses [kg]: the mixed family's payload range.
MASS_RANGE_KG = MIXED.mass_range_kg
#: The campaigns' random stream, apart from the scenario generator's (``[seed, index]``).
STREAM = 0xC1C1E
#: The fixture a docked unit waits on: footprint (x, z) [m] (its top follows the unit's height) and its
#: bottom [m]: 50 mm above the carriage's top (y = 0), whose 1.7 m width sweeps the deck beside the rail.
PEDESTAL_FOOTPRINT_M = (0.26, 0.26)
FIXTURE_BOTTOM_M = 0.05
#: Gap between a docked unit and its fixture beyond the clearance [m] (more than the witnesses' extra).
DOCK_EXTRA_M = 0.008
#: Where a dock's unit centre is across the cabin [m]: the arm reaches a unit held along +x from x = 0.5 m
#: on, one held along +z only up to x = 0.3-0.45 m (measured with the generator's IK on its units), inside
#: the lane the robot's park posture sweeps above the fixtures' bottom (up to x = 0.564 m, its sphere
#: cover): so every unit is docked held along +x, its fixture (half footprint 0.13 m) beyond the lane by
#: more than the clearance (0.564 + 0.13 + 0.02 < 0.72).
DOCK_X_M = (0.72, 0.95)
#: The docked unit centre's height [m].
DOCK_Y_M = (0.6, 1.1)
#: Spacing of the rail positions at which the park posture is checked against each fixture [m].
LANE_STEP_M = 0.05
#: Largest force ratio (of the drive limits) of a generated dock's grasp: below the planner's 95% by a
#: margin for the robot's own deflection and the grasp line's other end.
DOCK_FORCE_FRACTION = 0.85
#: Extra clearance the generator's witnesses keep beyond the requested one [m] (the planner adds its own
#: 1.5 mm slack to the requested clearance where it plans).
WITNESS_EXTRA_M = 0.005
#: Rail travel of the park posture, tried in order [m].
PARK_D1_M = (0.05, 0.15, 0.3, 0.5)
#: The lift-off line: straight up [m].
LIFT_M = 0.05
#: Stations along the cabin for side bays: spacing [m] and the first one's place along the rail [m] (the
#: docks are at 0.8-1.4 m).
STATION_SPACING_M = 0.75
FIRST_STATION_M = 1.9
#: Heights of the side bays' unit centres [m].
ROWS_Y_M = ((0.55, 1.2),)
#: Exact IK solutions drawn before the force filter (a 60 kg unit held along +x at 0.6-0.8 m height: 1 of
#: 8-10 solutions is holdable, none of the first 3; measured with the generator's IK and force check).
HELD_SOLUTIONS = 10


@dataclass(frozen=True)
class CycleGeneratorOptions:
    """What every generated campaign shares.

    Attributes:
        units: The range of units per campaign (inclusive).
        clearance_m: Every cycle's requested clearance [m].
        time_limit_s: Every cycle's planning time limit [s].
        rail_length_m: Rail length [m] (the cabin section is 0.5 m longer at each end).
        pair_probability: Chance that a side station holds a blocking pair (deep and front unit).
        end_bay_probability: Chance of one bay in the far end wall.
        max_attempts: Redraws of a unit (and of the campaign's dock) before giving up.
    """

    units: tuple[int, int] = (3, 8)
    clearance_m: float = 0.01
    time_limit_s: float = 30.0
    rail_length_m: float = 6.0
    pair_probability: float = 0.35
    end_bay_probability: float = 0.4
    max_attempts: int = 40

    def __post_init__(self) -> None:
        lo, hi = self.units
        if not 1 <= lo <= hi <= 8:
            raise ValueError(f"units must be a range within [1, 8], got {self.units}")
        if not 3.0 <= self.rail_length_m <= ROBOT_RAIL_M:
            raise ValueError(f"rail_length_m must be within [3, 6] m, got {self.rail_length_m}")


@dataclass(frozen=True)
class GeneratedCampaign:
    """One generated campaign: the campaign document, the cabin mesh and what it was made of.

    Attributes:
        name: Campaign name (``camp-<seed>-<index>``).
        campaign: The campaign document (mesh path relative to it).
        mesh_name: File name of the cabin mesh.
        mesh_bytes: The mesh file's content (binary STL, metres, base frame).
        meta: Features (units with their kind, the generator's precedence pairs), JSON-able.
    """

    name: str
    campaign: dict[str, Any]
    mesh_name: str
    mesh_bytes: bytes = field(repr=False)
    meta: dict[str, Any]


@dataclass
class _Unit:
    uid: str
    kind: str  # "side" | "front" | "end"
    size: tuple[float, float, float]
    mass: float
    grasp: Array
    R: Array
    p_bay: Array
    approach_m: float
    free_m: tuple[float, ...] = ()
    recess_m: float = 0.0
    deep_of: str | None = None
    dock_xz: tuple[float, float] = (0.0, 0.0)
    dock_y: float = 1.0
    grasp_line_m: float = 0.06
    #: The unit's orientation on its dock: held along +x (a side bay's orientation, same roll).
    R_dock: Array = field(default_factory=lambda: np.eye(3))

    def payload(self) -> PayloadGeometry:
        T = np.eye(4)
        T[:3, 3] = self.grasp
        return PayloadGeometry(size=self.size, source="box", T_tool_payload=T, mass=self.mass)


def _tool(T_base_unit: Array, grasp: Array) -> Array:
    T = T_base_unit.copy()
    T[:3, 3] = T_base_unit[:3, 3] - T_base_unit[:3, :3] @ grasp
    return T


def _reachable(
    robot: Cabin8,
    u: _Unit,
    p: Array,
    count: int = HELD_SOLUTIONS,
    held: bool = True,
    R: Array | None = None,
) -> list[Array]:
    """Exact, admissible IK solutions holding unit ``u`` at ``p`` (holdable within the force limits).

    ``R``: the unit's orientation (default: as installed). ``count`` solutions are drawn before the force
    filter: the holdable ones of a heavy unit held sideways are rarely among the three of the largest
    margin.
    """
    rotation = u.R if R is None else R
    sols = exact_solutions(robot, _tool(pose(rotation, p), u.grasp), robot.home_drives, count)
    if not held:
        return sols
    forces = StaticForceCheck(Cabin8Dynamics.of(robot), u.payload().rigid_payload())
    return [q for q in sols if forces.ok(q)]


def _draw_unit(rng: np.random.Generator, uid: str, kind: str) -> _Unit:
    """A unit drawn as the scenario generator draws its payloads (box, mass, grasp), and its orientation."""
    size, payload, _ = draw_payload(rng, MASS_RANGE_KG)
    mass, grasp = float(payload.mass), payload.T_tool_payload[:3, 3].copy()
    roll = int(rng.integers(2))
    R = payload_rotation("bay-end-far" if kind == "end" else "bay-side", roll)
    R_dock = payload_rotation("bay-side", roll)
    return _Unit(uid, kind, size, mass, grasp, R, np.zeros(3), 0.0, R_dock=R_dock)


def _size3(v: Array) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _panels_clear(
    robot: Cabin8, u: _Unit, p: Array, f: tuple[float, ...], recess: float, kind: str, clearance: float
) -> bool:
    """Whether a holdable IK solution at the installed and at the pre-insertion pose clears the bay's panels.

    The panels are boxes, obstacles of a world without a cabin: no grid to build per candidate.
    """
    bay = BayLayout(kind, (f[0], f[1], f[2], f[3], f[4]), recess)
    panels, _, _ = bay_boxes(pose(u.R, p), u.size, bay)
    obstacles = tuple(
        Obstacle.box(f"panel {k}", _size3(hi - lo), pose(np.eye(3), (lo + hi) / 2))
        for k, (lo, hi) in enumerate(panels)
    )
    world = CollisionWorld(robot, None, u.payload(), obstacles=obstacles)
    e = u.R[:, 2]
    return all(
        any(world.is_valid(q, clearance) for q in _reachable(robot, u, x)) for x in (p, p - u.approach_m * e)
    )


def _free_range(clearance: float) -> tuple[float, float]:
    """The free space per side of a generated bay around its unit [m]: from the clearance + 5 mm on.

    The scenario generator's range, cut below at the clearance + :data:`WITNESS_EXTRA_M`.
    The planner keeps 2 mm beyond the requested clearance at a goal (its 1.5 mm slack and the 0.5 mm
    motion margin) and a deflection-compensated goal's pose is exact to micrometres only: a bay with
    12 mm free space for a 10 mm clearance sits on that edge (a generated cycle was refused at 11.9996 mm
    of 12 mm required). The witnesses keep the same extra at the bay as at the dock.
    """
    return (max(FREE_RANGE_M[0], clearance + WITNESS_EXTRA_M), FREE_RANGE_M[1])


def _side_bay(
    rng: np.random.Generator, robot: Cabin8, section: Section, u: _Unit, z: float, row: int, clearance: float
) -> None:
    """Place a side-wall bay at station ``z`` in ``row``: a reachable installed and pre-insertion pose."""
    f = tuple(float(np.round(rng.uniform(*_free_range(clearance)), 4)) for _ in range(5))
    recess = float(np.round(rng.uniform(0.0, 0.03), 4))
    u.approach_m = float(np.round(recess + u.size[2] + rng.uniform(0.03, 0.08), 3))
    half = np.abs(u.R) @ (np.array(u.size) / 2 + 0.06)
    for _ in range(24):
        y = rng.uniform(*ROWS_Y_M[row])
        x_wall = section.wall_x(y - half[1], y + half[1])
        x_hi = x_wall - (u.size[2] / 2 + f[4] + PANEL_M)
        if x_hi <= 0.55:
            continue
        p = np.array([rng.uniform(0.55, x_hi), y, z])
        if _panels_clear(robot, u, p, f, recess, "bay-side", clearance):
            u.p_bay, u.free_m, u.recess_m = p, f, recess
            return
    raise Redraw("no reachable side bay at this station")


def _front_of(rng: np.random.Generator, robot: Cabin8, deep: _Unit, u: _Unit) -> None:
    """Mount ``u`` in the aisle in front of ``deep``'s bay, overlapping its pre-insertion pose."""
    e = deep.R[:, 2]
    u.R = deep.R.copy()
    gap = rng.uniform(0.03, 0.05)
    face = deep.p_bay[0] - deep.size[2] / 2 - deep.recess_m - PANEL_M  # the face plate's front, x
    x = face - gap - u.size[2] / 2
    pre_far = deep.p_bay[0] - deep.approach_m - deep.size[2] / 2  # the deep unit's pre-insertion back face
    if not x + u.size[2] / 2 > pre_far + 0.02:  # it must overlap the deep unit's pre-insertion pose
        raise Redraw("front unit does not reach the deep unit's corridor")
    p = np.array([x, deep.p_bay[1], deep.p_bay[2]])
    u.approach_m = float(np.round(rng.uniform(0.05, 0.10), 3))
    if not (_reachable(robot, u, p) and _reachable(robot, u, p - u.approach_m * e)):
        raise Redraw("front unit not reachable")
    u.p_bay, u.deep_of = p, deep.uid


def _end_bay(rng: np.random.Generator, robot: Cabin8, u: _Unit, rail_max: float, clearance: float) -> None:
    """A bay recessed into the far end wall, insertion along +z, as far as the arm reaches."""
    f = tuple(float(np.round(rng.uniform(*_free_range(clearance)), 4)) for _ in range(5))
    recess = float(np.round(rng.uniform(0.0, 0.03), 4))
    u.approach_m = float(np.round(recess + u.size[2] + rng.uniform(0.03, 0.08), 3))
    for _ in range(24):
        p = np.array([rng.uniform(-0.45, 0.55), rng.uniform(0.35, 1.15), rail_max + rng.uniform(0.55, 1.05)])
        if _panels_clear(robot, u, p, f, recess, "bay-end-far", clearance):
            u.p_bay, u.free_m, u.recess_m = p, f, recess
            return
    raise Redraw("no reachable end bay")


def _dock_pose(u: _Unit) -> Array:
    """The unit's centre on its dock (3,) [m]."""
    return np.array([u.dock_xz[0], u.dock_y, u.dock_xz[1]])


def _pedestal_top(u: _Unit, clearance: float) -> float:
    """The fixture's top [m]: clearance + 8 mm below the docked unit's lowest face."""
    half_y = float((np.abs(u.R_dock) @ (np.array(u.size) / 2))[1])
    return float(np.round(u.dock_y - half_y - clearance - DOCK_EXTRA_M, 6))


def _dock(rng: np.random.Generator, robot: Cabin8, u: _Unit, clearance: float) -> None:
    """A reachable dock at the entrance: grasp, pre-grasp and lift-off end with exact IK, holdable."""
    u.grasp_line_m = float(np.round(rng.uniform(0.05, 0.08), 3))
    e, up = u.R_dock[:, 2], np.array([0.0, 1.0, 0.0])
    for _ in range(16):
        u.dock_xz = (float(np.round(rng.uniform(*DOCK_X_M), 3)), float(np.round(rng.uniform(0.8, 1.4), 3)))
        u.dock_y = float(np.round(rng.uniform(*DOCK_Y_M), 3))
        p = _dock_pose(u)
        if (
            _robustly_held(robot, u, p)
            and _robustly_held(robot, u, p + LIFT_M * up)
            and _reachable(robot, u, p - u.grasp_line_m * e, held=False, R=u.R_dock)
        ):
            return
    raise Redraw("no reachable dock")


def _robustly_held(robot: Cabin8, u: _Unit, p: Array) -> bool:
    """Whether half or more of the exact IK solutions at ``p`` (two at least) hold the unit with margin.

    Held within :data:`DOCK_FORCE_FRACTION` of the drive limits. A cycle's planner chooses its grasp line
    among the dock's solutions by its own criteria (clearance, the lines' redundancy), not by force: a
    dock held by one solution in ten is one it refuses (``unit_not_holdable``, measured on the first
    generated campaigns), so a generated dock is one most solutions hold.
    """
    sols = _reachable(robot, u, p, held=False, R=u.R_dock)
    forces = StaticForceCheck(Cabin8Dynamics.of(robot), u.payload().rigid_payload())
    held = [q for q in sols if float(forces.ratios(q)[0]) <= DOCK_FORCE_FRACTION]
    return len(held) >= max(2, (len(sols) + 1) // 2)


def _pedestal(u: _Unit, deck_top: float, clearance: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The fixture's box (lo, hi) [m]: a shelf from above the carriage's lane up to below the docked unit.

    (``deck_top`` is kept for the signature of a floor-standing fixture; the carriage, 1.7 m wide, sweeps
    the deck beside the rail, so the fixture hangs above it, as the reference example's does.)
    """
    (x_d, z_d), (fx, fz) = u.dock_xz, PEDESTAL_FOOTPRINT_M
    top = _pedestal_top(u, clearance)
    bottom = min(FIXTURE_BOTTOM_M, top - 0.05)
    return (x_d - fx / 2, bottom, z_d - fz / 2), (x_d + fx / 2, top, z_d + fz / 2)


def _place_units(
    rng: np.random.Generator, robot: Cabin8, section: Section, n: int, opts: CycleGeneratorOptions
) -> list[_Unit]:
    """Draw ``n`` units with reachable, holdable bays and docks (side bays, blocking pairs, an end bay)."""
    rail_max, clearance = opts.rail_length_m, opts.clearance_m
    units: list[_Unit] = []
    end_wanted = rng.uniform() < opts.end_bay_probability and n >= 2
    stations = list(np.arange(FIRST_STATION_M, rail_max - 0.2, STATION_SPACING_M))
    # One bay per station (a stage reaching a high bay hits a low bay's panels below it).
    slots = [(float(z), 0) for z in stations for _ in range(2)]  # each station drawn twice at most
    slots = [slots[int(k)] for k in rng.permutation(len(slots))]
    k = 0
    while len(units) < n:
        uid = f"U{len(units) + 1}"
        if end_wanted and not any(u.kind == "end" for u in units):
            end_wanted = False
            u = _draw_unit(rng, uid, "end")
            try:
                _end_bay(rng, robot, u, rail_max, clearance)
                _dock(rng, robot, u, clearance)
                units.append(u)
            except Redraw:
                pass
            continue
        if k >= len(slots):
            raise Redraw("more units than bay stations")
        z, row = slots[k]
        k += 1
        if any(v.kind == "side" and abs(v.p_bay[2] - z) < STATION_SPACING_M / 2 for v in units):
            continue  # the station holds a bay already
        u = _draw_unit(rng, uid, "side")
        try:
            _side_bay(rng, robot, section, u, z + rng.uniform(-0.05, 0.05), row, clearance)
            _dock(rng, robot, u, clearance)
        except Redraw:
            continue
        units.append(u)
        if len(units) < n and rng.uniform() < opts.pair_probability:
            front = _draw_unit(rng, f"U{len(units) + 1}", "front")
            if front.size[0] <= u.size[0] + 1e-9 and front.size[1] <= u.size[1] + 1e-9:
                try:
                    _front_of(rng, robot, u, front)
                    _dock(rng, robot, front, clearance)
                    units.append(front)
                except Redraw:
                    pass
    return units


def _layout(rng: np.random.Generator, section: Section, units: list[_Unit], rail_max: float) -> CabinLayout:
    """The cabin: shell, deck, end walls (the far one with the end bay's opening), bay panels, rings."""
    boxes: list[tuple[tuple[float, ...], tuple[float, ...]]] = []
    end_opening = None
    z_max = section.shell.z_max_m
    for u in units:
        if u.kind == "front":
            continue
        kind = "bay-side" if u.kind == "side" else "bay-end-far"
        f = u.free_m
        bay = BayLayout(kind, (f[0], f[1], f[2], f[3], f[4]), u.recess_m)
        panels, cavity, (_, _, _, _, z_open) = bay_boxes(pose(u.R, u.p_bay), u.size, bay)
        boxes += [(tuple(map(float, a)), tuple(map(float, b))) for a, b in panels]
        if u.kind == "end":
            wall_z = float(u.p_bay[2] + (u.R @ np.array([0.0, 0.0, z_open]))[2])
            z_max = float(np.round(np.max([b for _, b in panels], axis=0)[2] + 0.06, 3))
            lo_c, hi_c = cavity
            end_opening = ("far", wall_z, (lo_c[0], hi_c[0], lo_c[1], hi_c[1]))
            if wall_z - 0.26 < rail_max:
                raise Redraw("the end wall cuts the rail")
    section = section.over(section.shell.z_min_m, z_max)
    rings: list[RingFrame] = []
    if rng.uniform() < 0.4:
        depth_max = ring_depth_max(section)
        if depth_max > 0.03:
            depth = float(np.round(rng.uniform(0.03, min(0.06, depth_max)), 3))
            thick = float(np.round(rng.uniform(0.03, 0.06), 3))
            for z in np.arange(FIRST_STATION_M - STATION_SPACING_M / 2, rail_max, STATION_SPACING_M):
                rings.append(RingFrame(float(np.round(z, 3)), thick, depth))
    return CabinLayout(section=section, rings=tuple(rings), bay_boxes=tuple(boxes), end_opening=end_opening)


def _witnesses(
    robot: Cabin8,
    layout: CabinLayout,
    u: _Unit,
    clearance: float,
    bays: CollisionWorld,
    bare: CollisionWorld,
    rail_max: float,
) -> None:
    """Every key configuration of unit ``u`` alone in the cabin: exact IK, clear, holdable (or redraw).

    ``bays`` is the cabin with the unit held, ``bare`` without it; and the lane past the unit's fixture:
    wherever along the rail the park posture keeps the clearance in the cabin, it keeps it with the
    fixture there too.
    """
    e, up = u.R[:, 2], np.array([0.0, 1.0, 0.0])
    payload = u.payload()
    # In its bay the unit has the drawn free space (the clearance + 5 mm to 40 mm) to the panels.
    for what, p in (("bay", u.p_bay), ("pre-insertion", u.p_bay - u.approach_m * e)):
        if not any(bays.is_valid(q, clearance) for q in _reachable(robot, u, p)):
            raise Redraw(f"{u.kind} unit: no clear, holdable {what} configuration")
    need = clearance + WITNESS_EXTRA_M
    dock = loaded_cabin(replace(layout, plates=(_pedestal(u, layout.shell.deck_top_y_m, clearance),)))
    held = CollisionWorld(robot, dock, payload, grid_step_m=GRID_STEP_M)
    p_dock = _dock_pose(u)
    for what, p in (("dock", p_dock), ("lift-off", p_dock + LIFT_M * up)):
        if not any(held.is_valid(q, need) for q in _reachable(robot, u, p, R=u.R_dock)):
            raise Redraw(f"{u.kind} unit: no clear, holdable {what} configuration")
    empty = CollisionWorld(robot, dock, None, grid_step_m=GRID_STEP_M)
    pre = _reachable(robot, u, p_dock - u.grasp_line_m * u.R_dock[:, 2], 3, held=False, R=u.R_dock)
    if not any(empty.is_valid(q, need) for q in pre):
        raise Redraw(f"{u.kind} unit: no clear pre-grasp configuration")
    for d1 in np.arange(PARK_D1_M[0], rail_max + 1e-9, LANE_STEP_M):
        q = _park(robot, float(d1))
        if bare.is_valid(q, clearance) and not empty.is_valid(q, clearance):
            raise Redraw(f"{u.kind} unit: its fixture blocks the lane at d1 = {d1:.2f} m")


def _park(robot: Cabin8, d1: float) -> Array:
    """The robot's home posture at rail travel ``d1`` (joints).

    Inside every limit with its margins: a park posture sags under gravity, one on a limit would leave it.
    """
    drives = np.array(robot.home_drives, dtype=float)
    drives[0] = d1
    return np.asarray(robot.joints_from_drives(drives), dtype=float)


def _draw(seed: int, index: int, rng: np.random.Generator, opts: CycleGeneratorOptions) -> GeneratedCampaign:
    lo, hi = opts.units
    n = int(rng.integers(lo, hi + 1))
    rail_max, clearance = opts.rail_length_m, opts.clearance_m
    robot = robot_of(rail_max)
    section = draw_section(rng, MIXED, -0.5, rail_max + 0.5)
    units = _place_units(rng, robot, section, n, opts)
    layout = _layout(rng, section, units, rail_max)
    shell = layout.shell
    cabin = loaded_cabin(layout)
    bays = CollisionWorld(robot, cabin, None, grid_step_m=GRID_STEP_M)
    for u in units:
        bays_u = CollisionWorld(robot, cabin, u.payload(), grid_step_m=GRID_STEP_M)
        _witnesses(robot, layout, u, clearance, bays_u, bays, rail_max)
    # Park: home at the rail's start, clear by the clearance + 20 mm without a unit.
    park = next(
        (q for q in (_park(robot, d1) for d1 in PARK_D1_M) if bays.is_valid(q, clearance + 0.02)), None
    )
    if park is None:
        raise Redraw("no clear park posture")
    name = f"camp-{seed}-{index:03d}"
    mesh_name = f"{name}-cabin.stl"
    whole = merge(name, cabin_parts(layout))
    data = binary_stl_bytes(whole.vertices, whole.faces, f"cabinplan generated campaign cabin {name} [m]")
    doc_units = []
    for u in units:
        e = [float(v) for v in u.R[:, 2]]
        e_dock = [float(v) for v in u.R_dock[:, 2]]
        p_lo, p_hi = _pedestal(u, shell.deck_top_y_m, clearance)
        centre = (np.array(p_lo) + np.array(p_hi)) / 2
        doc_units.append(
            {
                "unit": {
                    "id": u.uid,
                    "box": list(u.size),
                    "mass": u.mass,
                    "grasp": pose_doc(pose(np.eye(3), u.grasp)),
                },
                "dock": {
                    "pose": pose_doc(pose(u.R_dock, _dock_pose(u))),
                    "fixture": {
                        "box": [float(v) for v in np.round(np.array(p_hi) - np.array(p_lo), 6)],
                        "pose": pose_doc(pose(np.eye(3), centre)),
                    },
                    "approach": {"direction": e_dock, "distance": u.grasp_line_m},
                    "lift": {"direction": [0.0, 1.0, 0.0], "distance": LIFT_M},
                },
                "bay": {
                    "pose": pose_doc(pose(u.R, u.p_bay)),
                    "approach": {"direction": e, "distance": u.approach_m},
                },
            }
        )
    park_drives = robot.drives_dict(robot.drives_from_joints(park))
    campaign: dict[str, Any] = {
        "name": name,
        "robot": "cabin8",
        "cabin": {"mesh": mesh_name, "units": "m"},
        "park": {"drives": {k: float(v) for k, v in park_drives.items()}},
        "units": doc_units,
        "order": "given",
        "options": {"clearance_m": clearance, "time_limit_s": opts.time_limit_s, "seed": 0},
    }
    if rail_max < ROBOT_RAIL_M:
        campaign["rail_length"] = rail_max
    meta = {
        "units": [
            {
                "id": u.uid,
                "kind": u.kind,
                "box_m": list(u.size),
                "mass_kg": u.mass,
                "bay_m": [float(v) for v in np.round(u.p_bay, 4)],
                "dock_m": list(u.dock_xz),
                "deep_of": u.deep_of,
            }
            for u in units
        ],
        "precedence": [[u.deep_of, u.uid] for u in units if u.deep_of is not None],
        "shell_diameter_m": 2 * shell.inner_radius_m,
        "ring_frames": len(layout.rings),
        "park_d1_m": float(park[chain.D1]),
        "rail_length_m": rail_max,
    }
    return GeneratedCampaign(name, campaign, mesh_name, data, meta)


def generate_campaign(
    seed: int, index: int, options: CycleGeneratorOptions | None = None
) -> GeneratedCampaign:
    """Campaign ``index`` of ``seed``: drawn from ``default_rng([seed, index, STREAM])`` until a draw passes.

    Raises:
        RuntimeError: no valid draw within ``options.max_attempts``.
    """
    opts = options or CycleGeneratorOptions()
    rng = np.random.default_rng([seed, index, STREAM])
    return first_valid(
        lambda: _draw(seed, index, rng, opts), opts.max_attempts, f"campaign {index} of seed {seed}"
    )


def generate_campaigns(
    seed: int, count: int, options: CycleGeneratorOptions | None = None
) -> list[GeneratedCampaign]:
    """Campaigns 0..count-1 of ``seed``."""
    return [generate_campaign(seed, i, options) for i in range(count)]


def cycle_document_of(
    case: GeneratedCampaign, unit_id: str, installed: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One generated cycle: the campaign's unit ``unit_id`` with ``installed`` already in their bays.

    The same composition as a campaign's cycles (:func:`planner.task.campaign.cycle_document`), so a
    generated cycle is an ordinary cycle document ``cabinplan cycle`` plans.
    """
    from planner.task.campaign import cycle_document
    from planner.task.campaign_schema import campaign_from_dict

    return cycle_document(campaign_from_dict(case.campaign), unit_id, installed)


def campaign_yaml(case: GeneratedCampaign) -> str:
    """The campaign file's text: a comment line describing the case, then the campaign as YAML."""
    m = {k: v for k, v in case.meta.items() if k not in ("redraws", "units")}
    kinds = ",".join(f"{u['id']}:{u['kind']}" for u in case.meta["units"])
    return commented_yaml(f"Generated campaign ({kinds}): {json.dumps(m)}", case.campaign)


def write_campaign(case: GeneratedCampaign, out_dir: Path) -> Path:
    """Write the campaign (``<name>.yaml``) and its cabin mesh into ``out_dir``; the campaign's path."""
    return write_generated(case, campaign_yaml(case), out_dir)
