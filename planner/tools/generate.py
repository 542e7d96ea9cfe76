"""Seeded generator of cabins and planning scenarios nobody tuned the planner for.

Each case is drawn from its own generator ``numpy.random.default_rng([seed, index])``, so case ``i`` of a
seed is the same whatever the count, and the same seed gives the same bytes. A case is built in this order:

1. **Payload**: a box of several sizes, 20-120 kg, grasped at an offset along and across the tool axis.
2. **Goal** (the robot's reachable workspace decides where things go, never the planner):

   * ``bay-side``: a rack bay in the +x wall, insertion along +x (the arm cannot point to -x: theta3 is
     within +-105 deg);
   * ``bay-end-far`` / ``bay-end-near``: a bay recessed into the far (+z) or near (-z) end wall, insertion
     along the rail;
   * ``shelf``: a pose goal without approach, the payload set down just above a shelf plate;
   * ``drive``: a drive goal (a second holdable configuration elsewhere along the rail).

   For a pose goal, an axis-aligned payload orientation is chosen and the payload position is sampled
   until the redundant family of the inverse kinematics (:func:`planner.redundancy.ik.family_candidates`)
   has an exact, admissible solution at the goal and at the pre-insertion pose (approach distance: the
   payload fully out of the bay plus 30-80 mm). The bay is then built *around* that payload pose with the
   drawn free space per side (12-40 mm to each side wall, top, bottom and back panel).
3. **Cabin**: a ring-frame or plain cylindrical shell of 2.4-3.0 m inner diameter with the floor deck of
   the reference cabins (the carriage's free space beside it is what the ring frames leave), optional
   overhead ducts, wall brackets and a bulkhead hatch between start and goal whose stepped opening is
   sized for the robot's tucked posture with this payload (widened until a straight rail motion in that
   posture is certified clear).
4. **Checks** with the project's own models: the goal (one exact IK solution) keeps the requested
   clearance (:class:`~planner.collision.world.CollisionWorld`) and is holdable
   (:class:`~planner.plan.goals.StaticForceCheck`); the start keeps the requested clearance + 20 mm and
   is holdable; a drive goal alike. A draw that fails is redrawn (the case's generator moves on).
5. **Files**: the cabin mesh in one of STL/OBJ/PLY/GLB, in m or mm, authored in a frame shifted along
   and rotated about the cabin axis (the scenario's ``cabin.pose`` maps it back), and an ordinary scenario
   dict a user can run with ``cabinplan plan``.

Everything here is pure (numpy in, bytes and dicts out) except :func:`write_case` at the edge.

Frame (as in ``meshes/README.md``): z along the cabin axis and the rail, y up, x lateral; SI units.
"""

from __future__ import annotations

import functools
import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
import yaml

from meshes.generate import (
    Bracket,
    Bulkhead,
    Duct,
    OpeningStep,
    Part,
    Shell,
    binary_stl_bytes,
    box,
    bracket_bounds,
    bulkhead,
    deck,
    duct,
    end_walls,
    glb_bytes,
    prism,
    tube,
)
from planner.collision.bodies import PayloadGeometry
from planner.collision.world import CollisionWorld
from planner.core.schemas import Pose
from planner.core.types import Array
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.kinematics import chain
from planner.meshio.load import LoadedMesh, load_mesh
from planner.plan.goals import StaticForceCheck
from planner.redundancy.ik import IKOptions, family_candidates, random_admissible_joints, track_pose
from planner.robots.cabin8 import Cabin8

log = logging.getLogger(__name__)

GoalKind = Literal["bay-side", "bay-end-far", "bay-end-near", "shelf", "drive"]
MeshFormat = Literal["stl", "obj", "ply", "glb"]

GOAL_KINDS: tuple[GoalKind, ...] = ("bay-side", "bay-end-far", "bay-end-near", "shelf", "drive")
MESH_FORMATS: tuple[MeshFormat, ...] = ("stl", "obj", "ply", "glb")
#: Draw weights of the goal kinds (bay insertions dominate, as in the issue's cabins).
GOAL_WEIGHTS: tuple[float, ...] = (0.40, 0.15, 0.10, 0.15, 0.20)

#: Inner diameters of the shells [m].
SHELL_DIAMETERS_M: tuple[float, ...] = (2.4, 2.6, 2.8, 3.0)
#: Payload boxes (tool x, tool y, tool z = insertion depth) [m].
PAYLOAD_BOXES_M: tuple[tuple[float, float, float], ...] = (
    (0.45, 0.35, 0.30),
    (0.40, 0.30, 0.25),
    (0.35, 0.25, 0.20),
    (0.50, 0.30, 0.30),
    (0.30, 0.30, 0.35),
)
#: Free space drawn per bay side [m].
FREE_RANGE_M: tuple[float, float] = (0.012, 0.040)
MASS_RANGE_KG: tuple[float, float] = (20.0, 120.0)
#: Clearance the start (and a drive goal) keeps beyond the requested one [m].
START_EXTRA_M = 0.020
PANEL_M = 0.02
#: Node spacing of the generator's collision worlds' bound grid [m] (coarser than the planner's: faster
#: to build for a new cabin, same verdicts).
GRID_STEP_M = 0.06
#: The carriage box corners in the cross-section (x, y) [m] (``meshes/README.md``).
_CARRIAGE_CORNERS = np.array([[0.85, -0.12], [0.85, 0.0], [-0.85, -0.12], [-0.85, 0.0]])
#: The tucked posture of ``meshes/README.md`` (arm along +z), apart from d1.
_TUCKED = np.array([0.0, 0.0, 0.20, 0.0, -math.pi / 2, math.radians(15.0), -0.25, math.pi / 2])
_FAMILY = IKOptions(grid_gamma=11, grid_d5=11)
#: The model's own rail length [m] (cabin8.yaml); a scenario states ``rail_length`` only when shorter.
ROBOT_RAIL_M = 6.0


