"""What a generated case is made of: the mesh formats and ranges, the options, the case itself.

The goal kinds (:data:`GOAL_KINDS`, re-exported here) are the families' vocabulary
(:mod:`planner.generate.families`).

Every range here is drawn by the case's own generator (:mod:`planner.generate.cases`); the families
(:mod:`planner.generate.families`) narrow or widen some of them. Lengths in metres, masses in kg.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, Protocol

from planner.core.types import Array
from planner.generate.families import FAMILIES, GOAL_KINDS, GoalKind

if TYPE_CHECKING:
    from planner.generate.cabins import CabinLayout

MeshFormat = Literal["stl", "obj", "ply", "glb"]

MESH_FORMATS: tuple[MeshFormat, ...] = ("stl", "obj", "ply", "glb")

#: Inner diameters of the round shells [m] (the octagons' inscribed diameters alike).
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
#: Clearance the start (and a drive goal) keeps beyond the requested one [m].
START_EXTRA_M = 0.020
#: Node spacing of the generator's collision worlds' bound grid [m] (coarser than the planner's: faster
#: to build for a new cabin, same verdicts).
GRID_STEP_M = 0.06
#: The model's own rail length [m] (cabin8.yaml); a scenario states ``rail_length`` only when shorter.
ROBOT_RAIL_M = 6.0


@dataclass(frozen=True)
class GeneratorOptions:
    """What every generated case shares.

    Attributes:
        clearance_m: The scenario's requested clearance [m].
        time_limit_s: The scenario's planning time limit [s] (the planner's default).
        goal_kinds: Goal kinds to draw from (the family's weights, renormalised); ``None``: the family's.
        formats: Mesh formats, cycled by case index.
        max_attempts: Redraws per case before giving up (``None``: the family's, 60 for ``mixed``).
        rail_length_m: Rail length [m] (the cabin section is 0.5 m longer at each end); shorter rails make
            smaller, faster cases (the tests' sample).
        family: The family of cabins and goals (:data:`planner.generate.families.FAMILIES`); ``mixed`` is
            the original generator, byte for byte.
    """

    clearance_m: float = 0.01
    time_limit_s: float = 30.0
    goal_kinds: tuple[GoalKind, ...] | None = None
    formats: tuple[MeshFormat, ...] = MESH_FORMATS
    max_attempts: int | None = None
    rail_length_m: float = 6.0
    family: str = "mixed"

    def __post_init__(self) -> None:
        if not 3.0 <= self.rail_length_m <= 6.0:
            raise ValueError(f"rail_length_m must be within [3, 6] m, got {self.rail_length_m}")
        if self.family not in FAMILIES:
            raise ValueError(f"family must be one of {sorted(FAMILIES)}, got {self.family!r}")
        kinds = FAMILIES[self.family].goal_kinds
        if self.goal_kinds is not None and not set(self.goal_kinds) <= set(kinds):
            raise ValueError(
                f"goal_kinds of family {self.family!r} are within {kinds}, got {self.goal_kinds}"
            )


class Generated(Protocol):
    """What every generated document has (a case's scenario, a campaign): a name, a mesh file, features."""

    @property
    def name(self) -> str:
        """The document's name (its file is ``<name>.yaml``)."""

    @property
    def mesh_name(self) -> str:
        """File name of the cabin mesh."""

    @property
    def mesh_bytes(self) -> bytes:
        """The mesh file's content."""

    @property
    def meta(self) -> dict[str, Any]:
        """Features of the draw, JSON-able (``redraws``: the reasons of the draws before it, counted)."""


@dataclass(frozen=True)
class GeneratedCase:
    """One generated scenario: the scenario dict, the mesh file and what it was made of.

    Attributes:
        name: Scenario name (``gen-<seed>-<index>``, ``gen-<family>-<seed>-<index>`` for a family).
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


__all__ = [
    "FREE_RANGE_M",
    "GOAL_KINDS",
    "GRID_STEP_M",
    "MESH_FORMATS",
    "PAYLOAD_BOXES_M",
    "ROBOT_RAIL_M",
    "SHELL_DIAMETERS_M",
    "START_EXTRA_M",
    "Generated",
    "GeneratedCase",
    "GeneratorOptions",
    "GoalKind",
    "MeshFormat",
]
