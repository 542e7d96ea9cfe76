"""Cabin geometry of generated cases: what a cabin is made of, and its closed pieces in the base frame.

A :class:`CabinLayout` is pure data (a section, ring frames, stringers, a bay's panels, shelf plates, an end
wall with the bay's opening, a bulkhead hatch, ducts, brackets); :func:`cabin_parts` turns it into closed,
outward-wound pieces (:class:`~planner.meshes.generate.Part`) in a fixed order, which
:func:`cabin_mesh` merges into one triangle soup. Pieces may overlap where they join (a collision checker
only sees the union of the triangles), exactly as in the reference cabins (``planner/meshes/README.md``).

Frame: the robot base frame (z along the cabin axis and the rail, y up, x lateral); metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import trimesh

from planner.core.types import Array
from planner.generate.sections import PolygonSection, RoundSection, Section
from planner.meshes.generate import (
    Bracket,
    Bulkhead,
    Duct,
    OpeningStep,
    Part,
    Shell,
    box,
    bracket_box,
    bulkhead,
    deck,
    duct,
    end_walls,
    merge,
    prism,
    tube,
    wall_tube,
)

#: Panel thickness of generated bays and shelves [m].
PANEL_M = 0.02

Box = tuple[tuple[float, ...], tuple[float, ...]]


@dataclass(frozen=True)
class RingFrame:
    """A ring frame (stiffener) inside the shell: a band ``depth_m`` deep over z in [z_m, z_m + t]."""

    z_m: float
    thickness_m: float
    depth_m: float


@dataclass(frozen=True)
class Stringer:
    """A longitudinal stiffener on the inner wall, towards ``angle_rad`` from the axis (0: +x, pi/2: up).

    Its cross-section is ``width_m`` along the wall and ``height_m`` deep into the cabin (embedded 10 mm
    into the wall); it runs over z in [z_min_m, z_max_m].
    """

    angle_rad: float
    width_m: float
    height_m: float
    z_min_m: float
    z_max_m: float


@dataclass(frozen=True)
class BayLayout:
    """A bay built around the payload's goal pose.

    Attributes:
        kind: ``bay-side``, ``bay-end-far`` or ``bay-end-near``.
        free_m: Free space to the cavity walls (x-, x+, y-, y+, back) in the payload frame [m].
        recess_m: How far the payload's front face sits behind the opening [m].
    """

    kind: str
    free_m: tuple[float, float, float, float, float]
    recess_m: float


@dataclass(frozen=True)
class CabinLayout:
    """Everything that defines one generated cabin (base frame, metres)."""

    section: Section
    rings: tuple[RingFrame, ...] = ()
    bay_boxes: tuple[Box, ...] = ()
    end_opening: tuple[str, float, tuple[float, float, float, float]] | None = None
    bulkhead: Bulkhead | None = None
    ducts: tuple[Duct, ...] = ()
    brackets: tuple[Bracket, ...] = ()
    plates: tuple[Box, ...] = ()
    stringers: tuple[Stringer, ...] = ()

    @property
    def shell(self) -> Shell:
        """The shell's z range, wall, axis height and deck."""
        return self.section.shell

    def with_bulkhead(self, spec: Bulkhead) -> CabinLayout:
        """The same cabin with a bulkhead hatch."""
        return replace(self, bulkhead=spec)


def aabb(R: Array, p: Array, lo: Sequence[float] | Array, hi: Sequence[float] | Array) -> tuple[Array, Array]:
    """Base-frame corners of a box given in a frame (R, p) whose R is a signed permutation."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    world = corners @ R.T + p
    return world.min(axis=0), world.max(axis=0)


def _ring_edges(section: Section, ring: RingFrame, sections: int) -> tuple[Array, Array]:
    """The ring's inner and outer edge (M + 1, 2), closed: depth inside the wall to half into it."""
    shell = section.shell
    if isinstance(section, RoundSection):
        theta = 2 * np.pi * np.arange(sections + 1) / sections
        r_in, r_out = shell.inner_radius_m - ring.depth_m, shell.inner_radius_m + shell.wall_m / 2
        c, s = np.cos(theta), np.sin(theta)
        inner = np.column_stack([r_in * c, shell.axis_y_m + r_in * s])
        outer = np.column_stack([r_out * c, shell.axis_y_m + r_out * s])
        return inner, outer
    inner, outer = section.outline(-ring.depth_m), section.outline(shell.wall_m / 2)
    return np.vstack([inner, inner[:1]]), np.vstack([outer, outer[:1]])