class _Redraw(Exception):
    """A draw that does not make a valid case; the caller draws again."""


# ------------------------------------------------------------------------------------------ parameters


@dataclass(frozen=True)
class GeneratorOptions:
    """What every generated case shares.

    Attributes:
        clearance_m: The scenario's requested clearance [m].
        time_limit_s: The scenario's planning time limit [s] (the planner's default).
        goal_kinds: Goal kinds to draw from (weights of :data:`GOAL_WEIGHTS`, renormalised).
        formats: Mesh formats, cycled by case index.
        max_attempts: Redraws per case before giving up.
        rail_length_m: Rail length [m] (the cabin section is 0.5 m longer at each end); shorter rails make
            smaller, faster cases (the tests' sample).
    """

    clearance_m: float = 0.01
    time_limit_s: float = 30.0
    goal_kinds: tuple[GoalKind, ...] = GOAL_KINDS
    formats: tuple[MeshFormat, ...] = MESH_FORMATS
    max_attempts: int = 60
    rail_length_m: float = 6.0

    def __post_init__(self) -> None:
        if not 3.0 <= self.rail_length_m <= 6.0:
            raise ValueError(f"rail_length_m must be within [3, 6] m, got {self.rail_length_m}")


@dataclass(frozen=True)
class RingFrame:
    """A ring frame (stiffener) inside the shell: an annulus ``depth_m`` deep over z in [z_m, z_m + t]."""

    z_m: float
    thickness_m: float
    depth_m: float


@dataclass(frozen=True)
class BayLayout:
    """A bay built around the payload's goal pose.

    Attributes:
        kind: ``bay-side``, ``bay-end-far`` or ``bay-end-near``.
        free_m: Free space to the cavity walls (x-, x+, y-, y+, back) in the payload frame [m].
        recess_m: How far the payload's front face sits behind the opening [m].
    """

    kind: str
    free_m: tuple[float, float, float, float, float]
    recess_m: float


@dataclass(frozen=True)
class GeneratedCase:
    """One generated scenario: the scenario dict, the mesh file and what it was made of.

    Attributes:
        name: Scenario name (``gen-<seed>-<index>``).
        scenario: The scenario document (as written to YAML; mesh path relative to it).
        mesh_name: File name of the cabin mesh.
        mesh_bytes: The mesh file's content.
        meta: Features of the case (goal kind, shell, free space, format, ...), JSON-able.
        start_q: The start joints (8,) the checks were made at.
        goal_q: One exact goal configuration (8,) that passed the checks.
        layout: The cabin's geometry (base frame).
        T_base_cabin: The frame the mesh file is authored in (the scenario's ``cabin.pose``), (4, 4).
    """

    name: str
    scenario: dict[str, Any]
    mesh_name: str
    mesh_bytes: bytes = field(repr=False)
    meta: dict[str, Any]
    start_q: Array = field(repr=False)
    goal_q: Array = field(repr=False)
    layout: CabinLayout | None = field(default=None, repr=False)
    T_base_cabin: Array | None = field(default=None, repr=False)


# ------------------------------------------------------------------------------------------- geometry


@functools.cache
def _robot(rail_length_m: float) -> Cabin8:
    """The cabin8 model with this rail length (built once per length: its CasADi functions take a while)."""
    return Cabin8(rail_length=rail_length_m)


def _merge(name: str, parts: Sequence[Part]) -> Part:
    vertices, faces, offset = [], [], 0
    for part in parts:
        vertices.append(part.vertices)
        faces.append(part.faces + offset)
        offset += len(part.vertices)
    return Part(name, np.concatenate(vertices), np.concatenate(faces).astype(np.int64))


def ring_frame(shell: Shell, ring: RingFrame, sections: int = 64) -> Part:
    """An annulus from r = R - depth to R + wall/2 (embedded in the wall), above the deck, as convex prisms.

    The annulus is split into ``sections`` quadrilateral sectors, each a convex prism; sectors entirely
    below the deck are left out (nothing reaches there).
    """
    theta = 2 * np.pi * np.arange(sections + 1) / sections
    r_in, r_out = shell.inner_radius_m - ring.depth_m, shell.inner_radius_m + shell.wall_m / 2
    c, s = np.cos(theta), np.sin(theta)
    inner = np.column_stack([r_in * c, shell.axis_y_m + r_in * s])
    outer = np.column_stack([r_out * c, shell.axis_y_m + r_out * s])
    pieces = []
    for j in range(sections):
        quad = np.array([inner[j], outer[j], outer[j + 1], inner[j + 1]])
        if quad[:, 1].max() < shell.deck_top_y_m:
            continue
        pieces.append(prism(f"ring_{j}", quad, ring.z_m, ring.z_m + ring.thickness_m))
    return _merge("ring_frame", pieces)


