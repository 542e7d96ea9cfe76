"""A cycle made concrete: robot, cabin, obstacles, the unit's geometry and inertia, poses and lines.

:func:`resolve_cycle` loads the robot and the meshes, turns poses into 4x4 transforms and lines into unit
vectors, and checks what the schema cannot: the installed units do not overlap (the error names both), the
bay is free (no installed unit overlaps the unit at its installed pose), the unit on its dock is clear of its
fixture. :func:`load_cycle` reads, validates and resolves a file.

Geometry of the unit: a box, or a mesh covered by its oriented bounding box (as a scenario's mesh payload),
held (a payload body) and installed (an obstacle) alike. With a gripper, the body fixed to the tool while
the unit is held is the box in the unit's box frame that contains both (``held``); its inertia stays the
unit's (the gripper's mass belongs to the robot description's tool).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import fcl
import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.collision.obstacles import Obstacle
from planner.core.exceptions import InvalidInput
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.meshio.load import MeshLimits
from planner.robots.cabin8 import Cabin8
from planner.robots.geometry import BOX_CORNER_SIGNS, PAYLOAD
from planner.scenario.files import read_document
from planner.scenario.resolve import MeshResolver, ResolvedScenario, _load, _mesh_source, resolve_scenario
from planner.scenario.schema import Scenario
from planner.task.schema import Cycle, Geometry, LineSpec, cycle_from_dict, cycle_hash


@dataclass(frozen=True)
class Line:
    """A straight tool line: unit direction (3,) in the base frame and length [m]."""

    direction: Array = field(repr=False)
    distance_m: float

    @property
    def offset(self) -> Array:
        """Direction * distance (3,) [m]."""
        return self.direction * self.distance_m


@dataclass(frozen=True)
class ResolvedCycle:
    """A cycle made concrete. Transforms are 4x4 in the base frame; every array read-only.

    Attributes:
        spec: The validated cycle.
        base: The cycle's base scenario (robot, cabin, options; start = goal = the park posture), from which
            every leg's scenario is made (:mod:`planner.task.legs`).
        installed: The installed units as obstacles (``unit <id>``).
        unit: The unit as its own payload (its box, grasp and inertia).
        held: The body fixed to the tool while the unit is held: the unit, grown to contain the gripper.
        gripper: The gripper as the empty tool's payload body, or None without a gripper.
        unit_payload: The unit's inertial data in the tool frame (held).
        T_tool_unit: The grasp.
        T_base_unit_dock: The unit on its dock.
        T_base_unit_bay: The unit installed.
        fixture: The dock's fixture (``fixture of <id>``).
        dock_unit: The unit waiting on its dock, as an obstacle (``unit <id>``).
        bay_unit: The unit installed in its bay, as an obstacle (``unit <id>``).
        grasp_line, lift_line, insertion_line, retract_line: The straight tool lines.
        park_u, park_q: The park posture (drives, joints).
        grasp_dwell_s, release_dwell_s: Dwell times [s].
        sha256: :func:`~planner.task.schema.cycle_hash` of ``spec``.
    """

    spec: Cycle
    base: ResolvedScenario
    installed: tuple[Obstacle, ...]
    unit: PayloadGeometry
    held: PayloadGeometry
    gripper: PayloadGeometry | None
    unit_payload: RigidPayload
    T_tool_unit: Array = field(repr=False)
    T_base_unit_dock: Array = field(repr=False)
    T_base_unit_bay: Array = field(repr=False)
    fixture: Obstacle = field(repr=False)
    dock_unit: Obstacle = field(repr=False)
    bay_unit: Obstacle = field(repr=False)
    grasp_line: Line = field(repr=False)
    lift_line: Line = field(repr=False)
    insertion_line: Line = field(repr=False)
    retract_line: Line = field(repr=False)
    park_u: Array = field(repr=False)
    park_q: Array = field(repr=False)
    grasp_dwell_s: float = 0.0
    release_dwell_s: float = 0.0
    sha256: str = ""

    @property
    def robot(self) -> Cabin8:
        """The robot model."""
        return self.base.robot

    @property
    def unit_name(self) -> str:
        """How reports name the unit: ``unit <id>``."""
        return f"unit {self.spec.unit.id}"

    @property
    def gripper_body(self) -> str:
        """The world body that meets the unit at the grasp and the release.

        the gripper (the empty tool's payload body), or without one the robot's body fixed to the tool.
        """
        if self.gripper is not None:
            return PAYLOAD
        model = self.robot.collision_model()
        return next(b for b in reversed(model.body_names) if model.adjacent(b, PAYLOAD))

    @property
    def gripper_label(self) -> str:
        """The gripper body's name in reports."""
        return "gripper" if self.gripper is not None else self.gripper_body


def resolve_cycle(
    spec: Cycle,
    base_dir: Path | None = None,
    mesh_resolver: MeshResolver | None = None,
    mesh_limits: MeshLimits | None = None,
) -> ResolvedCycle:
    """Load the robot and meshes of a cycle, make its poses and lines concrete, and check its geometry.

    Raises:
        InvalidInput: what :func:`~planner.scenario.resolve.resolve_scenario` refuses (robot, cabin, park);
            overlapping installed units (``installed``, naming both); a bay already occupied
            (``bay.pose``, naming the unit there); the unit on its dock overlapping its fixture
            (``dock.pose``); a degenerate line.
        InvalidMesh: a mesh file cannot be used (the field named).
    """
    park = spec.park.model_dump(exclude_none=True)
    base_spec = Scenario.model_validate(
        {
            "name": spec.name,
            "robot": spec.robot,
            **({"rail_length": spec.rail_length} if spec.rail_length is not None else {}),
            "cabin": spec.cabin.model_dump(),
            "start": park,
            "goal": park,
            "options": spec.options.model_dump(),
        }
    )
    base = resolve_scenario(base_spec, base_dir, mesh_resolver, mesh_limits)
    if base.robot.desc.stiffness is None:
        raise InvalidInput(
            f"robot: {spec.robot!r} has no stiffness data; a cycle models the spring-back at grasp and "
            "release",
            field="robot",
        )

    deviation: dict[str, float] = {}  # where -> the mesh's surface deviation [m] (STEP tessellation)

    def geometry(g: Geometry, where: str) -> tuple[tuple[float, float, float], Array, Any]:
        """(box size [m], T_frame_box, mesh or None) of a box or a mesh's oriented bounding box."""
        size = g.box_m()
        if size is not None:
            return size, np.eye(4), None
        assert g.mesh is not None
        source, _ = _mesh_source(g.mesh, f"{where}.mesh", base_dir, mesh_resolver, allow_reference=False)
        mesh = _load(source, g.mesh, f"{where}.mesh", units=g.units, pose=None, limits=mesh_limits)
        deviation[where] = float(mesh.surface_deviation_m)
        obb = PayloadGeometry.from_mesh_vertices(mesh.vertices)
        return obb.size, obb.T_payload_box, mesh

    installed = []
    for i, inst in enumerate(spec.installed):
        size, T_box, _ = geometry(inst, f"installed[{i}]")
        installed.append(Obstacle.box(f"unit {inst.id}", size, inst.pose.matrix() @ T_box))
    for i, a in enumerate(installed):
        for j in range(i):
            if _overlap(a, installed[j]):
                raise InvalidInput(
                    f"installed: {installed[j].name} (installed[{j}]) and {a.name} (installed[{i}]) overlap",
                    field="installed",
                    units=[installed[j].name, a.name],
                )

    u = spec.unit
    size, T_unit_box, _ = geometry(u, "unit")
    T_tool_unit = u.grasp.matrix()
    com = np.array(u.com if u.com is not None else (0.0, 0.0, 0.0), dtype=float)
    R_ub = T_unit_box[:3, :3]
    inertia: Array = (
        np.array(u.inertia, dtype=np.float64)
        if u.inertia is not None
        else R_ub @ box_inertia(u.mass, size) @ R_ub.T
    )
    unit = PayloadGeometry(
        size=size,
        T_tool_payload=T_tool_unit,
        T_payload_box=T_unit_box,
        mass=float(u.mass),
        com_payload=com,
        inertia_payload=inertia,
        source="box" if u.box is not None else str(u.mesh),
    )
    try:
        unit_payload = unit.rigid_payload()
    except InvalidInput as exc:
        raise InvalidInput(f"unit: {exc.message}", field="unit.inertia") from None

    gripper = None
    held = unit
    if spec.gripper is not None:
        T_tool_gripper = spec.gripper.pose.matrix()
        gripper = PayloadGeometry(size=spec.gripper.box_m(), T_tool_payload=T_tool_gripper, source="gripper")
        held = _containing(unit, gripper)

    T_dock = spec.dock.pose.matrix()
    T_bay = spec.bay.pose.matrix()
    fsize, T_fbox, fmesh = geometry(spec.dock.fixture, "dock.fixture")
    T_fixture = spec.dock.fixture.pose.matrix()
    name = f"unit {u.id}"
    if fmesh is not None:
        fixture = Obstacle(f"fixture of {u.id}", T_fixture, vertices=fmesh.vertices, faces=fmesh.faces)
    else:
        fixture = Obstacle.box(f"fixture of {u.id}", fsize, T_fixture @ T_fbox)
    dock_unit = Obstacle.box(name, size, T_dock @ T_unit_box)
    bay_unit = Obstacle.box(name, size, T_bay @ T_unit_box)
    for j, other in enumerate(installed):
        if _overlap(bay_unit, other):
            raise InvalidInput(
                f"bay.pose: the bay is occupied: {name} at its installed pose overlaps {other.name} "
                f"(installed[{j}])",
                field="bay.pose",
                units=[other.name, name],
            )
    if _overlap(dock_unit, fixture):
        raise InvalidInput(
            f"dock.pose: {name} on its dock is in collision with its fixture (move the dock pose or the "
            "fixture)",
            field="dock.pose",
        )
    for j, other in enumerate(installed):
        if _overlap(fixture, other) or _overlap(dock_unit, other):
            raise InvalidInput(
                f"dock: the dock (unit or fixture) overlaps {other.name} (installed[{j}])", field="dock"
            )

    base = _with_surface_deviation(base, deviation)
    return ResolvedCycle(
        spec=spec,
        base=base,
        installed=tuple(installed),
        unit=unit,
        held=held,
        gripper=gripper,
        unit_payload=unit_payload,
        T_tool_unit=T_tool_unit,
        T_base_unit_dock=T_dock,
        T_base_unit_bay=T_bay,
        fixture=fixture,
        dock_unit=dock_unit,
        bay_unit=bay_unit,
        grasp_line=_line(spec.dock.approach, "dock.approach"),
        lift_line=_line(spec.dock.lift, "dock.lift"),
        insertion_line=_line(spec.bay.approach, "bay.approach"),
        retract_line=_line(spec.retract, "retract"),
        park_u=base.start_u,
        park_q=base.start_q,
        grasp_dwell_s=float(spec.dwell.grasp_s),
        release_dwell_s=float(spec.dwell.release_s),
        sha256=cycle_hash(spec),
    )


def load_cycle(path: Path | str, mesh_resolver: MeshResolver | None = None) -> ResolvedCycle:
    """Read, validate and resolve a cycle file (YAML or JSON); relative mesh paths refer to its folder."""
    path = Path(path)
    spec = cycle_from_dict(read_document(path, "cycle"), source=str(path))
    return resolve_cycle(spec, base_dir=path.parent, mesh_resolver=mesh_resolver)


def _line(spec: LineSpec, where: str) -> Line:
    d = np.asarray(spec.direction, dtype=float)
    norm = float(np.linalg.norm(d))
    if not (np.all(np.isfinite(d)) and norm > 1e-9):
        raise InvalidInput(f"{where}.direction: must be a finite non-zero vector", field=f"{where}.direction")
    return Line(d / norm, float(spec.distance))


def _overlap(a: Obstacle, b: Obstacle) -> bool:
    """True when two obstacles touch or overlap (an FCL collision query)."""
    return bool(
        fcl.collide(a.collision_object(), b.collision_object(), fcl.CollisionRequest(), fcl.CollisionResult())
        > 0
    )


def _containing(unit: PayloadGeometry, gripper: PayloadGeometry) -> PayloadGeometry:
    """The unit's payload grown to the box, in the unit's box frame, that contains the gripper too.

    Inertia, mass and centre of mass stay the unit's (given explicitly: the grown box's default inertia
    would be another body's).
    """
    T_tool_box = unit.T_tool_box
    T_box_tool = np.linalg.inv(T_tool_box)
    corners = []
    for g in (unit, gripper):
        h = 0.5 * np.array(g.size)
        T = T_box_tool @ g.T_tool_box
        corners.append((BOX_CORNER_SIGNS * h) @ T[:3, :3].T + T[:3, 3])
    pts = np.vstack(corners)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    T_shift = np.eye(4)
    T_shift[:3, 3] = 0.5 * (lo + hi)
    assert unit.inertia_payload is not None
    return PayloadGeometry(
        size=tuple(float(x) for x in (hi - lo)),  # type: ignore[arg-type]
        T_tool_payload=unit.T_tool_payload,
        T_payload_box=unit.T_payload_box @ T_shift,
        mass=unit.mass,
        com_payload=unit.com_payload,
        inertia_payload=unit.inertia_payload,
        source=f"{unit.source} with the gripper",
    )


def _with_surface_deviation(base: ResolvedScenario, deviation: dict[str, float]) -> ResolvedScenario:
    """``base`` with its certified clearance raised to cover the unit's and the obstacles' mesh files.

    A tessellated (STEP) surface may lie inside the exact one by up to its ``surface_deviation_m``, as
    :func:`~planner.scenario.resolve.resolve_scenario` adds for the cabin and payload files. Any two surfaces
    compared here are the unit's (held, or installed) and one environment surface (the cabin, an installed
    unit or the fixture), so the clearance gains the unit's deviation plus the largest environment one (the
    cabin's is already in ``base``). ``deviation`` maps the cycle field of each mesh to its deviation [m].
    """
    unit_m = deviation.get("unit", 0.0)
    environment_m = max((d for where, d in deviation.items() if where != "unit"), default=0.0)
    extra = unit_m + max(0.0, environment_m - base.surface_deviation_m)
    if extra <= 0.0:
        return base
    options = base.options.model_copy(update={"clearance_m": float(base.options.clearance_m) + extra})
    return dataclasses.replace(base, options=options, surface_deviation_m=base.surface_deviation_m + extra)
