"""Scenario files: the public input contract of the planner (schema, loading, resolution).

A *scenario* names the robot, the cabin (a mesh in the base frame), the payload and its grasp, the start
configuration, the goal (a drive/joint configuration or a payload pose with an optional straight-line
approach) and the planning options. It arrives as a YAML or JSON file (CLI) or as a dict (HTTP API), in SI
units: lengths in metres, angles in radians, masses in kilograms, quaternions as explicit ``{w, x, y, z}``.
Mesh files may declare millimetres; they are converted once, on load.

Two steps, kept apart so that the schema stays pure and the HTTP API can reuse it:

1. :func:`scenario_from_dict` / :func:`load_scenario_file` validate the *shape* of the input into a frozen
   :class:`Scenario` (pydantic, ``extra="forbid"`` everywhere: unknown fields are errors). Every failure
   is an :class:`~planner.exceptions.InvalidInput` whose message names the offending field as a dotted
   path, e.g. ``options.clearance_m: Input should be greater than 0``.
2. :func:`resolve_scenario` turns a :class:`Scenario` into a :class:`ResolvedScenario`: the robot model,
   the loaded cabin mesh, the payload geometry, drive *and* joint vectors of the start and goal, and the
   goal pose converted from the payload frame to the tool frame. Names that depend on the robot (drive and
   joint names) and on the file system (meshes) are checked here.

Frames: ``T_a_b`` is frame b expressed in frame a (4x4). The cabin pose is ``T_base_cabin``, the grasp is
``T_tool_payload`` and a pose goal is ``T_base_payload``; the tool goal follows as
``T_base_tool = T_base_payload @ inv(T_tool_payload)``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import stat
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import (
    AliasChoices,
    AllowInfNan,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import ErrorDetails

from meshes import reference_cabin_path, reference_cabins
from planner.collision.bodies import PayloadGeometry
from planner.collision.mesh_loader import LoadedMesh, MeshLimits, load_mesh
from planner.dynamics.payload import RigidPayload
from planner.exceptions import InvalidInput, InvalidMesh, OutsideWorkspace, UnknownRobot
from planner.robots import load_robot
from planner.robots.cabin8 import Cabin8
from planner.schemas import Pose

_LOG = logging.getLogger(__name__)

Array = NDArray[np.float64]

#: Largest accepted scenario file [bytes] (1 MiB), checked before the file is read.
MAX_SCENARIO_BYTES = 1 << 20

#: File extensions :func:`load_scenario_file` accepts (lower case, with the dot).
SCENARIO_EXTENSIONS: tuple[str, ...] = (".yaml", ".yml", ".json")

#: A finite real number: ints and floats only (no numeric strings, no booleans, no NaN/inf).
#:
#: Stricter than :data:`planner.schemas.Finite` (lax: accepts ``"0.3"`` and ``true``) and checked *before*
#: any bound, so ``.nan`` is reported as "not finite" rather than as "not <= 0.2"; bounds added to it also
#: land in the JSON schema as standard ``exclusiveMinimum``/``maximum`` keys.
Number = Annotated[float, Strict(), AllowInfNan(False)]
PositiveNumber = Annotated[Number, Field(gt=0.0)]
#: Bounds of absurd values, so that they are invalid input naming their field rather than reaching the
#: planner (a 1e308 kg payload would overflow the force checks and come back as a refusal): beyond any
#: payload or cabin of these robots, by orders of magnitude.
MAX_PAYLOAD_MASS_KG = 10_000.0
MAX_BOX_SIDE_M = 50.0
#: Largest seed, the same everywhere a seed is accepted (OMPL's and numpy's RNG take 32-bit seeds).
MAX_SEED = 2**31 - 1
BoxSide = Annotated[Number, Field(gt=0.0, le=MAX_BOX_SIDE_M)]
Vector3 = tuple[Number, Number, Number]
Matrix3 = tuple[Vector3, Vector3, Vector3]

#: OMPL geometric planners the planning adapter can run (``planner.planning.ompl_adapter.PLANNERS``;
#: a test keeps the two lists equal).
PlannerName = Literal["RRTConnect", "RRT", "RRTstar", "AORRTC"]

#: Maps a mesh name from a scenario to stored content (a path or the file's bytes), or returns ``None`` to
#: fall back to the default resolution (reference cabin, then a file path). It may raise
#: :class:`~planner.exceptions.InvalidInput` to refuse a name outright (e.g. to forbid file-system paths
#: in the HTTP API). Bytes are parsed in the format of the name's extension.
MeshResolver = Callable[[str], Path | bytes | None]

_IDENTITY_POSE = Pose(position=(0.0, 0.0, 0.0))
_MODEL_CONFIG = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


# ------------------------------------------------------------------------------------------------- schema


class CabinSpec(BaseModel):
    """The cabin: a triangle mesh placed in the robot base frame."""

    model_config = _MODEL_CONFIG

    mesh: str = Field(
        min_length=1,
        max_length=1000,
        description="Reference cabin name (e.g. 'cabin-aisle', with or without '.stl') or a mesh file path "
        "(STL, OBJ, PLY, GLB, glTF) relative to the scenario file.",
    )
    units: Literal["m", "mm"] = Field("m", description="Length unit of the mesh file's coordinates.")
    pose: Pose = Field(
        _IDENTITY_POSE, description="T_base_cabin: the mesh frame in the robot base frame (position in m)."
    )


class PayloadSpec(BaseModel):
    """The carried object: a box or a mesh (covered by its oriented bounding box), inertia and grasp."""

    model_config = _MODEL_CONFIG

    box: tuple[BoxSide, BoxSide, BoxSide] | None = Field(
        None,
        description="Box size [x, y, z] in m (each at most 50), centred on the payload frame. Exclusive "
        "with mesh.",
    )
    mesh: str | None = Field(
        None,
        min_length=1,
        max_length=1000,
        description="Payload mesh file relative to the scenario file, coordinates in the payload frame; "
        "collision checks use its oriented bounding box. Exclusive with box.",
    )
    units: Literal["m", "mm"] = Field("m", description="Length unit of the mesh file (box sizes are in m).")
    mass: Number = Field(
        0.0, ge=0.0, le=MAX_PAYLOAD_MASS_KG, description="Payload mass in kg (at most 10 000)."
    )
    com: Vector3 | None = Field(
        None, description="Centre of mass in the payload frame, in m (default: the payload frame origin)."
    )
    inertia: Matrix3 | None = Field(
        None,
        description="Inertia about the centre of mass in payload axes, kg m^2, 3x3 symmetric positive "
        "semi-definite with realisable principal moments (default: a uniform solid box of the payload).",
    )
    grasp: Pose = Field(
        _IDENTITY_POSE, description="T_tool_payload: the payload frame in the tool frame (position in m)."
    )

    @field_validator("inertia")
    @classmethod
    def _realisable_inertia(cls, value: Matrix3 | None) -> Matrix3 | None:
        if value is not None:
            _check_inertia(np.array(value, dtype=float))
        return value

    @model_validator(mode="after")
    def _box_or_mesh(self) -> PayloadSpec:
        if (self.box is None) == (self.mesh is None):
            got = "both" if self.box is not None else "neither"
            raise ValueError(f"exactly one of box or mesh is required, got {got}")
        if self.box is not None and self.units != "m":
            raise ValueError("units applies to a mesh payload only; box sizes are always in m")
        return self


class ConfigurationSpec(BaseModel):
    """A robot configuration by drive positions or by joint coordinates (exactly one)."""

    model_config = _MODEL_CONFIG

    drives: dict[str, Number] | None = Field(
        None, description="Every drive by name -> position (m for prismatic, rad for revolute drives)."
    )
    joints: dict[str, Number] | None = Field(
        None, description="Every joint coordinate by name -> value (m or rad)."
    )

    @model_validator(mode="after")
    def _exactly_one(self) -> ConfigurationSpec:
        given = [n for n in ("drives", "joints") if getattr(self, n) is not None]
        if len(given) != 1:
            raise ValueError(f"exactly one of drives or joints is required, got {_got(given)}")
        return self


class ApproachSpec(BaseModel):
    """A final straight-line motion of the payload onto its goal pose (e.g. inserting into a bay)."""

    model_config = _MODEL_CONFIG

    direction: Vector3 = Field(
        description="Direction of the final motion in the base frame (any non-zero length; normalised)."
    )
    distance: Number = Field(gt=0.0, le=1.0, description="Length of the straight final motion in m.")

    @field_validator("direction")
    @classmethod
    def _non_zero(cls, value: Vector3) -> Vector3:
        if not float(np.linalg.norm(value)) > 1e-9:
            raise ValueError("must be a non-zero vector")
        return value


class GoalSpec(BaseModel):
    """The goal: drive positions, joint coordinates, or a payload pose (exactly one)."""

    model_config = _MODEL_CONFIG

    drives: dict[str, Number] | None = Field(None, description="Every drive by name -> position (m or rad).")
    joints: dict[str, Number] | None = Field(None, description="Every joint by name -> value (m or rad).")
    pose: Pose | None = Field(
        None,
        description="T_base_payload: the payload frame in the base frame (the tool frame if no payload).",
    )
    approach: ApproachSpec | None = Field(
        None, description="Optional straight final motion onto the goal pose (pose goals only)."
    )

    @field_validator("pose")
    @classmethod
    def _explicit_orientation(cls, value: Pose | None) -> Pose | None:
        # A goal the payload must reach is never silently "unrotated": the orientation is part of it.
        if value is not None and "orientation" not in value.model_fields_set:
            raise ValueError("a goal pose needs its orientation {w, x, y, z} (the identity is [1, 0, 0, 0])")
        return value

    @field_validator("approach")
    @classmethod
    def _approach_needs_pose(cls, value: ApproachSpec | None, info: ValidationInfo) -> ApproachSpec | None:
        if value is not None and info.data.get("pose") is None:
            raise ValueError("only allowed with a pose goal")
        return value

    @model_validator(mode="after")
    def _exactly_one(self) -> GoalSpec:
        given = [n for n in ("drives", "joints", "pose") if getattr(self, n) is not None]
        if len(given) != 1:
            raise ValueError(f"exactly one of drives, joints or pose is required, got {_got(given)}")
        return self


class PlanOptions(BaseModel):
    """Planning options (all optional)."""

    model_config = _MODEL_CONFIG

    clearance_m: Number = Field(
        0.01,
        gt=0.0,
        le=0.2,
        validation_alias=AliasChoices("clearance_m", "clearance"),
        description="Minimum distance in m between the robot (with payload) and the cabin, and between "
        "non-adjacent robot bodies. Input key 'clearance' is accepted as an alias.",
    )
    time_limit_s: Number = Field(30.0, gt=0.0, le=600.0, description="Planning time budget in s.")
    seed: int = Field(
        0, ge=0, le=MAX_SEED, strict=True, description="Random seed; the same seed gives the same plan."
    )
    sample_period_s: Number = Field(
        0.004,
        ge=0.0005,
        le=0.05,
        description="Controller period in s at which the profile is sampled (at most 50 ms: over longer "
        "samples the time law changes within a sample and its positions no longer integrate exactly).",
    )
    planner: PlannerName = Field("RRTConnect", description="OMPL geometric planner of the global search.")
    motion_margin_m: Number = Field(
        0.005,
        ge=1e-4,
        le=0.05,
        description="Certified motion checks: clearance given up between checked states, in m.",
    )
    simplify: bool = Field(
        True,
        description="Shortcut the path and blend its corners; false keeps the raw planner path "
        "(the naive benchmark baseline).",
    )
    approach_step_m: Number = Field(
        0.005, ge=0.001, le=0.05, description="Step in m along the straight approach motion."
    )
    compensate_deflection: bool | None = Field(
        None,
        description="Pose goals: command the pose whose predicted static deflection (stiffness model, "
        "payload and link weights) lands the payload on the requested pose within 0.01 mm and 1e-5 rad. "
        "Default (null): true when a payload is given.",
    )

    @model_validator(mode="before")
    @classmethod
    def _one_clearance_key(cls, data: Any) -> Any:
        if isinstance(data, dict) and "clearance" in data and "clearance_m" in data:
            raise ValueError("give clearance_m or its alias clearance, not both")
        return data


class Scenario(BaseModel):
    """One planning request: robot, cabin, payload, start, goal and options (SI units)."""

    model_config = _MODEL_CONFIG

    name: str = Field(
        min_length=1,
        max_length=100,
        pattern=r"^[A-Za-z0-9._-]+$",
        description="Scenario name: letters, digits, '.', '_' and '-'.",
    )
    robot: str = Field("cabin8", min_length=1, max_length=100, description="Registry name of the robot.")
    rail_length: Annotated[Number, Field(gt=0.0, le=50.0)] | None = Field(
        None, description="Rail length in m; replaces the upper limit of drive d1 (default: the model's)."
    )
    cabin: CabinSpec | None = Field(None, description="The cabin mesh; omitted = free space.")
    payload: PayloadSpec | None = Field(None, description="The carried payload; omitted = none.")
    start: ConfigurationSpec = Field(description="Start configuration.")
    goal: GoalSpec = Field(description="Goal configuration or payload pose.")
    options: PlanOptions = Field(default_factory=PlanOptions, description="Planning options.")


def _got(given: list[str]) -> str:
    return "none" if not given else " and ".join(given)


def _check_inertia(inertia: Array) -> None:
    """Raise ValueError unless the inertia is symmetric, PSD and realisable (the RigidPayload rules)."""
    try:
        RigidPayload(0.0, np.zeros(3), inertia)
    except InvalidInput as exc:
        raise ValueError(exc.message.removeprefix("payload.inertia: ")) from None


# ------------------------------------------------------------------------------------- parse and load


def scenario_from_dict(data: object, source: str = "scenario") -> Scenario:
    """Validate a parsed scenario (a mapping, e.g. from YAML/JSON or an HTTP body).

    Args:
        data: The parsed document; its top level must be a mapping.
        source: Where the data came from (file path or ``"scenario"``), recorded in the error details.

    Returns:
        The validated, frozen scenario.

    Raises:
        InvalidInput: the data does not match the schema. The message names the first offending field
            as a dotted path and the reason (``"options.clearance_m: Input should be greater than 0"``);
            ``details`` has ``field``, ``source`` and ``errors`` (every error as ``{field, message}``).
    """
    if isinstance(data, Scenario):
        return data
    if not isinstance(data, dict):
        kind = "nothing (empty document)" if data is None else type(data).__name__
        raise InvalidInput(
            f"scenario: expected a mapping of fields at the top level, got {kind}",
            field="scenario",
            source=source,
        )
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        errors = [_describe(e) for e in exc.errors(include_url=False, include_input=False)]
        first = errors[0]
        raise InvalidInput(
            f"{first['field']}: {first['message']}", field=first["field"], source=source, errors=errors
        ) from None


def _describe(error: ErrorDetails) -> dict[str, str]:
    """``{field, message}`` of one pydantic error: dotted path (``payload.box[1]``) and a plain reason."""
    path = ""
    for part in error["loc"]:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    message = error["msg"]
    for prefix in ("Value error, ", "Assertion failed, "):
        message = message.removeprefix(prefix)
    if error["type"] == "extra_forbidden":
        message = "unknown field (not part of the scenario schema)"
    elif error["type"] == "missing":
        loc = error["loc"]
        message = (
            "missing value (too few items)"
            if loc and isinstance(loc[-1], int)
            else "required field is missing"
        )
    return {"field": path or "scenario", "message": message}


class _ScenarioYamlLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys and reads YAML 1.2 floats such as ``1e-3``."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=False)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping",
                    node.start_mark,
                    f"found duplicate key {key!r}",
                    key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# PyYAML implements YAML 1.1, where 1e-3 (no dot) is a string; accept it as the number users mean.
_ScenarioYamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _unique_json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def load_scenario_file(path: Path) -> Scenario:
    """Read and validate a scenario file (``.yaml``/``.yml`` or ``.json``, at most 1 MiB).

    Relative mesh paths in the scenario refer to the file's folder: pass ``path.parent`` as ``base_dir``
    to :func:`resolve_scenario` (or use :func:`load_scenario`).

    Args:
        path: The scenario file.

    Returns:
        The validated scenario.

    Raises:
        InvalidInput: wrong extension, missing/unreadable/oversized file, not UTF-8, a syntax error (the
            message gives line and column) or a duplicate key, or a schema violation (see
            :func:`scenario_from_dict`). ``details['field']`` is ``"scenario"`` for file-level problems.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in SCENARIO_EXTENSIONS:
        raise InvalidInput(
            f"scenario: unsupported file extension {ext or '(none)'!r} of {path.name!r}; "
            f"expected one of {', '.join(SCENARIO_EXTENSIONS)}",
            field="scenario",
            file=str(path),
        )
    text = _read_text(path)
    data: object
    try:
        if ext == ".json":
            data = json.loads(text, object_pairs_hook=_unique_json_object)
        else:
            data = yaml.load(text, Loader=_ScenarioYamlLoader)  # a SafeLoader subclass
    except json.JSONDecodeError as exc:
        raise _file_error(path, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        why = " ".join(str(exc.problem or exc.context or "syntax error").split())
        raise _file_error(path, f"invalid YAML{where}: {why}") from None
    except yaml.YAMLError as exc:
        raise _file_error(path, f"invalid YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise _file_error(path, "the document is nested too deeply") from None
    except ValueError as exc:  # duplicate JSON key
        raise _file_error(path, f"invalid JSON: {exc}") from None
    return scenario_from_dict(data, source=str(path))


def _file_error(path: Path, why: str) -> InvalidInput:
    return InvalidInput(f"scenario: {path.name}: {why}", field="scenario", file=str(path))


def _read_text(path: Path) -> str:
    """The file's text (UTF-8), refusing missing, non-regular and oversized files before reading."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise _file_error(path, f"file not found ({path})") from None
    except OSError as exc:
        raise _file_error(path, f"cannot read the file: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise _file_error(path, "not a regular file")
    if info.st_size > MAX_SCENARIO_BYTES:
        raise _file_error(
            path, f"{info.st_size} bytes exceeds the scenario size cap of {MAX_SCENARIO_BYTES} bytes (1 MiB)"
        )
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise _file_error(path, f"cannot read the file: {exc.strerror or exc}") from None
    if len(raw) > MAX_SCENARIO_BYTES:  # the file grew between stat and read
        raise _file_error(path, f"more than {MAX_SCENARIO_BYTES} bytes (1 MiB)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise _file_error(path, f"not UTF-8 text (invalid byte at offset {exc.start})") from None


def scenario_hash(s: Scenario) -> str:
    """SHA-256 (hex) of the scenario's canonical JSON (canonical field names, sorted keys, no spaces).

    Equal for equal content whatever the file format, key order, aliases or omitted defaults.
    """
    canonical = json.dumps(s.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


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
        options: Planning options.
        scenario_sha256: :func:`scenario_hash` of ``spec``.
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

    Returns:
        The resolved scenario.

    Raises:
        InvalidInput: unknown robot, unresolvable mesh name, unknown/missing drive or joint names, a start
            or goal outside the parallel stage's workspace, or unrealisable payload inertia; the message
            and ``details['field']`` name the field.
        InvalidMesh: a mesh file cannot be used (message prefixed with the field, e.g. ``cabin.mesh: ``).
    """
    robot = _robot(spec)
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
        )
    payload = _payload(spec.payload, base_dir, mesh_resolver, mesh_limits) if spec.payload else None

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

    _LOG.debug("resolved scenario %r (cabin %s)", spec.name, cabin_source)
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
        options=spec.options,
        scenario_sha256=scenario_hash(spec),
    )