def _aabb(
    R: Array, p: Array, lo: Sequence[float] | Array, hi: Sequence[float] | Array
) -> tuple[Array, Array]:
    """Base-frame corners of a box given in a frame (R, p) whose R is a signed permutation."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    world = corners @ R.T + p
    return world.min(axis=0), world.max(axis=0)


def bay_boxes(
    T_base_payload: Array, size: Sequence[float], bay: BayLayout
) -> tuple[list[tuple[Array, Array]], tuple[Array, Array], tuple[float, float, float, float, float]]:
    """Panels of a bay around a payload at its goal pose (axis-aligned R), as base-frame boxes.

    In the payload frame the cavity is x in [-bx/2 - f0, bx/2 + f1], y in [-by/2 - f2, by/2 + f3],
    z from the opening ``-bz/2 - recess`` to the back ``bz/2 + f4``; the opening faces -z (the approach
    comes from there). Five panels close it, and a face plate 60 mm wide frames the opening.

    Returns:
        The boxes (lo, hi), the cavity's own box (lo, hi) and the cavity bounds in the payload frame
        (x0, x1, y0, y1, z_open) for the end wall's opening.
    """
    R, p = T_base_payload[:3, :3], T_base_payload[:3, 3]
    bx, by, bz = size
    f = bay.free_m
    x0, x1, y0, y1 = -bx / 2 - f[0], bx / 2 + f[1], -by / 2 - f[2], by / 2 + f[3]
    z0, z1 = -bz / 2 - bay.recess_m, bz / 2 + f[4]
    t, m = PANEL_M, 0.06
    local = [
        ((x0 - t, y0 - t, z1), (x1 + t, y1 + t, z1 + t)),  # back
        ((x0 - t, y0 - t, z0), (x1 + t, y0, z1)),  # bottom
        ((x0 - t, y1, z0), (x1 + t, y1 + t, z1)),  # top
        ((x0 - t, y0, z0), (x0, y1, z1)),  # side x-
        ((x1, y0, z0), (x1 + t, y1, z1)),  # side x+
    ]
    if bay.kind == "bay-side":
        local += [  # the face plate around the opening
            ((x0 - t - m, y0 - t - m, z0 - t), (x1 + t + m, y0, z0)),
            ((x0 - t - m, y1, z0 - t), (x1 + t + m, y1 + t + m, z0)),
            ((x0 - t - m, y0, z0 - t), (x0, y1, z0)),
            ((x1, y0, z0 - t), (x1 + t + m, y1, z0)),
        ]
    boxes = [_aabb(R, p, lo, hi) for lo, hi in local]
    cavity = _aabb(R, p, (x0, y0, z0), (x1, y1, z1))
    return boxes, cavity, (x0, x1, y0, y1, z0)


@dataclass(frozen=True)
class CabinLayout:
    """Everything that defines one generated cabin (base frame, metres)."""

    shell: Shell
    rings: tuple[RingFrame, ...] = ()
    bay_boxes: tuple[tuple[tuple[float, ...], tuple[float, ...]], ...] = ()
    end_opening: tuple[str, float, tuple[float, float, float, float]] | None = None
    bulkhead: Bulkhead | None = None
    ducts: tuple[Duct, ...] = ()
    brackets: tuple[Bracket, ...] = ()
    plates: tuple[tuple[tuple[float, ...], tuple[float, ...]], ...] = ()


def cabin_parts(layout: CabinLayout) -> list[Part]:
    """The cabin's closed pieces in a fixed order (shell, deck, end walls, rings, bay, clutter)."""
    shell = layout.shell
    parts = [tube(shell), deck(shell)]
    walls = end_walls(shell)
    if layout.end_opening is not None:
        # The bay's end wall: a wall across the cabin with the bay's opening, the cavity behind it.
        which, z_m, (x0, x1, y0, y1) = layout.end_opening
        step = OpeningStep("bay", x0, x1, y0, y1)
        parts.append(bulkhead(shell, Bulkhead(z_m=z_m, thickness_m=shell.wall_m, steps=(step,))))
        walls = [w for w in walls if (w.name == "end_wall_min") == (which == "far")]
        parts += walls
    else:
        parts += walls
    parts += [ring_frame(shell, r) for r in layout.rings]
    parts += [box(f"bay_{i}", lo, hi) for i, (lo, hi) in enumerate(layout.bay_boxes)]
    parts += [box(f"plate_{i}", lo, hi) for i, (lo, hi) in enumerate(layout.plates)]
    if layout.bulkhead is not None:
        parts.append(bulkhead(shell, layout.bulkhead))
    parts += [duct(i, d) for i, d in enumerate(layout.ducts)]
    parts += [box(f"bracket_{i}", *bracket_bounds(shell, b)) for i, b in enumerate(layout.brackets)]
    return parts


def cabin_mesh(layout: CabinLayout) -> trimesh.Trimesh:
    """The assembled cabin as one triangle soup in the base frame (no processing)."""
    whole = _merge("cabin", cabin_parts(layout))
    return trimesh.Trimesh(whole.vertices, whole.faces, process=False)