def ring_frame(section: Section, ring: RingFrame, sections: int = 64) -> Part:
    """A ring frame from ``depth`` inside the wall to half into it, above the deck, as convex prisms.

    The band is split into quadrilateral sectors (``sections`` for a round shell, the outline's segments
    for a polygonal one), each a convex prism; sectors entirely below the deck are left out (nothing
    reaches there).
    """
    inner, outer = _ring_edges(section, ring, sections)
    pieces = []
    for j in range(len(inner) - 1):
        quad = np.array([inner[j], outer[j], outer[j + 1], inner[j + 1]])
        if quad[:, 1].max() < section.shell.deck_top_y_m:
            continue
        pieces.append(prism(f"ring_{j}", quad, ring.z_m, ring.z_m + ring.thickness_m))
    return merge("ring_frame", pieces)


def stringer_part(i: int, section: Section, s: Stringer) -> Part:
    """A stringer as a convex prism: a rectangle on the wall's normal, 10 mm into the wall."""
    p, n = section.wall_point(s.angle_rad)
    t = np.array([-n[1], n[0]])
    quad = np.array(
        [
            p + 0.010 * n - t * s.width_m / 2,
            p + 0.010 * n + t * s.width_m / 2,
            p - s.height_m * n + t * s.width_m / 2,
            p - s.height_m * n - t * s.width_m / 2,
        ]
    )
    a = quad[:, 0] * np.roll(quad[:, 1], -1) - np.roll(quad[:, 0], -1) * quad[:, 1]
    if a.sum() < 0:
        quad = quad[::-1]
    return prism(f"stringer_{i}", quad, s.z_min_m, s.z_max_m)


def stringer_box(section: Section, s: Stringer) -> tuple[Array, Array]:
    """Corners (lo, hi) of a stringer's bounding box [m]."""
    p, n = section.wall_point(s.angle_rad)
    reach = np.abs(np.array([-n[1], n[0]])) * s.width_m / 2 + np.abs(n) * max(s.height_m, 0.010)
    return np.append(p - reach, s.z_min_m), np.append(p + reach, s.z_max_m)


