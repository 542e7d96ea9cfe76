"""The scenario schema: the public input contract of the planner (pydantic, SI units).

A *scenario* names the robot, the cabin (a mesh in the base frame), the payload and its grasp, the start
configuration, the goal (a drive/joint configuration or a payload pose with an optional straight-line
approach) and the planning options. It arrives as a YAML or JSON file (CLI, :mod:`planner.scenario.files`)
or as a dict (HTTP API), in SI units: lengths in metres, angles in radians, masses in kilograms, quaternions
as explicit ``{w, x, y, z}``. Mesh files may declare millimetres; they are converted once, on load.

:func:`scenario_from_dict` validates the *shape* of the input into a frozen :class:`Scenario` (pydantic,
``extra="forbid"`` everywhere: unknown fields are errors). Every failure is an `InvalidInput` whose message
names the offending field as a dotted path, e.g. ``options.clearance_m: Input should be greater than 0``.
:mod:`planner.scenario.resolve` then makes it concrete (robot model, meshes, vectors and transforms).

Frames: ``T_a_b`` is frame b expressed in frame a (4x4). The cabin pose is ``T_base_cabin``, the grasp is
``T_tool_payload`` and a pose goal is ``T_base_payload``; the tool goal follows as
``T_base_tool = T_base_payload @ inv(T_tool_payload)``.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable
from typing import Annotated, Any, Literal, TypeVar

import numpy as np
from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import ErrorDetails

from planner.core.exceptions import InvalidInput
from planner.core.schemas import Pose, StrictFinite
from planner.core.timing_names import TimingName
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload

log = logging.getLogger(__name__)


#: Scenario numbers are strict (see :data:`planner.core.schemas.StrictFinite`).
Number = StrictFinite
PositiveNumber = Annotated[Number, Field(gt=0.0)]
#: Bounds of absurd values, so that they are invalid input naming their field rather than reaching the
#: planner (a 1e308 kg payload would overflow the force checks and come back as a refusal): beyond any
#: payload or cabin of these robots, by orders of magnitude.
MAX_PAYLOAD_MASS_KG = 10_000.0
MAX_BOX_SIDE_M = 50.0
#: Largest seed, the same everywhere a seed is accepted (OMPL's and numpy's RNG take 32-bit seeds).
MAX_SEED = 2**31 - 1
BoxSide = Annotated[Number, Field(gt=0.0, le=MAX_BOX_SIDE_M)]
#: A STEP file's chordal tessellation tolerance [m] (bounds of :mod:`planner.meshio.step`).
TessellationTolerance = Annotated[Number, Field(ge=1e-6, le=1e-2)]
Vector3 = tuple[Number, Number, Number]
Matrix3 = tuple[Vector3, Vector3, Vector3]

#: OMPL geometric planners the planning adapter can run (``planner.plan.ompl_adapter.PLANNERS``;
#: a test keeps the two lists equal).
PlannerName = Literal["RRTConnect", "RRT", "RRTstar", "AORRTC"]

#: What a name in a document may hold (a scenario's, a cycle's, a campaign's, a sweep's, a unit's id):
#: letters, digits, '.', '_' and '-'.
NAME_PATTERN = r"^[A-Za-z0-9._-]+$"
#: The name of a scenario, a cycle or a campaign.
DocumentName = Annotated[str, Field(min_length=1, max_length=100, pattern=NAME_PATTERN)]
#: The robot a scenario, a cycle or a campaign names (a registry name).
RobotName = Annotated[str, Field(min_length=1, max_length=100, description="Registry name of the robot.")]
#: The rail length a scenario, a cycle or a campaign may set [m].
RailLength = Annotated[
    Annotated[Number, Field(gt=0.0, le=50.0)] | None,
    Field(description="Rail length in m; replaces the upper limit of drive d1 (default: the model's)."),
]

_IDENTITY_POSE = Pose(position=(0.0, 0.0, 0.0))
_MODEL_CONFIG = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)
ModelT = TypeVar("ModelT", bound=BaseModel)


# ------------------------------------------------------------------------------------------------- schema


class RealisableInertia(BaseModel):
    """Mixin: the model's ``inertia`` field (3x3 [kg m^2] or ``None``) must be a rigid body's inertia.

    Symmetric, positive semi-definite, principal moments obeying the triangle inequality (the rules of
    :class:`~planner.dynamics.payload.RigidPayload`); the subclass declares the field and its description.
    """

    @field_validator("inertia", check_fields=False)
    @classmethod
    def _realisable_inertia(cls, value: Matrix3 | None) -> Matrix3 | None:
        if value is not None:
            _check_inertia(np.array(value, dtype=float))
        return value


class OrientedPose(BaseModel):
    """Mixin: the model's ``pose`` field, when given, states its orientation explicitly.

    A goal the payload must reach is never silently "unrotated": the orientation is part of it, so an
    omitted ``orientation`` (which would default to the identity) is an error naming the field.
    """

    @field_validator("pose", check_fields=False)
    @classmethod
    def _explicit_orientation(cls, value: Pose | None) -> Pose | None:
        if value is not None and "orientation" not in value.model_fields_set:
            raise ValueError("a goal pose needs its orientation {w, x, y, z} (the identity is [1, 0, 0, 0])")
        return value


class CabinSpec(BaseModel):
    """The cabin: a triangle mesh placed in the robot base frame."""

    model_config = _MODEL_CONFIG

    mesh: str = Field(
        min_length=1,
        max_length=1000,
        description="Reference cabin name (e.g. 'cabin-aisle', with or without '.stl') or a mesh file path "
        "(STL, OBJ, PLY, GLB, glTF, or STEP: .step/.stp) relative to the scenario file.",
    )
    units: Literal["m", "mm"] = Field(
        "m",
        description="Length unit of the mesh file's coordinates (a STEP file declares its own units, "
        "which are used instead).",
    )
    tessellation_tolerance_m: TessellationTolerance | None = Field(
        None,
        description="STEP only: chordal tolerance of the tessellation in m (default 1e-4). The tessellated "
        "surface may lie up to this far inside the exact one; the planner adds it to the clearance.",
    )
    pose: Pose = Field(
        _IDENTITY_POSE, description="T_base_cabin: the mesh frame in the robot base frame (position in m)."
    )


class PayloadSpec(RealisableInertia):
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
    units: Literal["m", "mm"] = Field(
        "m",
        description="Length unit of the mesh file (box sizes are in m; a STEP file's own units are used).",
    )
    tessellation_tolerance_m: TessellationTolerance | None = Field(
        None,
        description="STEP mesh only: chordal tolerance of the tessellation in m (default 1e-4), added to the "
        "clearance.",
    )
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

    @model_validator(mode="after")
    def _box_or_mesh(self) -> PayloadSpec:
        if (self.box is None) == (self.mesh is None):
            got = "both" if self.box is not None else "neither"
            raise ValueError(f"exactly one of box or mesh is required, got {got}")
        if self.box is not None and self.units != "m":
            raise ValueError("units applies to a mesh payload only; box sizes are always in m")
        if self.box is not None and self.tessellation_tolerance_m is not None:
            raise ValueError("tessellation_tolerance_m applies to a STEP mesh payload only")
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
        _exactly_one_of(self, ("drives", "joints"))
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


class GoalSpec(OrientedPose):
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

    @field_validator("approach")
    @classmethod
    def _approach_needs_pose(cls, value: ApproachSpec | None, info: ValidationInfo) -> ApproachSpec | None:
        if value is not None and info.data.get("pose") is None:
            raise ValueError("only allowed with a pose goal")
        return value

    @model_validator(mode="after")
    def _exactly_one(self) -> GoalSpec:
        _exactly_one_of(self, ("drives", "joints", "pose"))
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
        description="Certified motion checks (expert option): the margin in m the planner's certified walk "
        "starts with; near tight states it adapts down to 0.5 mm on its own, so no scenario needs to set it.",
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

    timing: TimingName | None = Field(
        None,
        description="Time law of the drive profile: 'jerk_limited' (every drive's jerk within its limit, "
        "the path kept exactly) or 'acceleration_limited' (TOPP-RA alone: acceleration steps). Default "
        "(null): jerk_limited when the robot description has jerk limits, else acceleration_limited.",
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

    name: DocumentName = Field(description="Scenario name: letters, digits, '.', '_' and '-'.")
    robot: RobotName = "cabin8"
    robot_description: str | None = Field(
        None,
        min_length=1,
        max_length=1000,
        description="A cabin8-type description file (e.g. from `cabinplan stiffness calibrate`) to use "
        "instead of the registry's; a path relative to the scenario file. Read from files only by the CLI.",
    )
    rail_length: RailLength = None
    cabin: CabinSpec | None = Field(None, description="The cabin mesh; omitted = free space.")
    payload: PayloadSpec | None = Field(None, description="The carried payload; omitted = none.")
    start: ConfigurationSpec = Field(description="Start configuration.")
    goal: GoalSpec = Field(description="Goal configuration or payload pose.")
    options: PlanOptions = Field(default_factory=PlanOptions, description="Planning options.")


def _exactly_one_of(model: BaseModel, names: tuple[str, ...]) -> None:
    """Raise ValueError unless exactly one of the named fields is given (the message names them)."""
    given = [n for n in names if getattr(model, n) is not None]
    if len(given) != 1:
        choices = f"{', '.join(names[:-1])} or {names[-1]}"
        got = "none" if not given else " and ".join(given)
        raise ValueError(f"exactly one of {choices} is required, got {got}")


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
    return validate_document(Scenario, data, "scenario", source)


def validate_document(
    model: type[ModelT],
    data: object,
    name: str,
    source: str,
    relabel: Callable[[dict[str, str]], None] | None = None,
) -> ModelT:
    """Validate a parsed document (scenario, cycle, sweep ...) into its frozen pydantic ``model``.

    Args:
        model: The document's model class.
        data: The parsed document; its top level must be a mapping (an instance of ``model`` passes).
        name: The document's name, the field of a top-level error (``"scenario"``, ``"cycle"``).
        source: Where the data came from (file path or the name), recorded in the error details.
        relabel: Rewrites one error ``{field, message}`` in place before it is reported (a model-level
            message naming its own field, the document's name instead of ``"scenario"``).

    Returns:
        The validated model.

    Raises:
        InvalidInput: the message names the first offending field as a dotted path and the reason;
            ``details`` has ``field``, ``source`` and ``errors`` (every error as ``{field, message}``).
    """
    if isinstance(data, model):
        return data
    if not isinstance(data, dict):
        kind = "nothing (empty document)" if data is None else type(data).__name__
        raise InvalidInput(
            f"{name}: expected a mapping of fields at the top level, got {kind}", field=name, source=source
        )
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = [describe_error(e) for e in exc.errors(include_url=False, include_input=False)]
        if relabel is not None:
            for e in errors:
                relabel(e)
        first = errors[0]
        raise InvalidInput(
            f"{first['field']}: {first['message']}", field=first["field"], source=source, errors=errors
        ) from None


def describe_error(error: ErrorDetails) -> dict[str, str]:
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


def scenario_hash(s: Scenario) -> str:
    """SHA-256 (hex) of the scenario's canonical JSON (canonical field names, sorted keys, no spaces).

    Equal for equal content whatever the file format, key order, aliases or omitted defaults.
    """
    canonical = json.dumps(s.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()
