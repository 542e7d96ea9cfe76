"""The cycle document: one assembly cycle -- take a unit from its dock, install it in its bay, park.

A cycle names the robot, the cabin (as a scenario does), the units already installed (each a box or a mesh
at a pose, with an id), the unit to install (box or mesh, mass, centre of mass, inertia, grasp), its dock
(the unit's pose on its transport fixture at the cabin entrance, the fixture's geometry, the grasp approach
line and the lift-off line), the bay (the installed pose and its insertion line), the dwell times of the
grasp and the release, the retract line, the park posture, an optional gripper body and the planning
options (those of a scenario). SI units: lengths in metres, except that a geometry may declare ``units:
mm`` for its box size and mesh file; poses are in metres, quaternions ``{w, x, y, z}``.

Frames: ``T_base_unit`` is the unit frame in the robot base frame (a dock pose, a bay pose, an installed
unit's pose); the grasp is ``T_tool_unit``, so the tool pose holding the unit at ``T_base_unit`` is
``T_base_unit @ inv(T_tool_unit)``. Line directions are in the base frame; an approach line ends at its
pose (the tool moves along ``direction`` onto it), a lift-off or retract line starts at its pose.

:func:`cycle_from_dict` validates the shape (pydantic, ``extra="forbid"``); every failure is an
`InvalidInput` naming the dotted field (``unit.mass: Input should be greater than 0``).
:func:`cycle_json_schema` is the JSON schema (for OpenAPI).
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from planner.core.schemas import Pose
from planner.scenario.schema import (
    MAX_BOX_SIDE_M,
    MAX_PAYLOAD_MASS_KG,
    NAME_PATTERN,
    ApproachSpec,
    CabinSpec,
    ConfigurationSpec,
    DocumentName,
    Matrix3,
    Number,
    OrientedPose,
    PlanOptions,
    RailLength,
    RealisableInertia,
    RobotName,
    Vector3,
    validate_document,
)

_MODEL_CONFIG = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)
_IDENTITY_POSE = Pose(position=(0.0, 0.0, 0.0))
UnitId = Annotated[str, Field(min_length=1, max_length=50, pattern=NAME_PATTERN)]
Side = Annotated[Number, Field(gt=0.0)]
#: Longest dwell [s] (a grasp or a release is seconds, not minutes).
MAX_DWELL_S = 60.0


class Geometry(BaseModel):
    """A rigid body's shape: a box centred on its frame, or a mesh file (exactly one)."""

    model_config = _MODEL_CONFIG

    box: tuple[Side, Side, Side] | None = Field(
        None, description="Box size [x, y, z] in `units`, centred on the body frame. Exclusive with mesh."
    )
    mesh: str | None = Field(
        None,
        min_length=1,
        max_length=1000,
        description="Mesh file (STL, OBJ, PLY, GLB, glTF) relative to the cycle file, coordinates in the "
        "body frame, in `units`. Exclusive with box.",
    )
    units: Literal["m", "mm"] = Field("m", description="Length unit of the box size and the mesh file.")

    @model_validator(mode="after")
    def _box_or_mesh(self) -> Geometry:
        if (self.box is None) == (self.mesh is None):
            got = "both" if self.box is not None else "neither"
            raise ValueError(f"exactly one of box or mesh is required, got {got}")
        if self.box is not None:
            scale = 1e-3 if self.units == "mm" else 1.0
            if max(self.box) * scale > MAX_BOX_SIDE_M:
                raise ValueError(f"box sides are at most {MAX_BOX_SIDE_M} m")
        return self

    def box_m(self) -> tuple[float, float, float] | None:
        """The box size in metres (None for a mesh)."""
        if self.box is None:
            return None
        scale = 1e-3 if self.units == "mm" else 1.0
        return (self.box[0] * scale, self.box[1] * scale, self.box[2] * scale)


class InstalledUnit(Geometry):
    """A unit already installed in the cabin: an obstacle for every motion, named ``unit <id>``."""

    id: UnitId = Field(description="Unit id (letters, digits, '.', '_', '-'); reports name it 'unit <id>'.")
    pose: Pose = Field(description="T_base_unit: the unit frame in the base frame (position in m).")


class UnitSpec(Geometry, RealisableInertia):
    """The unit to install.

    its shape, inertia and grasp. A mesh unit is held and installed as its oriented bounding box (collision
    checks), like a scenario's mesh payload.
    """

    id: UnitId = Field(description="Unit id; reports name it 'unit <id>'.")
    mass: Number = Field(gt=0.0, le=MAX_PAYLOAD_MASS_KG, description="Mass in kg.")
    com: Vector3 | None = Field(
        None, description="Centre of mass in the unit frame [m] (default: its origin)."
    )
    inertia: Matrix3 | None = Field(
        None,
        description="Inertia about the centre of mass in unit axes [kg m^2] (default: a uniform solid box).",
    )
    grasp: Pose = Field(
        description="T_tool_unit: the unit frame in the tool frame when held (position in m)."
    )


class FixtureSpec(Geometry):
    """The transport fixture the unit waits on at its dock (an obstacle, named ``fixture of <id>``)."""

    pose: Pose = Field(description="T_base_fixture: the fixture frame in the base frame (position in m).")


