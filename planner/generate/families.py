"""Families of generated cabins and goals: one registry, each family a set of ranges the draw reads.

``mixed`` is the original generator (its cases are the same bytes as before the families existed): every
goal kind, a round shell with ring frames every 0.45-0.75 m (60%) or plain, payloads 20-120 kg. The other
families are the cabins of issue 26 that nobody tuned the planner for: ring-frame shells with frames
every 1.0-1.5 m and a rack bay in the side wall, octagonal and box-section shells, stringer shells, bays in
the end walls, and cabins where ducts, brackets and a bulkhead hatch are in the way; payloads 20-110 kg.
Every family keeps the mixed family's checks (a witness goal configuration, a clear and holdable start,
the hatch certified passable) and its file variety (STL/OBJ/PLY/GLB, m and mm, a shifted, rotated file
frame). A family's case ``i`` of ``seed`` is drawn from ``default_rng([seed, i, family.tag])``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from planner.generate.sections import SectionKind

GoalKind = Literal["bay-side", "bay-end-far", "bay-end-near", "shelf", "drive"]

GOAL_KINDS: tuple[GoalKind, ...] = ("bay-side", "bay-end-far", "bay-end-near", "shelf", "drive")
#: Draw weights of the goal kinds (bay insertions dominate, as in the issue's cabins).
GOAL_WEIGHTS: tuple[float, ...] = (0.40, 0.15, 0.10, 0.15, 0.20)


@dataclass(frozen=True)
class Family:
    """The ranges one family of cases is drawn from.

    Attributes:
        name: The family's name (``--family``).
        description: One line for listings.
        tag: Third word of the case generator's seed (``None``: the mixed family's ``[seed, index]``).
        section: Shell cross-section: ``round`` (2.4-3.0 m), ``octagon`` (2.4-3.0 m across the flats) or
            ``box`` (2.3-2.9 m wide, chamfered corners).
        goal_kinds: Goal kinds drawn, with ``goal_weights``.
        mass_range_kg: Payload mass range [kg].
        ring_probability: Probability of ring frames.
        ring_spacing_m: Range of the ring frames' spacing [m].
        stringers: Range of the stringer count (``randint`` bounds, high exclusive); ``None``: none.
        ducts: Range of the duct count (high exclusive).
        brackets: Range of the bracket count (high exclusive).
        far_probability: Probability that the start is well away from the goal along the rail (> 1.5 m).
        hatch_probability: Probability of a bulkhead hatch between a far start and the goal.
        goal_solutions: Exact goal configurations tried at a pose goal (a family's case keeps its goal
            kind through its redraws: side bays pass the clearance and hold checks in 5-25% of the draws
            with 3, so the families try 8, which about triples the rate on ring-frame shells).
        max_attempts: Draws per case before giving up (unless the options say).
    """

    name: str
    description: str
    tag: int | None
    section: SectionKind = "round"
    goal_kinds: tuple[GoalKind, ...] = GOAL_KINDS
    goal_weights: tuple[float, ...] = GOAL_WEIGHTS
    mass_range_kg: tuple[float, float] = (20.0, 110.0)
    ring_probability: float = 0.5
    ring_spacing_m: tuple[float, float] = (1.0, 1.5)
    stringers: tuple[int, int] | None = None
    ducts: tuple[int, int] = (0, 4)
    brackets: tuple[int, int] = (0, 7)
    far_probability: float = 0.5
    hatch_probability: float = 0.5
    goal_solutions: int = 8
    max_attempts: int = 200

    def __post_init__(self) -> None:
        if len(self.goal_kinds) != len(self.goal_weights):
            raise ValueError(f"family {self.name}: one weight per goal kind")


_FAMILIES: tuple[Family, ...] = (
    Family(
        "mixed",
        "every goal kind; round shells, ring frames every 0.45-0.75 m (60%) or plain; 20-120 kg",
        None,
        mass_range_kg=(20.0, 120.0),
        ring_probability=0.6,
        ring_spacing_m=(0.45, 0.75),
        goal_solutions=3,
        max_attempts=60,
    ),
    Family(
        "ring-frame",
        "round shells with ring frames every 1.0-1.5 m and a rack bay in the side wall",
        1,
        goal_kinds=("bay-side",),
        goal_weights=(1.0,),
        ring_probability=1.0,
    ),
    Family("octagonal", "octagonal shells, every goal kind", 2, section="octagon"),
    Family("box-section", "box-section shells with chamfered corners, every goal kind", 3, section="box"),
    Family(
        "stringer", "round shells with 10-20 longitudinal stringers, every goal kind", 4, stringers=(10, 21)
    ),
    Family(
        "end-bay",
        "bays recessed into the far or near end wall",
        5,
        goal_kinds=("bay-end-far", "bay-end-near"),
        goal_weights=(0.5, 0.5),
    ),
    Family(
        "cluttered",
        "1-3 ducts and 3-6 brackets drawn, a bulkhead hatch between a far start and the goal",
        6,
        goal_kinds=("bay-side", "shelf", "drive"),
        goal_weights=(0.5, 0.25, 0.25),
        ducts=(1, 4),
        brackets=(3, 7),
        far_probability=1.0,
        hatch_probability=1.0,
    ),
)

#: The families by name, in listing order.
FAMILIES: dict[str, Family] = {f.name: f for f in _FAMILIES}
#: The families nobody tuned for (every family but ``mixed``).
NEW_FAMILIES: tuple[str, ...] = tuple(f.name for f in _FAMILIES if f.tag is not None)

__all__ = ["FAMILIES", "GOAL_KINDS", "GOAL_WEIGHTS", "NEW_FAMILIES", "Family", "GoalKind"]
