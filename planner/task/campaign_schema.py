"""The campaign document: a cabin, the units installed before it, and the units to install, each one cycle.

A campaign (YAML or JSON, SI units like a scenario) lists the units a line installs in one cabin::

    name: line-7
    robot: cabin8
    cabin: {mesh: cabin-aisle}
    installed: []                 # units already in the cabin (each a box or a mesh at a pose)
    park: {drives: {...}}         # where every cycle starts and ends
    units:                        # each: the unit, its dock and its bay (the cycle document's pieces)
      - {unit: {id: A1, box: [...], mass: 60, grasp: {...}}, dock: {...}, bay: {...}}
      - {unit: {id: B3, ...}, dock: {...}, bay: {...}, retract: {...}}
    order: given                  # or find: search an order in which every cycle plans
    dwell: {grasp_s: 0.5, release_s: 0.5}
    options: {...}                # every cycle's planning options (a scenario's)
    limits: {grace_s: 15}         # wall clock of each cycle's process (the sweeps' limits)
    search: {max_cycles: 200}     # order: find, the most cycles it may plan

The pieces are the cycle document's (:mod:`planner.task.schema`). Each unit's cycle is an ordinary cycle
document composed by :func:`planner.task.campaign.cycle_document`: the campaign's robot, cabin, park,
dwell, gripper and options, the units installed before the campaign plus the campaign's units installed
before this one (each at its bay pose), and this unit's ``unit``, ``dock``, ``bay`` and ``retract``. So a
cycle of a campaign re-runs alone with ``cabinplan cycle``.

:func:`campaign_from_dict` validates the shape (pydantic, ``extra="forbid"``; unit ids unique among the
campaign's units and the installed ones); every failure is an `InvalidInput` naming the dotted field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from planner.core.exceptions import InvalidInput
from planner.core.schemas import Limits
from planner.scenario.files import read_document
from planner.scenario.schema import (
    CabinSpec,
    ConfigurationSpec,
    DocumentName,
    PlanOptions,
    RailLength,
    RobotName,
    describe_error,
)
from planner.task.schema import BayGoal, DockSpec, DwellSpec, GripperSpec, InstalledUnit, LineSpec, UnitSpec

__all__ = [
    "MAX_UNITS",
    "Campaign",
    "CampaignUnit",
    "SearchOptions",
    "campaign_from_dict",
    "load_campaign_file",
]

_CONFIG = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

#: Most units in one campaign (an exhaustive order search is 2^n states).
MAX_UNITS = 16


class CampaignUnit(BaseModel):
    """One unit to install: the cycle document's ``unit``, ``dock``, ``bay`` and ``retract``."""

    model_config = _CONFIG

    unit: UnitSpec = Field(description="The unit (its id, shape, mass, inertia and grasp), as in a cycle.")
    dock: DockSpec = Field(description="Its dock at the cabin entrance, as in a cycle.")
    bay: BayGoal = Field(description="Its bay: installed pose and insertion line, as in a cycle.")
    retract: LineSpec | None = Field(
        None,
        description="The retract line from the release (default: back out along the insertion line, the "
        "same distance).",
    )
    dwell: DwellSpec | None = Field(None, description="This cycle's dwell times (default: the campaign's).")

    @property
    def id(self) -> str:
        """The unit's id."""
        return self.unit.id

    def retract_line(self) -> LineSpec:
        """The retract line: the given one, or the insertion line reversed."""
        if self.retract is not None:
            return self.retract
        d = self.bay.approach.direction
        return LineSpec(direction=(-d[0], -d[1], -d[2]), distance=self.bay.approach.distance)


class SearchOptions(BaseModel):
    """How ``order: find`` searches."""

    model_config = _CONFIG

    max_cycles: int = Field(
        200,
        ge=1,
        le=10_000,
        strict=True,
        description="Most cycles the search may plan; past it the campaign stops undecided.",
    )