def mesh_bytes(
    layout: CabinLayout, fmt: MeshFormat, units: Literal["m", "mm"], T_base_cabin: Array, name: str
) -> bytes:
    """The cabin's file: vertices expressed in the file frame (``inv(T_base_cabin)``), in ``units``."""
    scale = 1000.0 if units == "mm" else 1.0
    T_cabin_base = np.linalg.inv(T_base_cabin)
    parts = [
        Part(p.name, scale * (p.vertices @ T_cabin_base[:3, :3].T + T_cabin_base[:3, 3]), p.faces)
        for p in cabin_parts(layout)
    ]
    if fmt == "glb":
        # One node per part; names must be unique (a scene keeps one geometry per name).
        return glb_bytes([Part(f"{i:03d}_{p.name}", p.vertices, p.faces) for i, p in enumerate(parts)])
    whole = _merge(name, parts)
    if fmt == "stl":
        return binary_stl_bytes(whole.vertices, whole.faces, f"cabinplan generated cabin {name} [{units}]")
    mesh = trimesh.Trimesh(whole.vertices, whole.faces, process=False)
    if fmt == "obj":
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False)
        return str(text).encode("ascii")
    return bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))


# ------------------------------------------------------------------------------------------- sampling


def _rot_z(angle: float) -> Array:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def payload_rotation(kind: str, roll: int) -> Array:
    """Axis-aligned payload orientation: its z axis is the insertion direction, ``roll`` in {0, 1}.

    ``roll`` 1 turns the payload 90 deg about its own z axis (its x axis vertical).
    """
    z = {"bay-side": (1.0, 0.0, 0.0), "bay-end-far": (0.0, 0.0, 1.0), "bay-end-near": (0.0, 0.0, -1.0)}[kind]
    ez = np.array(z)
    ex = np.array([0.0, 1.0, 0.0]) if roll else np.cross(np.array([0.0, 1.0, 0.0]), ez)
    ey = np.cross(ez, ex)
    return np.column_stack([ex, ey, ez])


def _pose(R: Array, p: Array) -> Array:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def exact_solutions(robot: Cabin8, T_base_tool: Array, u_ref: Array, count: int = 3) -> list[Array]:
    """Up to ``count`` exact, admissible, distinct IK solutions of a tool pose (best margin first)."""
    good, _ = family_candidates(robot, T_base_tool, u_ref, 0.3, _FAMILY)
    out: list[Array] = []
    for cand in good:
        if len(out) >= count:
            break
        if any(np.all(np.abs(cand.q[[3, 6]] - q[[3, 6]]) < np.array([0.08, 0.08])) for q in out):
            continue
        sol = track_pose(robot, cand.q, T_base_tool, cand.q)
        if sol is not None:
            out.append(sol.q)
    return out


@dataclass
class _Draw:
    """The state of one draw of a case (mutable while it is built)."""

    rng: np.random.Generator
    robot: Cabin8
    payload: PayloadGeometry
    size: tuple[float, float, float]
    kind: str
    shell: Shell
    meta: dict[str, Any] = field(default_factory=dict)


def _payload(rng: np.random.Generator) -> tuple[tuple[float, float, float], PayloadGeometry, dict[str, Any]]:
    size = PAYLOAD_BOXES_M[int(rng.integers(len(PAYLOAD_BOXES_M)))]
    mass = float(np.round(rng.uniform(*MASS_RANGE_KG), 1))
    grasp = np.round(
        [rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), size[2] / 2 + rng.uniform(0.03, 0.08)], 4
    )
    T = np.eye(4)
    T[:3, 3] = grasp
    payload = PayloadGeometry(size=size, source="box", T_tool_payload=T, mass=mass)
    return size, payload, {"payload_box_m": list(size), "mass_kg": mass, "grasp_m": grasp.tolist()}


def _shell(rng: np.random.Generator, z_min: float = -0.5, z_max: float = 6.5) -> Shell:
    diameter = SHELL_DIAMETERS_M[int(rng.integers(len(SHELL_DIAMETERS_M)))]
    return Shell(
        inner_radius_m=diameter / 2,
        z_min_m=z_min,
        z_max_m=z_max,
        z_segments=max(4, int(math.ceil((z_max - z_min) / 0.5))),
    )


def _ring_depth_max(shell: Shell) -> float:
    """Deepest ring frame that leaves the carriage 30 mm (its corners' distance to the axis)."""
    d = np.hypot(_CARRIAGE_CORNERS[:, 0], _CARRIAGE_CORNERS[:, 1] - shell.axis_y_m)
    return float(shell.inner_radius_m - d.max() - 0.03)


def _tool_pose(T_base_payload: Array, payload: PayloadGeometry) -> Array:
    return T_base_payload @ np.linalg.inv(payload.T_tool_payload)


def _goal_bay(d: _Draw, rail_max: float) -> tuple[Array, Array, BayLayout, float, list[Array]]:
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
        if d.kind == "bay-side":
            y = rng.uniform(0.35, 1.25)
            z = rng.uniform(0.8, rail_max - 0.3)
            axis = d.shell.axis_y_m
            x_wall = d.shell.half_width_at(axis + max(abs(y + half[1] - axis), abs(y - half[1] - axis)))
            x_hi = x_wall - (size[2] / 2 + free[4] + PANEL_M)
            x = rng.uniform(0.55, x_hi) if x_hi > 0.55 else math.nan
            p = np.array([x, y, z])
        else:
            p = np.array([rng.uniform(-0.45, 0.55), rng.uniform(0.35, 1.15), math.nan])
            # along the rail: as far towards the end as the arm reaches from the rail's end
            reach = rng.uniform(0.55, 1.05)
            p[2] = rail_max + reach if d.kind == "bay-end-far" else -reach
        if not np.all(np.isfinite(p)):
            continue
        T_goal = _pose(R, p)
        sols = exact_solutions(robot, _tool_pose(T_goal, d.payload), robot.home_drives)
        if not sols:
            continue
        pre = exact_solutions(robot, _tool_pose(_pose(R, p - distance * e), d.payload), robot.home_drives, 1)
        if not pre:
            continue
        d.meta.update(roll=roll, free_per_side_m=list(free), recess_m=recess)
        return T_goal, e, bay, distance, sols
    raise _Redraw("no reachable bay pose")