def bracket_bounds(
    section: Section, b: Bracket
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Corners (lo, hi) of a bracket's box on the section's wall [m]."""
    return bracket_box(section.half_width_at(b.y_center_m), b)


def bay_boxes(
    T_base_payload: Array, size: Sequence[float], bay: BayLayout
) -> tuple[list[tuple[Array, Array]], tuple[Array, Array], tuple[float, float, float, float, float]]:
    """Panels of a bay around a payload at its goal pose (axis-aligned R), as base-frame boxes.

    In the payload frame the cavity is x in [-bx/2 - f0, bx/2 + f1], y in [-by/2 - f2, by/2 + f3],
    z from the opening ``-bz/2 - recess`` to the back ``bz/2 + f4``; the opening faces -z (the approach
    comes from there). Five panels close it, and a face plate 60 mm wide frames the opening.

    Returns:
        The boxes (lo, hi), the cavity's own box (lo, hi) and the cavity bounds in the payload frame
        (x0, x1, y0, y1, z_open) for the end wall's opening.
    """
    R, p = T_base_payload[:3, :3], T_base_payload[:3, 3]
    bx, by, bz = size
    f = bay.free_m
    x0, x1, y0, y1 = -bx / 2 - f[0], bx / 2 + f[1], -by / 2 - f[2], by / 2 + f[3]
    z0, z1 = -bz / 2 - bay.recess_m, bz / 2 + f[4]
    t, m = PANEL_M, 0.06
    local = [
        ((x0 - t, y0 - t, z1), (x1 + t, y1 + t, z1 + t)),  # back
        ((x0 - t, y0 - t, z0), (x1 + t, y0, z1)),  # bottom
        ((x0 - t, y1, z0), (x1 + t, y1 + t, z1)),  # top
        ((x0 - t, y0, z0), (x0, y1, z1)),  # side x-
        ((x1, y0, z0), (x1 + t, y1, z1)),  # side x+
    ]
    if bay.kind == "bay-side":
        local += [  # the face plate around the opening
            ((x0 - t - m, y0 - t - m, z0 - t), (x1 + t + m, y0, z0)),
            ((x0 - t - m, y1, z0 - t), (x1 + t + m, y1 + t + m, z0)),
            ((x0 - t - m, y0, z0 - t), (x0, y1, z0)),
            ((x1, y0, z0 - t), (x1 + t + m, y1, z0)),
        ]
    boxes = [aabb(R, p, lo, hi) for lo, hi in local]
    cavity = aabb(R, p, (x0, y0, z0), (x1, y1, z1))
    return boxes, cavity, (x0, x1, y0, y1, z0)


def _walls(section: Section) -> list[Part]:
    """The shell wall, the deck and both end walls of a section."""
    shell = section.shell
    if isinstance(section, RoundSection):
        return [tube(shell), deck(shell)] + end_walls(shell)
    assert isinstance(section, PolygonSection)
    zs = np.linspace(shell.z_min_m, shell.z_max_m, shell.z_segments + 1)
    half = section.half_width_at(shell.deck_top_y_m) + shell.wall_m / 2
    rim = section.rim(shell.wall_m / 2)
    return [
        wall_tube("shell", section.outline(0.0), section.outline(shell.wall_m), zs),
        box(
            "deck",
            (-half, shell.deck_top_y_m - shell.deck_m, shell.z_min_m),
            (half, shell.deck_top_y_m, shell.z_max_m),
        ),
        prism("end_wall_min", rim, shell.z_min_m, shell.z_min_m + shell.wall_m),
        prism("end_wall_max", rim, shell.z_max_m - shell.wall_m, shell.z_max_m),
    ]


def _bulkhead(section: Section, spec: Bulkhead) -> Part:
    if isinstance(section, RoundSection):
        return bulkhead(section.shell, spec)
    return bulkhead(section.shell, spec, outline=section.rim(section.shell.wall_m / 2))


def cabin_parts(layout: CabinLayout) -> list[Part]:
    """The cabin's closed pieces in a fixed order (shell, deck, end walls, rings, bay, clutter)."""
    section, shell = layout.section, layout.shell
    walls = _walls(section)
    parts, ends = walls[:2], walls[2:]
    if layout.end_opening is not None:
        # The bay's end wall: a wall across the cabin with the bay's opening, the cavity behind it.
        which, z_m, (x0, x1, y0, y1) = layout.end_opening
        step = OpeningStep("bay", x0, x1, y0, y1)
        parts.append(_bulkhead(section, Bulkhead(z_m=z_m, thickness_m=shell.wall_m, steps=(step,))))
        parts += [w for w in ends if (w.name == "end_wall_min") == (which == "far")]
    else:
        parts += ends
    parts += [ring_frame(section, r) for r in layout.rings]
    parts += [box(f"bay_{i}", lo, hi) for i, (lo, hi) in enumerate(layout.bay_boxes)]
    parts += [box(f"plate_{i}", lo, hi) for i, (lo, hi) in enumerate(layout.plates)]
    if layout.bulkhead is not None:
        parts.append(_bulkhead(section, layout.bulkhead))
    parts += [duct(i, d) for i, d in enumerate(layout.ducts)]
    parts += [box(f"bracket_{i}", *bracket_bounds(section, b)) for i, b in enumerate(layout.brackets)]
    parts += [stringer_part(i, section, s) for i, s in enumerate(layout.stringers)]
    return parts


def cabin_mesh(layout: CabinLayout) -> trimesh.Trimesh:
    """The assembled cabin as one triangle soup in the base frame (no processing)."""
    whole = merge("cabin", cabin_parts(layout))
    return trimesh.Trimesh(whole.vertices, whole.faces, process=False)


__all__ = [
    "PANEL_M",
    "BayLayout",
    "CabinLayout",
    "RingFrame",
    "Stringer",
    "aabb",
    "bay_boxes",
    "bracket_bounds",
    "cabin_mesh",
    "cabin_parts",
    "merge",
    "ring_frame",
    "stringer_box",
    "stringer_part",
]
