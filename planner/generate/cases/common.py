"""The state of one draw, and what every goal kind shares: the payload, the section, the redraw signal."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.core.types import Array
from planner.generate.families import Family
from planner.generate.options import PAYLOAD_BOXES_M, SHELL_DIAMETERS_M, Generated
from planner.generate.sections import RoundSection, Section, box_section, octagon, shell_over
from planner.meshes.generate import Shell
from planner.robots.cabin8 import Cabin8

G = TypeVar("G", bound=Generated)

#: The carriage box corners in the cross-section (x, y) [m] (``planner/meshes/README.md``).
CARRIAGE_CORNERS = np.array([[0.85, -0.12], [0.85, 0.0], [-0.85, -0.12], [-0.85, 0.0]])


class Redraw(Exception):
    """A draw that does not make a valid case (or campaign, or unit); the caller draws again."""


def first_valid(draw: Callable[[], G], attempts: int, what: str) -> G:
    """The first of ``attempts`` draws that is not redrawn, its ``meta["redraws"]`` the reasons counted.

    Raises:
        RuntimeError: every draw raised :class:`Redraw` (``what`` and the reasons named).
    """
    reasons: dict[str, int] = {}
    for _ in range(attempts):
        try:
            case = draw()
        except Redraw as exc:
            reasons[str(exc)] = reasons.get(str(exc), 0) + 1
            continue
        case.meta["redraws"] = reasons
        return case
    raise RuntimeError(f"{what}: no valid draw in {attempts} ({reasons})")


@dataclass
class Draw:
    """The state of one draw of a case (mutable while it is built)."""

    rng: np.random.Generator
    robot: Cabin8
    payload: PayloadGeometry
    size: tuple[float, float, float]
    kind: str
    section: Section
    meta: dict[str, Any] = field(default_factory=dict)
    goal_solutions: int = 3


@dataclass
class Goal:
    """Where the payload goes and what the cabin holds for it (filled by the goal kind's module).

    Attributes:
        pose: ``T_base_payload`` at the goal (4, 4), ``None`` for a drive goal.
        direction: Insertion direction (3,) of a bay (the approach line runs along it), else ``None``.
        distance: Approach distance [m].
        solutions: Exact goal configurations (8,) found while placing it.
        bay_boxes: The bay's panels (lo, hi) [m].
        plates: Shelf plates (lo, hi) [m].
        keep_out: Boxes (lo, hi) no clutter may enter (the bay and its approach corridor, the shelf).
        end_opening: ``(which end, wall z, (x0, x1, y0, y1))`` of an end wall with the bay's opening.
    """

    pose: Array | None = None
    direction: Array | None = None
    distance: float = 0.0
    solutions: list[Array] = field(default_factory=list)
    bay_boxes: list[tuple[Array, Array]] = field(default_factory=list)
    plates: list[tuple[tuple[float, ...], tuple[float, ...]]] = field(default_factory=list)
    keep_out: list[tuple[Array, Array]] = field(default_factory=list)
    end_opening: tuple[str, float, tuple[float, float, float, float]] | None = None


def clutter_ok(lo: Array, hi: Array, keep_out: list[tuple[Array, Array]]) -> bool:
    """Whether the box (lo, hi) is apart from every keep-out box."""
    return all(np.any(hi <= k_lo) or np.any(lo >= k_hi) for k_lo, k_hi in keep_out)


def draw_payload(
    rng: np.random.Generator, mass_range_kg: tuple[float, float]
) -> tuple[tuple[float, float, float], PayloadGeometry, dict[str, Any]]:
    """A payload box, its mass and a grasp 30-80 mm in front of the tool, up to 30 mm off-axis."""
    size = PAYLOAD_BOXES_M[int(rng.integers(len(PAYLOAD_BOXES_M)))]
    mass = float(np.round(rng.uniform(*mass_range_kg), 1))
    grasp = np.round(
        [rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), size[2] / 2 + rng.uniform(0.03, 0.08)], 4
    )
    T = np.eye(4)
    T[:3, 3] = grasp
    payload = PayloadGeometry(size=size, source="box", T_tool_payload=T, mass=mass)
    return size, payload, {"payload_box_m": list(size), "mass_kg": mass, "grasp_m": grasp.tolist()}


def draw_section(rng: np.random.Generator, family: Family, z_min: float, z_max: float) -> Section:
    """The shell's cross-section of the family, over z in [z_min, z_max] [m].

    Round: inner diameter 2.4-3.0 m; octagon: 2.4-3.0 m across the flats; box: 2.3-2.9 m wide, floor
    0.42-0.60 m below the rail, ceiling 1.75-2.15 m above it, corners chamfered 0.20-0.40 m. Each leaves the
    carriage more than 80 mm along the whole rail.
    """
    if family.section == "round":
        diameter = SHELL_DIAMETERS_M[int(rng.integers(len(SHELL_DIAMETERS_M)))]
        return RoundSection(shell_over(Shell(inner_radius_m=diameter / 2), z_min, z_max))
    shell = shell_over(Shell(), z_min, z_max)
    if family.section == "octagon":
        return octagon(shell, SHELL_DIAMETERS_M[int(rng.integers(len(SHELL_DIAMETERS_M)))] / 2)
    half, floor, ceiling, chamfer = (
        float(np.round(rng.uniform(lo, hi), 3))
        for lo, hi in ((1.15, 1.45), (-0.60, -0.42), (1.75, 2.15), (0.20, 0.40))
    )
    return box_section(shell, half, floor, ceiling, chamfer)


def ring_depth_max(section: Section) -> float:
    """Deepest ring frame that leaves the carriage 30 mm (its corners' depth inside the wall)."""
    return float(section.wall_distance(CARRIAGE_CORNERS).min() - 0.03)


def box_corners_xy(box_: tuple[Array, Array]) -> Array:
    """The four (x, y) corners (4, 2) of a box's cross-section."""
    lo, hi = box_
    return np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])], dtype=float)


def keep_clear(
    section: Section, lo: Array, hi: Array, keep_out: list[tuple[Array, Array]], depth: float
) -> bool:
    """Whether a band ``depth`` deep at the wall (bounding box lo, hi) keeps out of every keep-out box.

    A keep-out box that the band's z range overlaps must lie wholly inside the band (20 mm to spare).
    """
    return all(clutter_ok(lo, hi, [k]) or section.inside(box_corners_xy(k), depth, 0.02) for k in keep_out)


__all__ = [
    "CARRIAGE_CORNERS",
    "Draw",
    "Goal",
    "Redraw",
    "box_corners_xy",
    "clutter_ok",
    "draw_payload",
    "draw_section",
    "first_valid",
    "keep_clear",
    "ring_depth_max",
]