def _goal_shelf(d: _Draw, rail_max: float) -> tuple[Array, list[tuple[tuple[float, ...], tuple[float, ...]]]]:
    """A reachable pose goal without approach just above a shelf plate (free gap 12-40 mm below)."""
    rng, robot, size = d.rng, d.robot, d.size
    for _ in range(40):
        kind = ("bay-side", "bay-end-far", "bay-end-near")[int(rng.integers(3))]
        R = payload_rotation(kind, int(rng.integers(2)))
        p = np.array([rng.uniform(-0.3, 0.9), rng.uniform(0.45, 1.2), rng.uniform(0.8, rail_max - 0.2)])
        T_goal = _pose(R, p)
        sols = exact_solutions(robot, _tool_pose(T_goal, d.payload), robot.home_drives)
        if not sols:
            continue
        lo, hi = _aabb(R, p, -np.array(size) / 2, np.array(size) / 2)
        gap = float(np.round(rng.uniform(*FREE_RANGE_M), 4))
        margin = rng.uniform(0.03, 0.12, size=2)
        plate = (
            (lo[0] - margin[0], lo[1] - gap - 0.02, lo[2] - margin[1]),
            (hi[0] + margin[0], lo[1] - gap, hi[2] + margin[1]),
        )
        d.meta.update(shelf_gap_m=gap, free_per_side_m=[gap])
        return T_goal, [plate]
    raise _Redraw("no reachable shelf pose")


def _tucked(d1: float) -> Array:
    q = _TUCKED.copy()
    q[chain.D1] = d1
    return q


def _hatch(
    d: _Draw,
    world_of: Callable[[Bulkhead], tuple[CollisionWorld, StaticForceCheck]],
    z_bh: float,
    clearance: float,
) -> Bulkhead | None:
    """A bulkhead at ``z_bh`` whose stepped opening passes the tucked posture with this payload.

    The arm step is sized from the payload box at the tucked posture plus a drawn margin, then widened
    (20 mm a time) until the straight rail motion through the bulkhead in that posture is certified
    with the requested clearance + 10 mm; ``None`` if it never is (or the posture is not holdable).
    """
    rng, robot = d.rng, d.robot
    q = _tucked(z_bh)
    T = robot.fk(q) @ d.payload.T_tool_box
    half = np.array(d.payload.size) / 2
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    pts = corners @ T[:3, :3].T + T[:3, 3]
    margin = float(rng.uniform(0.07, 0.11))
    x_half = float(max(abs(pts[:, 0]).max() + margin, 0.25))
    y_top = float(max(pts[:, 1].max() + margin, 0.9))
    for _ in range(6):
        steps = (
            OpeningStep("carriage", -0.90, 0.90, d.shell.deck_top_y_m, 0.08),
            OpeningStep("stage", -0.60, 0.60, 0.08, 0.40),
            OpeningStep("arm", -x_half, x_half, 0.40, y_top),
        )
        spec = Bulkhead(z_m=float(np.round(z_bh, 3)), thickness_m=0.05, steps=steps)
        world, forces = world_of(spec)
        if not forces.ok(q):
            return None
        a, b = _tucked(z_bh - 1.0), _tucked(z_bh + 0.7)
        if world.check_motion(a, b, clearance + 0.01).valid:
            return spec
        x_half, y_top = x_half + 0.02, y_top + 0.02
    return None


def _configuration(
    d: _Draw, world: CollisionWorld, forces: StaticForceCheck, d1_range: tuple[float, float], clearance: float
) -> Array:
    """A start-like configuration in ``d1_range``: clear by ``clearance``, holdable; near home or uniform."""
    rng, robot = d.rng, d.robot
    if d1_range[1] - d1_range[0] < 0.05:
        raise _Redraw("no room on the rail")
    q_home = robot.joints_from_drives(robot.home_drives)
    for _ in range(8):
        if rng.uniform() < 0.5:
            noise = rng.normal(0.0, 1.0, size=(60, 8)) * np.array([0, 0.08, 0.04, 0.08, 0.4, 0.25, 0.1, 0.6])
            qs = q_home + noise
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
    raise _Redraw("no clear, holdable configuration")


def _clutter_ok(lo: Array, hi: Array, keep_out: list[tuple[Array, Array]]) -> bool:
    return all(np.any(hi <= k_lo) or np.any(lo >= k_hi) for k_lo, k_hi in keep_out)