class LineSpec(ApproachSpec):
    """A straight line of the tool: a direction in the base frame (normalised) and a length [m]."""


class DockSpec(OrientedPose):
    """Where the unit waits: its pose on the fixture, the fixture, and the grasp and lift-off lines."""

    model_config = _MODEL_CONFIG

    pose: Pose = Field(description="T_base_unit of the unit on its fixture (position in m).")
    fixture: FixtureSpec = Field(description="The transport fixture's geometry and pose.")
    approach: LineSpec = Field(
        description="The grasp line: the tool moves along `direction` for `distance` m onto the grasp."
    )
    lift: LineSpec = Field(description="The lift-off line: from the grasp, the loaded tool moves along it.")


class BayGoal(OrientedPose):
    """The bay: the installed pose of the unit and its insertion line."""

    model_config = _MODEL_CONFIG

    pose: Pose = Field(description="T_base_unit of the installed unit (position in m).")
    approach: LineSpec = Field(
        description="The insertion line: the unit moves along `direction` for `distance` m onto the pose."
    )


class GripperSpec(BaseModel):
    """The gripper: a box fixed to the tool (its mass belongs to the robot description's tool)."""

    model_config = _MODEL_CONFIG

    box: tuple[Side, Side, Side] = Field(description="Box size [x, y, z] in `units`, centred on its frame.")
    units: Literal["m", "mm"] = Field("m", description="Length unit of the box size.")
    pose: Pose = Field(_IDENTITY_POSE, description="T_tool_gripper: the gripper frame in the tool frame [m].")

    def box_m(self) -> tuple[float, float, float]:
        """The box size in metres."""
        scale = 1e-3 if self.units == "mm" else 1.0
        return (self.box[0] * scale, self.box[1] * scale, self.box[2] * scale)


class DwellSpec(BaseModel):
    """How long the robot rests at the grasp (closing on the unit) and at the release (letting go) [s]."""

    model_config = _MODEL_CONFIG

    grasp_s: Number = Field(0.5, ge=0.0, le=MAX_DWELL_S, description="Grasp dwell [s].")
    release_s: Number = Field(0.5, ge=0.0, le=MAX_DWELL_S, description="Release dwell [s].")


class Cycle(BaseModel):
    """One assembly cycle: park -> grasp at the dock -> carry -> insert -> release -> retract -> park."""

    model_config = _MODEL_CONFIG

    name: DocumentName = Field(description="Cycle name.")
    robot: RobotName = "cabin8"
    rail_length: RailLength = None
    cabin: CabinSpec = Field(description="The cabin mesh, as in a scenario.")
    installed: tuple[InstalledUnit, ...] = Field((), max_length=200, description="Units already installed.")
    unit: UnitSpec = Field(description="The unit to install.")
    dock: DockSpec = Field(description="The unit's dock at the cabin entrance.")
    bay: BayGoal = Field(description="The unit's bay: installed pose and insertion line.")
    retract: LineSpec = Field(
        description="The retract line: from the release, the empty tool moves along it."
    )
    park: ConfigurationSpec = Field(description="The park posture the cycle starts and ends at.")
    dwell: DwellSpec = Field(default_factory=DwellSpec, description="Grasp and release dwell times.")
    gripper: GripperSpec | None = Field(
        None,
        description="A gripper body at the tool (default: none; the robot's last body then meets the unit).",
    )
    options: PlanOptions = Field(default_factory=PlanOptions, description="Planning options (a scenario's).")

    @model_validator(mode="after")
    def _unique_ids(self) -> Cycle:
        seen: dict[str, str] = {}
        for i, u in enumerate(self.installed):
            if u.id in seen:
                raise ValueError(
                    f"installed[{i}].id: unit id {u.id!r} is used twice ({seen[u.id]} and installed[{i}])"
                )
            seen[u.id] = f"installed[{i}]"
        if self.unit.id in seen:
            raise ValueError(f"unit.id: {self.unit.id!r} is already installed ({seen[self.unit.id]})")
        return self


def cycle_from_dict(data: object, source: str = "cycle") -> Cycle:
    """Validate a parsed cycle document (a mapping, e.g. from YAML/JSON or an HTTP body).

    Raises:
        InvalidInput: the data does not match the schema; the message names the first offending field as
            a dotted path and the reason; ``details`` has ``field``, ``source`` and ``errors``.
    """
    return validate_document(Cycle, data, "cycle", source, _relabel_cycle_error)


def _relabel_cycle_error(error: dict[str, str]) -> None:
    """A model-level message that names its own field: that field, not "cycle"."""
    head, sep, rest = error["message"].partition(": ")
    if error["field"] == "scenario" and sep and " " not in head:
        error["field"], error["message"] = head, rest
    elif error["field"] == "scenario":
        error["field"] = "cycle"


def cycle_hash(c: Cycle) -> str:
    """SHA-256 (hex) of the cycle's canonical JSON (sorted keys, defaults included)."""
    canonical = json.dumps(c.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def cycle_json_schema() -> dict[str, Any]:
    """The cycle document's JSON schema (pydantic's, for OpenAPI and editors)."""
    return Cycle.model_json_schema()