def load_scenario(path: Path, mesh_resolver: MeshResolver | None = None) -> ResolvedScenario:
    """Read, validate and resolve a scenario file; relative mesh paths refer to the file's folder."""
    path = Path(path)
    return resolve_scenario(load_scenario_file(path), base_dir=path.parent, mesh_resolver=mesh_resolver)


def _robot(spec: Scenario) -> Cabin8:
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
) -> LoadedMesh:
    """:func:`load_mesh` with the scenario field named in any :class:`InvalidMesh` message."""
    try:
        return load_mesh(source, units=units, name=Path(name).name, pose=pose, limits=limits)
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
) -> PayloadGeometry:
    """Payload geometry of a box or mesh payload, with its inertial data validated."""
    kwargs: dict[str, Any] = {
        "T_tool_payload": spec.grasp.matrix(),
        "mass": float(spec.mass),
        "com_payload": np.array(spec.com if spec.com is not None else (0.0, 0.0, 0.0), dtype=float),
        "inertia_payload": np.array(spec.inertia, dtype=float) if spec.inertia is not None else None,
    }
    if spec.box is not None:
        payload = PayloadGeometry(size=spec.box, source="box", **kwargs)
    else:
        assert spec.mesh is not None  # the schema guarantees exactly one of box and mesh
        source, _ = _mesh_source(spec.mesh, "payload.mesh", base_dir, resolver, allow_reference=False)
        mesh = _load(source, spec.mesh, "payload.mesh", units=spec.units, pose=None, limits=limits)
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
    return payload


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
        try:
            q = robot.joints_from_drives(u)
        except OutsideWorkspace as exc:
            raise _outside(where, exc, "the stage sliders do not assemble") from exc
        return u, q
    assert joints is not None  # the schema guarantees exactly one of drives and joints
    where = f"{prefix}.joints"
    q = robot.joints_from_dict(dict(joints), field=where)
    try:
        u = robot.drives_from_joints(q)
    except OutsideWorkspace as exc:
        raise _outside(where, exc, "no slider positions reach this platform pose") from exc
    return u, q


def _outside(where: str, exc: OutsideWorkspace, what: str) -> InvalidInput:
    condition = exc.details.get("condition")
    return InvalidInput(
        f"{where}: outside the parallel stage's workspace, {what}: {exc.message}",
        field=where,
        condition=condition,
    )


def _rigid_inverse(T: Array) -> Array:
    """Inverse of a rigid 4x4 transform: (R, p) -> (R^T, -R^T p)."""
    R, p = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ p
    return out


__all__ = [
    "MAX_SCENARIO_BYTES",
    "ApproachSpec",
    "CabinSpec",
    "ConfigurationSpec",
    "GoalSpec",
    "MeshResolver",
    "PayloadSpec",
    "PlanOptions",
    "PlannerName",
    "ResolvedScenario",
    "Scenario",
    "load_scenario",
    "load_scenario_file",
    "resolve_scenario",
    "scenario_from_dict",
    "scenario_hash",
]
