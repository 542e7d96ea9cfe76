"""Scenario resolution: a :class:`~planner.scenario.schema.Scenario` made concrete.

:func:`resolve_scenario` turns a scenario into a :class:`ResolvedScenario`: the robot model, the loaded
cabin mesh, the payload geometry, drive *and* joint vectors of the start and goal, and the goal pose
converted from the payload frame to the tool frame. Names that depend on the robot (drive and joint names)
and on the file system (meshes) are checked here. :func:`load_scenario` reads, validates and resolves a file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.collision.obstacles import Obstacle
from planner.collision.world import DEFAULT_SELF_CLEARANCE_M, CollisionWorld
from planner.core.exceptions import InvalidInput, InvalidMesh, OutsideWorkspace, UnknownRobot
from planner.core.types import Array
from planner.meshes import reference_cabin_path, reference_cabins
from planner.meshio.load import LoadedMesh, MeshLimits, load_mesh
from planner.robots import load_robot
from planner.robots.cabin8 import Cabin8
from planner.scenario.files import load_scenario_file
from planner.scenario.schema import PayloadSpec, PlanOptions, Scenario, scenario_hash

log = logging.getLogger(__name__)

#: Maps a mesh name from a scenario to stored content (a path or the file's bytes), or returns ``None`` to
#: fall back to the default resolution (reference cabin, then a file path). It may raise
#: `InvalidInput` to refuse a name outright (e.g. to forbid file-system paths
#: in the HTTP API). Bytes are parsed in the format of the name's extension.
MeshResolver = Callable[[str], Path | bytes | None]


# ------------------------------------------------------------------------------------------ resolution


@dataclass(frozen=True)
class ResolvedScenario:
    """A scenario made concrete: robot model, loaded geometry, and start/goal as vectors and transforms.

    Every array is read-only. Drive vectors ``u`` and joint vectors ``q`` are (8,) in the robot's drive and
    joint order (m, rad).

    Attributes:
        spec: The validated scenario as given.
        robot: The robot model (rail length applied).
        cabin: The cabin mesh in the base frame, or ``None`` for free space.
        cabin_source: Reference cabin name, resolver name or file path of the cabin; ``"none"`` without.
        payload: Payload geometry and inertia, or ``None``.
        start_u: Start drive positions, (8,).
        start_q: Start joint coordinates, (8,).
        goal_u: Goal drive positions (8,) for drives/joints goals, else ``None``.
        goal_q: Goal joint coordinates (8,) for drives/joints goals, else ``None``.
        T_base_payload_goal: Pose goal: the payload frame in the base frame as given (4x4), else ``None``.
        T_base_tool_goal: Pose goal in the tool frame, ``T_base_payload_goal @ inv(T_tool_payload)``
            (4x4; equal to the payload goal without a payload), else ``None``.
        approach_direction: Unit direction (3,) of the final straight motion in the base frame, or ``None``.
        approach_distance_m: Length of that motion [m]; 0.0 without an approach.
        options: Planning options: the scenario's, with ``clearance_m`` raised by
            ``surface_deviation_m`` (what every stage and the gate certify against the loaded triangles).
        scenario_sha256: :func:`scenario_hash` of ``spec``.
        obstacles: The cabin state: fixed bodies added to the cabin (installed units, fixtures), each
            compared by clearance like the cabin (:mod:`planner.collision.obstacles`); () for a scenario.
        allowed_pairs: ``(body, obstacle)`` pairs this plan may bring within the clearance (a cycle's
            grasp and release lines, :mod:`planner.task`); empty for a scenario.
        surface_deviation_m: How much closer the exact surfaces of the cabin and payload files may be than
            their loaded triangles [m]: the sum of both meshes' ``surface_deviation_m`` (a STEP file's
            tessellation tolerance plus float32 rounding; 0 for triangle files and box payloads).
        payload_mesh: The payload's loaded mesh (its file hash goes into the provenance), or ``None``.
        gate_collision: Whether the plan's own gate certifies the clearance (its ``collision`` check and
            figure). False only for a cycle's legs inside :func:`planner.task.cycle.plan_cycle`, whose
            cycle gate certifies the same samples in the same world, with the same clearance and margin
            (:func:`planner.gate.cycle.validate_cycle`); True for every scenario a user gives.
        deflection_series: Whether the plan predicts the deflection along its profile (the report's
            ``deflection`` and :attr:`~planner.plan.pipeline.PlanResult.deflection`). False only for a
            cycle's legs, whose results keep neither (the cycle gate predicts each leg's sag itself).
    """

    spec: Scenario
    robot: Cabin8
    cabin: LoadedMesh | None
    cabin_source: str
    payload: PayloadGeometry | None
    start_u: Array = field(repr=False)
    start_q: Array = field(repr=False)
    goal_u: Array | None = field(repr=False)
    goal_q: Array | None = field(repr=False)
    T_base_payload_goal: Array | None = field(repr=False)
    T_base_tool_goal: Array | None = field(repr=False)
    approach_direction: Array | None = field(repr=False)
    approach_distance_m: float
    options: PlanOptions
    scenario_sha256: str
    obstacles: tuple[Obstacle, ...] = ()
    allowed_pairs: frozenset[tuple[str, str]] = frozenset()
    surface_deviation_m: float = 0.0
    payload_mesh: LoadedMesh | None = field(default=None, repr=False)
    gate_collision: bool = True
    deflection_series: bool = True

    def world(self, self_clearance: float = DEFAULT_SELF_CLEARANCE_M) -> CollisionWorld:
        """The collision world of this scenario: robot, payload, cabin and its obstacles.

        ``self_clearance``: what non-adjacent bodies keep from each other [m] in the world's checks (the
        planner's world keeps more than the gate certifies: ``PLANNER_SELF_SLACK_M``).
        """
        return CollisionWorld(
            self.robot,
            self.cabin,
            self.payload,
            self_clearance=self_clearance,
            obstacles=self.obstacles,
            allowed=self.allowed_pairs,
        )

    @property
    def requested_clearance_m(self) -> float:
        """The clearance the scenario asked for [m] (``options.clearance_m`` adds the surface deviation)."""
        return float(self.spec.options.clearance_m)

    def clearance_report(self) -> dict[str, Any]:
        """How the certified clearance was chosen: requested, the meshes' surface deviation, certified [m].

        ``{"requested_m", "surface_deviation_m", "certified_m", "note"}``: the gate certifies
        ``certified_m`` against the loaded triangles, so the exact CAD surfaces keep ``requested_m``.
        """
        dev = self.surface_deviation_m
        if dev > 0.0:
            note = (
                f"the tessellated STEP surfaces may lie up to {dev * 1e3:.4g} mm inside the exact ones: "
                f"added to the requested {self.requested_clearance_m * 1e3:.4g} mm, so the exact surfaces "
                "keep the requested clearance"
            )
        else:
            note = "the meshes are the surfaces (no tessellation): certified = requested"
        return {
            "requested_m": self.requested_clearance_m,
            "surface_deviation_m": dev,
            "certified_m": float(self.options.clearance_m),
            "note": note,
        }

    def __post_init__(self) -> None:
        for name in (
            "start_u",
            "start_q",
            "goal_u",
            "goal_q",
            "T_base_payload_goal",
            "T_base_tool_goal",
            "approach_direction",
        ):
            value = getattr(self, name)
            if value is not None:
                value = np.array(value, dtype=np.float64)
                value.flags.writeable = False
                object.__setattr__(self, name, value)


def resolve_scenario(
    spec: Scenario,
    base_dir: Path | None = None,
    mesh_resolver: MeshResolver | None = None,
    mesh_limits: MeshLimits | None = None,
    robot_description_files: bool = False,
) -> ResolvedScenario:
    """Load the robot and meshes of a scenario and turn its start and goal into vectors and transforms.

    Mesh names resolve in this order: ``mesh_resolver(name)`` (if given and not ``None``), a reference
    cabin name (cabins only, see :mod:`meshes`), then a file path relative to ``base_dir`` (the current
    directory if ``None``). Start and goal limits are *not* checked here (the planner refuses them with its
    own reasons); names, completeness and the parallel stage's workspace are.

    Args:
        spec: The validated scenario.
        base_dir: Folder that relative mesh paths refer to (normally the scenario file's folder).
        mesh_resolver: Optional hook mapping a mesh name to stored content (HTTP API).
        mesh_limits: Caps applied when loading meshes (default :class:`MeshLimits` ()).
        robot_description_files: Whether ``robot_description`` may name a file (relative to ``base_dir``);
            only the CLI allows it (a service must not read its own files on a request's word).

    Returns:
        The resolved scenario.

    Raises:
        InvalidInput: unknown robot, unresolvable mesh name, unknown/missing drive or joint names, a start
            or goal outside the parallel stage's workspace, or unrealisable payload inertia; the message
            and ``details['field']`` name the field.
        InvalidMesh: a mesh file cannot be used (message prefixed with the field, e.g. ``cabin.mesh: ``).
    """
    robot = _robot(spec, base_dir, robot_description_files)
    if spec.options.compensate_deflection and robot.desc.stiffness is None:
        raise InvalidInput(
            f"options.compensate_deflection: robot {robot.name!r} has no stiffness data",
            field="options.compensate_deflection",
        )
    cabin: LoadedMesh | None = None
    cabin_source = "none"
    if spec.cabin is not None:
        source, cabin_source = _mesh_source(
            spec.cabin.mesh, "cabin.mesh", base_dir, mesh_resolver, allow_reference=True
        )
        cabin = _load(
            source,
            spec.cabin.mesh,
            "cabin.mesh",
            units=spec.cabin.units,
            pose=spec.cabin.pose.matrix(),
            limits=mesh_limits,
            tolerance_m=spec.cabin.tessellation_tolerance_m,
        )
    payload, payload_mesh = (
        _payload(spec.payload, base_dir, mesh_resolver, mesh_limits) if spec.payload else (None, None)
    )
    # Cabin and payload surfaces may each be closer than their triangles: the distance between them by
    # up to the sum. The clearance every stage certifies is raised by it (the report says so).
    deviation = sum(m.surface_deviation_m for m in (cabin, payload_mesh) if m is not None)
    options = spec.options
    if deviation > 0.0:
        options = options.model_copy(update={"clearance_m": float(options.clearance_m) + deviation})

    start_u, start_q = _configuration(robot, spec.start.drives, spec.start.joints, "start")
    goal = spec.goal
    goal_u = goal_q = T_base_payload = T_base_tool = direction = None
    distance_m = 0.0
    if goal.pose is None:
        goal_u, goal_q = _configuration(robot, goal.drives, goal.joints, "goal")
    else:
        T_base_payload = goal.pose.matrix()
        T_tool_payload = payload.T_tool_payload if payload is not None else np.eye(4)
        T_base_tool = T_base_payload @ _rigid_inverse(T_tool_payload)
        if goal.approach is not None:
            d = np.asarray(goal.approach.direction, dtype=float)
            norm = float(np.linalg.norm(d))
            if not (np.all(np.isfinite(d)) and norm > 1e-9):
                raise InvalidInput(
                    f"goal.approach.direction: must be a finite non-zero vector, got {d.tolist()}",
                    field="goal.approach.direction",
                )
            direction = d / norm
            distance_m = float(goal.approach.distance)

    log.debug("resolved scenario %r (cabin %s)", spec.name, cabin_source)
    return ResolvedScenario(
        spec=spec,
        robot=robot,
        cabin=cabin,
        cabin_source=cabin_source,
        payload=payload,
        start_u=start_u,
        start_q=start_q,
        goal_u=goal_u,
        goal_q=goal_q,
        T_base_payload_goal=T_base_payload,
        T_base_tool_goal=T_base_tool,
        approach_direction=direction,
        approach_distance_m=distance_m,
        options=options,
        scenario_sha256=scenario_hash(spec),
        surface_deviation_m=deviation,
        payload_mesh=payload_mesh,
    )


def load_scenario(path: Path, mesh_resolver: MeshResolver | None = None) -> ResolvedScenario:
    """Read, validate and resolve a scenario file; relative mesh paths refer to the file's folder."""
    path = Path(path)
    return resolve_scenario(
        load_scenario_file(path),
        base_dir=path.parent,
        mesh_resolver=mesh_resolver,
        robot_description_files=True,
    )


def _robot(spec: Scenario, base_dir: Path | None = None, files: bool = False) -> Cabin8:
    if spec.robot_description is not None:
        if not files:
            raise InvalidInput(
                "robot_description: description files are read by the CLI only (cabinplan plan)",
                field="robot_description",
            )
        path = Path(spec.robot_description)
        if not path.is_absolute():
            path = (base_dir if base_dir is not None else Path.cwd()) / path
        if not path.is_file():
            raise InvalidInput(f"robot_description: no such file {path}", field="robot_description")
        described = Cabin8(path, rail_length=spec.rail_length)
        if described.name != spec.robot:
            raise InvalidInput(
                f"robot_description: the file describes {described.name!r}, the scenario's robot is "
                f"{spec.robot!r}",
                field="robot_description",
            )
        return described
    try:
        robot = load_robot(spec.robot, spec.rail_length)
    except UnknownRobot as exc:
        raise UnknownRobot(exc.message, field="robot", **exc.details) from None
    if not isinstance(robot, Cabin8):
        raise InvalidInput(
            f"robot: scenarios support cabin8-type robots only, got {spec.robot!r} ({robot.kind})",
            field="robot",
        )
    return robot


def _mesh_source(
    name: str,
    field_name: str,
    base_dir: Path | None,
    resolver: MeshResolver | None,
    *,
    allow_reference: bool,
) -> tuple[Path | bytes, str]:
    """(what to load, provenance label) of a mesh name; see :func:`resolve_scenario` for the order."""
    if resolver is not None:
        found = resolver(name)
        if found is not None:
            return found, name
    if allow_reference:
        reference = reference_cabin_path(name)
        if reference is not None:
            return reference, reference.stem
    path = Path(name)
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    if path.is_file():
        return path, str(path)
    hint = f" nor a reference cabin ({', '.join(reference_cabins())})" if allow_reference else ""
    raise InvalidInput(
        f"{field_name}: {name!r} is neither an existing file (looked for {path}){hint}",
        field=field_name,
        path=str(path),
    )


def _load(
    source: Path | bytes,
    name: str,
    field_name: str,
    *,
    units: Literal["m", "mm"],
    pose: Array | None,
    limits: MeshLimits | None,
    tolerance_m: float | None = None,
) -> LoadedMesh:
    """:func:`load_mesh` with the scenario field named in any :class:`InvalidMesh` message."""
    try:
        return load_mesh(
            source,
            units=units,
            name=Path(name).name,
            pose=pose,
            limits=limits,
            tessellation_tolerance_m=tolerance_m,
        )
    except InvalidMesh as exc:
        if exc.message.startswith(f"{field_name}:"):
            raise
        details = {k: v for k, v in exc.details.items() if k != "field"}
        raise InvalidMesh(f"{field_name}: {exc.message}", field=field_name, **details) from exc


def _payload(
    spec: PayloadSpec,
    base_dir: Path | None,
    resolver: MeshResolver | None,
    limits: MeshLimits | None,
) -> tuple[PayloadGeometry, LoadedMesh | None]:
    """Payload geometry of a box or mesh payload (and its mesh), with its inertial data validated."""
    kwargs: dict[str, Any] = {
        "T_tool_payload": spec.grasp.matrix(),
        "mass": float(spec.mass),
        "com_payload": np.array(spec.com if spec.com is not None else (0.0, 0.0, 0.0), dtype=float),
        "inertia_payload": np.array(spec.inertia, dtype=float) if spec.inertia is not None else None,
    }
    mesh: LoadedMesh | None = None
    if spec.box is not None:
        payload = PayloadGeometry(size=spec.box, source="box", **kwargs)
    else:
        assert spec.mesh is not None  # the schema guarantees exactly one of box and mesh
        source, _ = _mesh_source(spec.mesh, "payload.mesh", base_dir, resolver, allow_reference=False)
        mesh = _load(
            source,
            spec.mesh,
            "payload.mesh",
            units=spec.units,
            pose=None,
            limits=limits,
            tolerance_m=spec.tessellation_tolerance_m,
        )
        try:
            payload = PayloadGeometry.from_mesh_vertices(mesh.vertices, source=spec.mesh, **kwargs)
        except InvalidInput as exc:
            if exc.details.get("field") != "payload.box":
                raise
            raise InvalidInput(
                f"payload.mesh: the mesh's oriented bounding box is degenerate ({exc.message}); "
                "a payload needs a volume",
                field="payload.mesh",
            ) from exc
    try:
        payload.rigid_payload()  # raises InvalidInput naming payload.mass / payload.com / payload.inertia
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InvalidInput(f"payload.inertia: {exc}", field="payload.inertia") from exc
    return payload, mesh


def _configuration(
    robot: Cabin8,
    drives: dict[str, float] | None,
    joints: dict[str, float] | None,
    prefix: str,
) -> tuple[Array, Array]:
    """(u, q) of a configuration given by drives or by joints; checks names and the stage workspace."""
    if drives is not None:
        where = f"{prefix}.drives"
        u = robot.drives_from_dict(dict(drives), field=where)
        return u, _in_workspace(robot.joints_from_drives, u, where, "the stage sliders do not assemble")
    assert joints is not None  # the schema guarantees exactly one of drives and joints
    where = f"{prefix}.joints"
    q = robot.joints_from_dict(dict(joints), field=where)
    u = _in_workspace(robot.drives_from_joints, q, where, "no slider positions reach this platform pose")
    return u, q


def _in_workspace(to_other: Callable[[Array], Array], x: Array, where: str, what: str) -> Array:
    """``to_other(x)`` (drives <-> joints); outside the stage's workspace, InvalidInput naming ``where``."""
    try:
        return to_other(x)
    except OutsideWorkspace as exc:
        raise InvalidInput(
            f"{where}: outside the parallel stage's workspace, {what}: {exc.message}",
            field=where,
            condition=exc.details.get("condition"),
        ) from exc


def _rigid_inverse(T: Array) -> Array:
    """Inverse of a rigid 4x4 transform: (R, p) -> (R^T, -R^T p)."""
    R, p = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ p
    return out


__all__ = ["MeshResolver", "ResolvedScenario", "load_scenario", "resolve_scenario"]