def _draw(seed: int, index: int, rng: np.random.Generator, opts: GeneratorOptions) -> GeneratedCase:
    """One attempt at case ``index``; raises :class:`_Redraw` when the draw does not make a valid case."""
    weights = np.array([GOAL_WEIGHTS[GOAL_KINDS.index(k)] for k in opts.goal_kinds])
    kind = opts.goal_kinds[int(rng.choice(len(opts.goal_kinds), p=weights / weights.sum()))]
    size, payload, meta = _payload(rng)
    meta["goal"] = kind
    rail_max = opts.rail_length_m
    z_min, z_max = -0.5, opts.rail_length_m + 0.5
    if kind == "bay-end-far":
        rail_max = float(np.round(rng.uniform(opts.rail_length_m - 2.0, opts.rail_length_m), 3))
    base_robot = _robot(rail_max)
    d = _Draw(rng, base_robot, payload, size, kind, _shell(rng, z_min, z_max), meta)
    clearance = opts.clearance_m

    goal_pose: Array | None = None
    direction: Array | None = None
    distance = 0.0
    bay_list: list[tuple[Array, Array]] = []
    plates: list[tuple[tuple[float, ...], tuple[float, ...]]] = []
    keep_out: list[tuple[Array, Array]] = []
    end_opening = None
    goal_sols: list[Array] = []
    if kind.startswith("bay"):
        goal_pose, direction, bay, distance, goal_sols = _goal_bay(d, rail_max)
        bay_list, cavity, (x0, x1, y0, y1, z_open) = bay_boxes(goal_pose, size, bay)
        lo_all = np.min([b[0] for b in bay_list], axis=0)
        hi_all = np.max([b[1] for b in bay_list], axis=0)
        p_pre = goal_pose[:3, 3] - distance * direction
        corridor_lo = np.minimum(lo_all, p_pre - np.max(size) - 0.1)
        corridor_hi = np.maximum(hi_all, p_pre + np.max(size) + 0.1)
        keep_out.append((corridor_lo, corridor_hi))
        if kind != "bay-side":
            # The end wall's plane is the opening; the section ends just behind the cavity.
            R, p = goal_pose[:3, :3], goal_pose[:3, 3]
            wall_z = float(p[2] + (R @ np.array([0.0, 0.0, z_open]))[2])
            lo_c, hi_c = cavity
            if kind == "bay-end-far":
                z_max = float(np.round(hi_all[2] + 0.06, 3))
                end_opening = ("far", wall_z, (lo_c[0], hi_c[0], lo_c[1], hi_c[1]))
                if wall_z - 0.2 - 0.06 < rail_max:
                    raise _Redraw("the end wall cuts the rail")
            else:
                z_min = float(np.round(lo_all[2] - 0.06, 3))
                end_opening = ("near", wall_z - d.shell.wall_m, (lo_c[0], hi_c[0], lo_c[1], hi_c[1]))
                if wall_z - d.shell.wall_m > -0.2 - 0.06:
                    raise _Redraw("the end wall cuts the rail")
            d.shell = _shell_like(d.shell, z_min, z_max)
    elif kind == "shelf":
        goal_pose, plates = _goal_shelf(d, rail_max)
        keep_out.append((np.array(plates[0][0]) - 0.45, np.array(plates[0][1]) + np.array([0.45, 0.8, 0.45])))
    shell = d.shell
    rings: list[RingFrame] = []
    if rng.uniform() < 0.6:
        depth_max = _ring_depth_max(shell)
        if depth_max > 0.03:
            spacing = rng.uniform(0.45, 0.75)
            depth = float(np.round(rng.uniform(0.03, min(0.10, depth_max)), 3))
            thick = float(np.round(rng.uniform(0.03, 0.07), 3))
            z = shell.z_min_m + rng.uniform(0.3, 0.3 + spacing)
            while z < shell.z_max_m - 0.3:
                lo = np.array([-2.0, -1.0, z - 0.02])
                hi = np.array([2.0, 3.0, z + thick + 0.02])
                r_free = shell.inner_radius_m - depth - 0.02
                if all(_clutter_ok(lo, hi, [k]) or _inside_radius(k, shell, r_free) for k in keep_out):
                    rings.append(RingFrame(float(np.round(z, 3)), thick, depth))
                z += spacing
    ducts: list[Duct] = []
    for _ in range(int(rng.integers(0, 4))):
        radius = float(np.round(rng.uniform(0.05, 0.11), 3))
        angle = math.pi / 2 + rng.uniform(-1.0, 1.0)
        r_c = shell.inner_radius_m - radius - rng.uniform(0.04, 0.10)
        x, y = r_c * math.cos(angle), shell.axis_y_m + r_c * math.sin(angle)
        z0, z1 = shell.z_min_m + 0.04, shell.z_max_m - 0.04
        cand = Duct(float(np.round(x, 3)), float(np.round(y, 3)), radius, z0, z1)
        if _clutter_ok(
            np.array([x - radius, y - radius, z0]), np.array([x + radius, y + radius, z1]), keep_out
        ):
            ducts.append(cand)
    brackets: list[Bracket] = []
    for _ in range(int(rng.integers(0, 7))):
        b = Bracket(
            side=int(rng.choice([-1, 1])),
            y_center_m=float(np.round(rng.uniform(0.3, 1.5), 3)),
            z_center_m=float(np.round(rng.uniform(shell.z_min_m + 0.3, shell.z_max_m - 0.3), 3)),
            protrusion_m=float(np.round(rng.uniform(0.08, 0.22), 3)),
            height_m=float(np.round(rng.uniform(0.06, 0.12), 3)),
            length_m=float(np.round(rng.uniform(0.12, 0.35), 3)),
        )
        b_lo, b_hi = bracket_bounds(shell, b)
        if _clutter_ok(np.array(b_lo), np.array(b_hi), keep_out):
            brackets.append(b)

    robot = d.robot
    layout = CabinLayout(
        shell=shell,
        rings=tuple(rings),
        bay_boxes=tuple((tuple(map(float, lo)), tuple(map(float, hi))) for lo, hi in bay_list),
        end_opening=end_opening,
        ducts=tuple(ducts),
        brackets=tuple(brackets),
        plates=tuple(plates),
    )
    dynamics = Cabin8Dynamics.of(robot)
    forces = StaticForceCheck(dynamics, payload.rigid_payload())

    def world_of(layout_: CabinLayout) -> CollisionWorld:
        # A coarse bound grid: the verdicts are exact either way (FCL decides what the bounds do not).
        return CollisionWorld(robot, _loaded(layout_), payload, grid_step_m=GRID_STEP_M)

    # The goal and where the start goes along the rail.
    if goal_pose is not None:
        T_tool = _tool_pose(goal_pose, payload)
        goal_sols = goal_sols or exact_solutions(robot, T_tool, robot.home_drives)
        goal_d1 = float(np.median([q[chain.D1] for q in goal_sols])) if goal_sols else 3.0
    else:
        goal_d1 = float(rng.uniform(0.3, rail_max - 0.3))
    far = rng.uniform() < 0.5
    span = (0.0, rail_max)
    if far:  # start well away from the goal along the rail
        lo_side = (span[0] + 0.05, goal_d1 - 1.5)
        hi_side = (goal_d1 + 1.5, span[1] - 0.05)
        pick = lo_side if lo_side[1] - lo_side[0] > hi_side[1] - hi_side[0] else hi_side
    else:
        pick = (max(span[0] + 0.05, goal_d1 - 1.2), min(span[1] - 0.05, goal_d1 + 1.2))
    # A hatch between start and goal: placed once the start side is known.
    hatch_wanted = far and rng.uniform() < 0.5 and pick[1] - pick[0] > 0.3
    world = world_of(layout)
    if kind == "drive":
        q_goal = _configuration(d, world, forces, (0.05, rail_max - 0.05), clearance + START_EXTRA_M)
        goal_d1 = float(q_goal[chain.D1])
        lo_side = (0.05, goal_d1 - 1.5)
        hi_side = (goal_d1 + 1.5, rail_max - 0.05)
        pick = lo_side if lo_side[1] - lo_side[0] > hi_side[1] - hi_side[0] else hi_side
        goal_sols = [q_goal]
    else:
        valid = [q for q in goal_sols if world.is_valid(q, clearance) and forces.ok(q)]
        if not valid:
            raise _Redraw("no goal solution keeps the clearance and holds the payload")
        q_goal = valid[0]
    q_start = _configuration(d, world, forces, pick, clearance + START_EXTRA_M)
    if hatch_wanted:
        d1_a, d1_b = sorted((float(q_start[chain.D1]), goal_d1))
        if d1_b - d1_a > 1.6:
            z_bh = float(rng.uniform(d1_a + 0.7, d1_b - 0.7))

            def hatch_world(spec: Bulkhead) -> tuple[CollisionWorld, StaticForceCheck]:
                return world_of(_with_bulkhead(layout, spec)), forces

            spec = _hatch(d, hatch_world, z_bh, clearance)
            if spec is not None:
                layout = _with_bulkhead(layout, spec)
                world = world_of(layout)
                if not (
                    world.is_valid(q_start, clearance + START_EXTRA_M)
                    and all(world.is_valid(q, clearance) for q in (q_goal,))
                ):
                    raise _Redraw("the hatch blocks the start or the goal")
                meta["bulkhead_z_m"] = spec.z_m

    meta.update(
        witness_goal_q=[float(v) for v in q_goal],
        witness_goal_distance_m=float(np.round(world.min_distance(q_goal).distance_m, 5)),
        shell_diameter_m=2 * shell.inner_radius_m,
        ring_frames=len(rings),
        ducts=len(ducts),
        brackets=len(brackets),
        rail_length_m=rail_max,
        start_to_goal_rail_m=float(np.round(abs(goal_d1 - q_start[chain.D1]), 3)),
    )
    if "free_per_side_m" in meta:
        meta["min_free_m"] = float(min(meta["free_per_side_m"]))
    # The file: format, units and the frame it is authored in.
    fmt = opts.formats[index % len(opts.formats)]
    units: Literal["m", "mm"] = "mm" if rng.uniform() < 0.4 else "m"
    shift = float(np.round(rng.uniform(-1.5, 1.5), 3)) if rng.uniform() < 0.6 else 0.0
    angle = float(
        rng.choice([0.0, math.pi / 2, math.pi, -math.pi / 2, float(np.round(rng.uniform(-3, 3), 3))])
    )
    T_base_cabin = np.eye(4)
    T_base_cabin[:3, :3] = _rot_z(angle)
    T_base_cabin[:3, 3] = (0.0, shell.axis_y_m, shift)
    name = f"gen-{seed}-{index:03d}"
    mesh_name = f"{name}-cabin.{fmt}"
    data = mesh_bytes(layout, fmt, units, T_base_cabin, name)
    meta.update(format=fmt, units=units, cabin_shift_m=shift, cabin_rotation_rad=angle)

    scenario: dict[str, Any] = {
        "name": name,
        "robot": "cabin8",
        "cabin": {"mesh": mesh_name, "units": units, "pose": _pose_doc(T_base_cabin)},
        "payload": {
            "box": list(size),
            "mass": meta["mass_kg"],
            "grasp": _pose_doc(payload.T_tool_payload),
        },
        "start": {"drives": robot.drives_dict(robot.drives_from_joints(q_start))},
        "options": {"clearance_m": clearance, "time_limit_s": opts.time_limit_s, "seed": 0},
    }
    if rail_max < ROBOT_RAIL_M:
        scenario["rail_length"] = rail_max
    if kind == "drive":
        scenario["goal"] = {"drives": robot.drives_dict(robot.drives_from_joints(q_goal))}
    else:
        assert goal_pose is not None
        goal: dict[str, Any] = {"pose": _pose_doc(goal_pose)}
        if direction is not None:
            goal["approach"] = {"direction": [float(v) for v in direction], "distance": distance}
        scenario["goal"] = goal
    scenario["start"]["drives"] = {k: float(v) for k, v in scenario["start"]["drives"].items()}
    if "drives" in scenario["goal"]:
        scenario["goal"]["drives"] = {k: float(v) for k, v in scenario["goal"]["drives"].items()}
    return GeneratedCase(name, scenario, mesh_name, data, meta, q_start, q_goal, layout, T_base_cabin)