class Campaign(BaseModel):
    """A campaign: cabin, installed units, the units to install with their docks and bays, the order."""

    model_config = _CONFIG

    name: DocumentName = Field(description="Campaign name: letters, digits, '.', '_' and '-'.")
    robot: RobotName = "cabin8"
    rail_length: RailLength = None
    cabin: CabinSpec = Field(description="The cabin mesh, as in a cycle.")
    installed: tuple[InstalledUnit, ...] = Field(
        (), max_length=200, description="Units in the cabin before the campaign (each an obstacle)."
    )
    park: ConfigurationSpec = Field(description="The park posture every cycle starts and ends at.")
    units: tuple[CampaignUnit, ...] = Field(
        min_length=1, max_length=MAX_UNITS, description="The units to install (at most 16)."
    )
    order: Literal["given", "find"] = Field(
        "given",
        description="'given': install in the listed order and stop at the first cycle refused; "
        "'find': search an order in which every cycle plans.",
    )
    dwell: DwellSpec = Field(default_factory=DwellSpec, description="Grasp and release dwell times.")
    gripper: GripperSpec | None = Field(None, description="A gripper body at the tool, as in a cycle.")
    options: PlanOptions = Field(default_factory=PlanOptions, description="Every cycle's planning options.")
    limits: Limits = Field(default_factory=Limits, description="Wall-clock limits of each cycle's process.")
    search: SearchOptions = Field(default_factory=SearchOptions, description="order: find, its budget.")

    @model_validator(mode="after")
    def _unique_ids(self) -> Campaign:
        seen: dict[str, str] = {}
        for k, e in enumerate(self.installed):
            if e.id in seen:
                raise ValueError(
                    f"installed[{k}].id: {e.id!r} is used twice ({seen[e.id]} and installed[{k}])"
                )
            seen[e.id] = f"installed[{k}]"
        for k, u in enumerate(self.units):
            if u.id in seen:
                raise ValueError(f"units[{k}].unit.id: {u.id!r} is used twice ({seen[u.id]} and units[{k}])")
            seen[u.id] = f"units[{k}]"
        return self

    @property
    def ids(self) -> list[str]:
        """The unit ids in their listed order."""
        return [u.id for u in self.units]

    def unit(self, unit_id: str) -> CampaignUnit:
        """The unit of this id."""
        for u in self.units:
            if u.id == unit_id:
                return u
        raise InvalidInput(f"units: no unit {unit_id!r} in campaign {self.name}", field="units")


def campaign_from_dict(data: object, source: str = "campaign") -> Campaign:
    """Validate a parsed campaign (a mapping from YAML/JSON or an HTTP body) into a frozen :class:`Campaign`.

    Raises:
        InvalidInput: the first offending field as a dotted path and the reason (``details``: ``field``,
            ``source``, ``errors``).
    """
    if isinstance(data, Campaign):
        return data
    if not isinstance(data, dict):
        kind = "nothing (empty document)" if data is None else type(data).__name__
        raise InvalidInput(
            f"campaign: expected a mapping of fields at the top level, got {kind}",
            field="campaign",
            source=source,
        )
    try:
        return Campaign.model_validate(data)
    except ValidationError as exc:
        errors = [describe_error(e) for e in exc.errors(include_url=False, include_input=False)]
        for e in errors:  # a model-level check names its own field at the start of its message
            if e["field"] in ("scenario", "campaign") and ": " in e["message"]:
                e["field"], e["message"] = e["message"].split(": ", 1)
        first = errors[0]
        raise InvalidInput(
            f"{first['field']}: {first['message']}", field=first["field"], source=source, errors=errors
        ) from None


def load_campaign_file(path: Path) -> Campaign:
    """Read and validate a campaign file (``.yaml``/``.yml``/``.json``, at most 1 MiB).

    Raises:
        InvalidInput: wrong extension, unreadable or oversized file, a syntax error (line and column), a
            duplicate key, or a schema violation (the dotted field).
    """
    path = Path(path)
    return campaign_from_dict(read_document(path, "campaign"), source=str(path))
