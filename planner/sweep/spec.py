"""The sweep description: a base scenario and the axes it is varied along (schema and loading).

A sweep file (YAML or JSON, at most 1 MiB, SI units like a scenario) names a base scenario (a scenario
file relative to the sweep file, or the scenario inline) and either *axes* (their cross product gives the
plans) or an explicit list of *plans* (each entry sets some of the same fields). For example::

    name: aisle-bays-90kg
    base: aisle-bay-insert.yaml
    axes:
      goal: {bays: all}                 # or {bays: [A1, A3]}, {poses: [...]}, {grid: {x, y, z}}
      payload_mass_kg: [60, 90]
      start:
        - {name: docked, drives: {d1: 1.0, ...}}
      seed: [1, 2]

Every field is validated with ``extra="forbid"``; a failure is an `InvalidInput`
naming the field (``axes.payload_mass_kg[1]: Input should be greater than or equal to 0``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from planner.core.schemas import Limits, Pose, Quaternion
from planner.scenario.files import MAX_SCENARIO_BYTES, read_document
from planner.scenario.schema import NAME_PATTERN, ConfigurationSpec, Number, PositiveNumber, validate_document

_CONFIG = ConfigDict(extra="forbid", frozen=True)

#: Most plans one sweep may expand to (a cross product grows fast; split larger studies).
MAX_PLANS = 100_000

Name = Annotated[str, Field(min_length=1, max_length=60, pattern=NAME_PATTERN)]
Vector3 = tuple[Number, Number, Number]


class Linspace(BaseModel):
    """``num`` evenly spaced values from ``start`` to ``stop`` inclusive (``numpy.linspace``), in m."""

    model_config = _CONFIG

    start: Number
    stop: Number
    num: int = Field(ge=1, le=1000, strict=True)

    def values(self) -> list[float]:
        """The values, start to stop."""
        if self.num == 1:
            return [float(self.start)]
        step = (float(self.stop) - float(self.start)) / (self.num - 1)
        return [float(self.start) + k * step for k in range(self.num)]


Coordinate = list[Number] | Linspace


class GoalGrid(BaseModel):
    """A grid of goal positions (payload frame origin in the base frame, m); cross product of x, y, z."""

    model_config = _CONFIG

    x: Coordinate = Field(description="x values [m]: a list or {start, stop, num}.")
    y: Coordinate = Field(description="y values [m].")
    z: Coordinate = Field(description="z values [m].")
    orientation: Quaternion | None = Field(
        None, description="Payload orientation at every grid point (default: the base goal's)."
    )

    def positions(self) -> list[tuple[float, float, float]]:
        """Every grid position, x slowest, z fastest."""

        def vals(c: Coordinate) -> list[float]:
            return c.values() if isinstance(c, Linspace) else [float(v) for v in c]

        return [(x, y, z) for x in vals(self.x) for y in vals(self.y) for z in vals(self.z)]


class GoalAxis(BaseModel):
    """Goal poses to sweep: bays of the cabin manifest, a list of poses, or a grid (exactly one)."""

    model_config = _CONFIG

    bays: Literal["all"] | list[Annotated[str, Field(min_length=1, max_length=60)]] | None = Field(
        None, description="Bay ids of the manifest (see ``bays``), or 'all'."
    )
    poses: list[Pose] | None = Field(
        None, min_length=1, description="T_base_payload goal poses (orientation default: the base goal's)."
    )
    grid: GoalGrid | None = Field(None, description="A grid of goal positions.")

    @model_validator(mode="after")
    def _exactly_one(self) -> GoalAxis:
        given = [n for n in ("bays", "poses", "grid") if getattr(self, n) is not None]
        if len(given) != 1:
            raise ValueError(f"exactly one of bays, poses or grid is required, got {given or 'none'}")
        if isinstance(self.bays, list) and not self.bays:
            raise ValueError("bays: give at least one bay id, or 'all'")
        return self


class BaySource(BaseModel):
    """Where bay ids are looked up, and how a bay becomes a goal pose with a straight insertion."""

    model_config = _CONFIG

    manifest: str | None = Field(
        None,
        max_length=1000,
        description="Cabin manifest (JSON in the format of meshes/cabins.json), relative to the sweep "
        "file; default: the reference cabins' manifest.",
    )
    cabin: str | None = Field(
        None,
        max_length=100,
        description="Cabin name in the manifest; default: the base scenario's cabin mesh (without '.stl').",
    )
    orientation: Quaternion | None = Field(
        None, description="Payload orientation in the bay (default: the base goal's orientation)."
    )
    approach_distance_m: Number | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description="Length of the straight insertion along the bay's insertion axis [m] (default: the "
        "base goal's approach distance).",
    )


class StartPosture(ConfigurationSpec):
    """A named start configuration (drives or joints, as in a scenario's ``start``)."""

    name: Name = Field(description="Label of the posture in the results.")


class Axes(BaseModel):
    """Values to sweep; the plans are the cross product of every axis given (an axis left out = base)."""

    model_config = _CONFIG

    goal: GoalAxis | None = Field(None, description="Goal poses: bays, a list, or a grid.")
    payload_mass_kg: list[Annotated[Number, Field(ge=0.0)]] | None = Field(None, min_length=1)
    payload_box_m: list[tuple[PositiveNumber, PositiveNumber, PositiveNumber]] | None = Field(
        None, min_length=1, description="Payload box sizes [x, y, z] in m."
    )
    grasp: list[Pose] | None = Field(None, min_length=1, description="T_tool_payload grasp offsets.")
    start: list[StartPosture] | None = Field(None, min_length=1, description="Named start postures.")
    clearance_m: list[Annotated[Number, Field(gt=0.0, le=0.2)]] | None = Field(None, min_length=1)
    seed: list[Annotated[int, Field(ge=0, strict=True)]] | None = Field(None, min_length=1)


class PlanPoint(BaseModel):
    """One explicitly listed plan: the fields it changes in the base scenario (each optional)."""

    model_config = _CONFIG

    bay: str | None = Field(None, min_length=1, max_length=60, description="Bay id (see ``bays``).")
    goal_pose: Pose | None = Field(None, description="T_base_payload goal pose.")
    payload_mass_kg: Annotated[Number, Field(ge=0.0)] | None = None
    payload_box_m: tuple[PositiveNumber, PositiveNumber, PositiveNumber] | None = None
    grasp: Pose | None = None
    start: StartPosture | None = None
    clearance_m: Annotated[Number, Field(gt=0.0, le=0.2)] | None = None
    seed: Annotated[int, Field(ge=0, strict=True)] | None = None

    @model_validator(mode="after")
    def _one_goal(self) -> PlanPoint:
        if self.bay is not None and self.goal_pose is not None:
            raise ValueError("give bay or goal_pose, not both")
        return self


class SweepSpec(BaseModel):
    """A feasibility sweep: base scenario, axes or explicit plans, bay source and wall-clock limits."""

    model_config = _CONFIG

    name: Name = Field(description="Sweep name: letters, digits, '.', '_' and '-'.")
    base: str | dict[str, Any] = Field(
        description="The base scenario: a scenario file relative to the sweep file, or the scenario inline."
    )
    axes: Axes = Field(default_factory=Axes, description="Axes whose cross product gives the plans.")
    plans: list[PlanPoint] | None = Field(
        None, min_length=1, max_length=MAX_PLANS, description="Explicit plans instead of axes."
    )
    bays: BaySource = Field(default_factory=BaySource, description="Where bay ids are looked up.")
    limits: Limits = Field(default_factory=Limits, description="Wall-clock limits of each plan.")

    @model_validator(mode="after")
    def _axes_or_plans(self) -> SweepSpec:
        if self.plans is not None and self.axes.model_fields_set:
            raise ValueError("give axes (a cross product) or plans (an explicit list), not both")
        return self


def sweep_from_dict(data: object, source: str = "sweep") -> SweepSpec:
    """Validate a parsed sweep description.

    Raises:
        InvalidInput: the message names the first offending field as a dotted path and the reason;
            ``details['errors']`` lists every error as ``{field, message}``.
    """
    return validate_document(SweepSpec, data, "sweep", source, _relabel_sweep_error)


def _relabel_sweep_error(error: dict[str, str]) -> None:
    """The sweep's own name in a top-level error and an unknown field's message."""
    if error["field"] == "scenario":
        error["field"] = "sweep"
    elif error["message"] == "unknown field (not part of the scenario schema)":
        error["message"] = "unknown field (not part of the sweep schema)"


def load_sweep_file(path: Path) -> SweepSpec:
    """Read and validate a sweep file (``.yaml``/``.yml``/``.json``, at most 1 MiB).

    Raises:
        InvalidInput: wrong extension, unreadable or oversized file, a syntax error (with line and
            column), a duplicate key, or a schema violation.
    """
    path = Path(path)
    return sweep_from_dict(read_document(path, "sweep"), source=str(path))


__all__ = [
    "MAX_PLANS",
    "MAX_SCENARIO_BYTES",
    "Axes",
    "BaySource",
    "GoalAxis",
    "GoalGrid",
    "Limits",
    "Linspace",
    "PlanPoint",
    "StartPosture",
    "SweepSpec",
    "load_sweep_file",
    "sweep_from_dict",
]