def _inside_radius(box_: tuple[Array, Array], shell: Shell, radius: float) -> bool:
    lo, hi = box_
    xs, ys = (lo[0], hi[0]), (lo[1], hi[1])
    return all(math.hypot(x, y - shell.axis_y_m) <= radius for x in xs for y in ys)


def _shell_like(shell: Shell, z_min: float, z_max: float) -> Shell:
    return Shell(
        inner_radius_m=shell.inner_radius_m,
        z_min_m=z_min,
        z_max_m=z_max,
        z_segments=max(4, int(math.ceil((z_max - z_min) / 0.5))),
    )


def _with_bulkhead(layout: CabinLayout, spec: Bulkhead) -> CabinLayout:
    return CabinLayout(**{**{k: getattr(layout, k) for k in layout.__dataclass_fields__}, "bulkhead": spec})


def _loaded(layout: CabinLayout) -> LoadedMesh:
    whole = _merge("cabin", cabin_parts(layout))
    return load_mesh(binary_stl_bytes(whole.vertices, whole.faces, "generated"), units="m", name="cabin.stl")


def _pose_doc(T: Array) -> dict[str, Any]:
    pose = Pose.from_matrix(T)
    q = pose.orientation
    return {
        "position": [float(np.round(v, 9)) + 0.0 for v in pose.position],
        "orientation": {k: float(np.round(getattr(q, k), 12)) + 0.0 for k in ("w", "x", "y", "z")},
    }


def generate_case(seed: int, index: int, options: GeneratorOptions | None = None) -> GeneratedCase:
    """Case ``index`` of ``seed``: drawn from ``default_rng([seed, index])`` until a draw passes the checks.

    Raises:
        RuntimeError: no valid draw within ``options.max_attempts`` (not seen with the defaults).
    """
    opts = options or GeneratorOptions()
    rng = np.random.default_rng([seed, index])
    reasons: dict[str, int] = {}
    for _ in range(opts.max_attempts):
        try:
            case = _draw(seed, index, rng, opts)
        except _Redraw as exc:
            reasons[str(exc)] = reasons.get(str(exc), 0) + 1
            continue
        case.meta["redraws"] = reasons
        return case
    raise RuntimeError(f"case {index} of seed {seed}: no valid draw in {opts.max_attempts} ({reasons})")


def generate_cases(seed: int, count: int, options: GeneratorOptions | None = None) -> list[GeneratedCase]:
    """Cases 0..count-1 of ``seed``."""
    return [generate_case(seed, i, options) for i in range(count)]


# ------------------------------------------------------------------------------------------------ I/O


def scenario_yaml(case: GeneratedCase) -> str:
    """The scenario file's text: a comment line describing the case, then the scenario as YAML."""
    m = case.meta
    head = f"# Generated ({m['goal']}): {json.dumps({k: v for k, v in m.items() if k != 'redraws'})}\n"
    return head + yaml.safe_dump(case.scenario, sort_keys=False, default_flow_style=None, width=110)


def write_case(case: GeneratedCase, out_dir: Path) -> Path:
    """Write the case's scenario (``<name>.yaml``) and mesh file into ``out_dir``; the scenario's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / case.mesh_name).write_bytes(case.mesh_bytes)
    path = out_dir / f"{case.name}.yaml"
    path.write_text(scenario_yaml(case), encoding="utf-8")
    return path


def write_manifest(cases: Sequence[GeneratedCase], out_dir: Path, seed: int) -> Path:
    """``manifest.json``: the seed and, per case, its scenario file, mesh file and features."""
    doc = {
        "generator": "planner.tools.generate",
        "seed": seed,
        "count": len(cases),
        "cases": [
            {"name": c.name, "scenario": f"{c.name}.yaml", "mesh": c.mesh_name, **c.meta} for c in cases
        ],
    }
    path = out_dir / "manifest.json"
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path


__all__ = [
    "GOAL_KINDS",
    "MESH_FORMATS",
    "CabinLayout",
    "GeneratedCase",
    "GeneratorOptions",
    "RingFrame",
    "cabin_mesh",
    "exact_solutions",
    "generate_case",
    "generate_cases",
    "payload_rotation",
    "ring_frame",
    "scenario_yaml",
    "write_case",
    "write_manifest",
]
