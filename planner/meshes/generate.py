"""Generate the reference cabins: binary STL meshes (one also as GLB) and the ``cabins.json`` manifest.

Run ``python -m planner.meshes.generate`` (writes into the package folder, ``planner/meshes/``);
``--out DIR`` writes somewhere else. The output is deterministic: the same parameters give the same bytes.

Frame (the cabin frame equals the robot base frame): z along the cabin axis (the rail runs along the
floor at y = 0 from z = 0 to 6 m), y up, x lateral. Every length is in metres.

The parameters of each cabin are one :class:`CabinSpec` instance at the top of this file (``AISLE``,
``HATCH``, ``CLUTTERED``, ``TIGHTBAY``); tune them there and regenerate. ``planner/meshes/README.md``
documents the resulting geometry.

Geometry is built from closed, outward-wound pieces (boxes, convex prisms, a thick cylindrical tube,
cylinders) that may overlap where they join; a collision checker only sees the union of the triangles.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

_LOG = logging.getLogger(__name__)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Reference payload (tool x, tool y, tool z = insertion direction) [m]; in a bay it sits with its
#: 0.45 side along the cabin axis z, its 0.35 side vertical (y) and its 0.50 side along the bay depth (x).
PAYLOAD_SIZE_M: tuple[float, float, float] = (0.45, 0.35, 0.50)
#: The robot's carriage box (x, y, z sizes) and its centre at rail travel d1: (0, -0.06, d1) [m].
CARRIAGE_SIZE_M: tuple[float, float, float] = (1.70, 0.12, 0.40)
CARRIAGE_CENTER_Y_M = -0.06
RAIL_Z_RANGE_M: tuple[float, float] = (0.0, 6.0)


# ------------------------------------------------------------------------------------------ parameters


@dataclass(frozen=True)
class Shell:
    """Thick cylindrical fuselage shell with a flat floor deck (and optional end walls).

    Attributes:
        inner_radius_m: Inner radius of the shell (inner diameter 2 r).
        wall_m: Wall thickness (outer radius = inner + wall).
        axis_y_m: Height of the cylinder axis (the axis is parallel to z at x = 0).
        z_min_m: Start of the cabin section along z.
        z_max_m: End of the cabin section along z.
        sections: Segments around the circumference.
        z_segments: Segments along z (keeps triangles short for the collision BVH).
        end_walls: Close both ends with flat walls of thickness ``wall_m`` inside [z_min, z_max].
        deck_top_y_m: Height of the floor deck's top surface.
        deck_m: Deck thickness.
    """

    inner_radius_m: float = 1.20
    wall_m: float = 0.04
    axis_y_m: float = 0.60
    z_min_m: float = -0.50
    z_max_m: float = 6.50
    sections: int = 128
    z_segments: int = 14
    end_walls: bool = True
    deck_top_y_m: float = -0.16
    deck_m: float = 0.04

    def half_width_at(self, y_m: float) -> float:
        """Half-width of the free cross-section (inner surface) at height ``y_m`` [m]."""
        dy = y_m - self.axis_y_m
        return math.sqrt(max(self.inner_radius_m**2 - dy**2, 0.0))


@dataclass(frozen=True)
class Bay:
    """One bay: an open box behind a rectangular opening in the rack face, open towards -x.

    Attributes:
        id: Name of the bay (unique in its cabin).
        z_center_m: Centre of the opening along the cabin axis.
        y_center_m: Centre of the opening's height.
        width_m: Opening (and cavity) size along z.
        height_m: Opening (and cavity) size along y.
    """

    id: str
    z_center_m: float
    y_center_m: float
    width_m: float = 0.55
    height_m: float = 0.45


@dataclass(frozen=True)
class Rack:
    """Wall-mounted rack on the +x side: a face plate at x = ``front_x_m`` with one opening per bay.

    The plate occupies x in [front_x - panel, front_x]; each cavity spans x in [front_x, front_x + depth]
    with panels of thickness ``panel_m`` on its five closed sides. The plate extends ``margin_m`` beyond
    the outermost panels.
    """

    front_x_m: float = 0.60
    depth_m: float = 0.57
    panel_m: float = 0.02
    margin_m: float = 0.05
    bays: tuple[Bay, ...] = ()


@dataclass(frozen=True)
class OpeningStep:
    """One rectangle of a stepped bulkhead opening: x in [x_min, x_max], y in [y_min, y_max] [m]."""

    name: str
    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    clears: str = ""


@dataclass(frozen=True)
class Bulkhead:
    """A wall across the cabin at z in [z_m, z_m + thickness_m] with a stepped opening.

    ``steps`` are stacked bottom to top and must touch (each ``y_min`` equals the previous ``y_max``).
    """

    z_m: float
    thickness_m: float
    steps: tuple[OpeningStep, ...]


@dataclass(frozen=True)
class Duct:
    """A closed cylinder along z (an overhead duct) centred at (x_m, y_m)."""

    x_m: float
    y_m: float
    radius_m: float
    z_min_m: float
    z_max_m: float
    sections: int = 48


@dataclass(frozen=True)
class Bracket:
    """A box fixed to the shell wall on side ``side`` (+1: +x wall, -1: -x wall).

    It protrudes ``protrusion_m`` from the inner wall surface (measured at ``y_center_m``) and is
    embedded ``embed_m`` into the wall; ``height_m`` along y, ``length_m`` along z.
    """

    side: int
    y_center_m: float
    z_center_m: float
    protrusion_m: float
    height_m: float
    length_m: float
    embed_m: float = 0.04


@dataclass(frozen=True)
class CabinSpec:
    """Everything that defines one reference cabin."""

    name: str
    description: str
    shell: Shell = field(default_factory=Shell)
    rack: Rack | None = None
    bulkhead: Bulkhead | None = None
    ducts: tuple[Duct, ...] = ()
    brackets: tuple[Bracket, ...] = ()
    write_glb: bool = False


_BAY_Y = 0.675  # opening centre height of the standard bays: opening y in [0.45, 0.90]

AISLE = CabinSpec(
    name="cabin-aisle",
    description="Cylindrical aisle cabin with a six-bay rack on the +x wall (openings 0.55 x 0.45 m).",
    rack=Rack(bays=tuple(Bay(f"A{i + 1}", z_center_m=1.5 + 0.6 * i, y_center_m=_BAY_Y) for i in range(6))),
)

HATCH = CabinSpec(
    name="cabin-hatch",
    description=(
        "Aisle cabin split by a bulkhead at z = 2.0 m with a stepped (three-level) opening just larger "
        "than the carriage, the parallel stage and the tucked arm with payload; two bays beyond it."
    ),
    rack=Rack(
        bays=(Bay("H1", z_center_m=3.6, y_center_m=_BAY_Y), Bay("H2", z_center_m=4.2, y_center_m=_BAY_Y))
    ),
    bulkhead=Bulkhead(
        z_m=2.0,
        thickness_m=0.05,
        steps=(
            OpeningStep("carriage", -0.90, 0.90, -0.16, 0.08, "carriage |x| <= 0.85, y in [-0.12, 0]"),
            OpeningStep("stage", -0.60, 0.60, 0.08, 0.40, "sliders |x| <= 0.50 and links, tucked posture"),
            OpeningStep("arm", -0.28, 0.28, 0.40, 1.00, "tucked payload |x| <= 0.175, y in [0.33, 0.89]"),
        ),
    ),
    write_glb=True,
)

CLUTTERED = CabinSpec(
    name="cabin-cluttered",
    description="Aisle cabin with four ducts (three overhead) and eleven wall brackets around a 3-bay rack.",
    rack=Rack(bays=tuple(Bay(f"C{i + 1}", z_center_m=2.4 + 0.6 * i, y_center_m=_BAY_Y) for i in range(3))),
    ducts=(
        Duct(x_m=-0.55, y_m=1.45, radius_m=0.12, z_min_m=-0.46, z_max_m=6.46),
        Duct(x_m=0.00, y_m=1.62, radius_m=0.10, z_min_m=-0.46, z_max_m=6.46),
        Duct(x_m=0.60, y_m=1.42, radius_m=0.12, z_min_m=-0.46, z_max_m=6.46),
        Duct(x_m=-0.95, y_m=0.35, radius_m=0.08, z_min_m=-0.46, z_max_m=6.46),
    ),
    brackets=(
        Bracket(side=+1, y_center_m=1.04, z_center_m=3.0, protrusion_m=0.25, height_m=0.08, length_m=0.30),
        Bracket(side=+1, y_center_m=1.15, z_center_m=1.2, protrusion_m=0.15, height_m=0.08, length_m=0.25),
        Bracket(side=+1, y_center_m=1.15, z_center_m=4.8, protrusion_m=0.15, height_m=0.08, length_m=0.25),
        Bracket(side=+1, y_center_m=0.30, z_center_m=1.2, protrusion_m=0.12, height_m=0.10, length_m=0.20),
        Bracket(side=+1, y_center_m=0.30, z_center_m=4.8, protrusion_m=0.12, height_m=0.10, length_m=0.20),
        Bracket(side=+1, y_center_m=0.675, z_center_m=1.6, protrusion_m=0.20, height_m=0.12, length_m=0.15),
        Bracket(side=-1, y_center_m=0.90, z_center_m=0.8, protrusion_m=0.20, height_m=0.10, length_m=0.25),
        Bracket(side=-1, y_center_m=0.90, z_center_m=2.3, protrusion_m=0.20, height_m=0.10, length_m=0.25),
        Bracket(side=-1, y_center_m=0.90, z_center_m=3.8, protrusion_m=0.20, height_m=0.10, length_m=0.25),
        Bracket(side=-1, y_center_m=0.90, z_center_m=5.3, protrusion_m=0.20, height_m=0.10, length_m=0.25),
        Bracket(side=-1, y_center_m=1.30, z_center_m=3.0, protrusion_m=0.15, height_m=0.08, length_m=0.40),
    ),
)

_TIGHT_CLEARANCE_M = 0.0125  # per side, for the 0.45 x 0.35 payload cross-section
TIGHTBAY = CabinSpec(
    name="cabin-tightbay",
    description=(
        "Aisle cabin with a tight bay (12.5 mm clearance per side for the 0.45 x 0.35 m payload "
        "cross-section) next to a standard bay for comparison."
    ),
    rack=Rack(
        bays=(
            Bay(
                "T1",
                z_center_m=3.0,
                y_center_m=_BAY_Y,
                width_m=PAYLOAD_SIZE_M[0] + 2 * _TIGHT_CLEARANCE_M,
                height_m=PAYLOAD_SIZE_M[1] + 2 * _TIGHT_CLEARANCE_M,
            ),
            Bay("T2", z_center_m=3.8, y_center_m=_BAY_Y),
        )
    ),
)

CABINS: tuple[CabinSpec, ...] = (AISLE, HATCH, CLUTTERED, TIGHTBAY)


# ------------------------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class Part:
    """One named closed piece of a cabin: vertices (V, 3) [m] and outward-wound faces (F, 3)."""

    name: str
    vertices: Array
    faces: IntArray


def merge(name: str, parts: Sequence[Part]) -> Part:
    """One part of several (vertices stacked, faces re-indexed)."""
    vertices, faces, offset = [], [], 0
    for part in parts:
        vertices.append(part.vertices)
        faces.append(part.faces + offset)
        offset += len(part.vertices)
    return Part(name, np.concatenate(vertices), np.concatenate(faces).astype(np.int64))


def box(name: str, lo: Sequence[float], hi: Sequence[float]) -> Part:
    """Axis-aligned box between corners ``lo`` and ``hi`` [m] (trimesh primitive, 12 triangles)."""
    lo_a, hi_a = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if np.any(hi_a - lo_a <= 0):
        raise ValueError(f"box {name}: empty extent {lo_a} .. {hi_a}")
    mesh = trimesh.creation.box(bounds=np.array([lo_a, hi_a]))
    return Part(name, np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64))


def prism(name: str, polygon_xy: Array, z0: float, z1: float) -> Part:
    """Extrude a convex counter-clockwise polygon (N, 2) from z0 to z1 (fan-triangulated caps)."""
    n = len(polygon_xy)
    bottom = np.column_stack([polygon_xy, np.full(n, z0)])
    top = np.column_stack([polygon_xy, np.full(n, z1)])
    vertices = np.vstack([bottom, top])
    faces = []
    for i in range(1, n - 1):
        faces.append((n, n + i, n + i + 1))  # top, normal +z
        faces.append((0, i + 1, i))  # bottom, normal -z
    for i in range(n):
        j = (i + 1) % n
        faces.append((i, j, n + j))
        faces.append((i, n + j, n + i))
    return Part(name, vertices, np.array(faces, dtype=np.int64))


def tube(shell: Shell) -> Part:
    """Closed thick cylindrical shell (inner + outer surface + end rings), axis along z at y = axis_y."""
    inner = _circle(shell, shell.inner_radius_m)
    outer = _circle(shell, shell.inner_radius_m + shell.wall_m)
    return wall_tube("shell", inner, outer, np.linspace(shell.z_min_m, shell.z_max_m, shell.z_segments + 1))


def wall_tube(name: str, inner_xy: Array, outer_xy: Array, zs: Array) -> Part:
    """Closed thick wall between two closed cross-section outlines, extruded along z.

    Args:
        name: The part's name.
        inner_xy: The inner surface's outline (M, 2), counter-clockwise seen from +z.
        outer_xy: The outer surface's outline (M, 2): point j faces inner point j.
        zs: The stations along z (K + 1,), increasing; the surfaces are split there (short triangles keep
            the collision BVH tight).

    Returns:
        Inner and outer surfaces and the two end rings, outward-wound.
    """
    m, k = len(inner_xy), len(zs) - 1
    rings = [np.array([[xy[j, 0], xy[j, 1], z] for z in zs for j in range(m)]) for xy in (inner_xy, outer_xy)]
    vertices = np.vstack(rings)
    outer0 = m * (k + 1)

    def idx(surface: int, ring: int, j: int) -> int:
        return surface * outer0 + ring * m + (j % m)

    faces = []
    for ring in range(k):
        for j in range(m):
            a, b = idx(1, ring, j), idx(1, ring, j + 1)
            c, d = idx(1, ring + 1, j + 1), idx(1, ring + 1, j)
            faces += [(a, b, c), (a, c, d)]  # outer surface, normal away from the axis
            a, b = idx(0, ring, j), idx(0, ring, j + 1)
            c, d = idx(0, ring + 1, j + 1), idx(0, ring + 1, j)
            faces += [(a, c, b), (a, d, c)]  # inner surface, normal towards the axis
    for j in range(m):
        i0, i1, o0, o1 = idx(0, 0, j), idx(0, 0, j + 1), idx(1, 0, j), idx(1, 0, j + 1)
        faces += [(i0, o1, o0), (i0, i1, o1)]  # ring at z_min, normal -z
        i0, i1, o0, o1 = idx(0, k, j), idx(0, k, j + 1), idx(1, k, j), idx(1, k, j + 1)
        faces += [(i0, o0, o1), (i0, o1, i1)]  # ring at z_max, normal +z
    return Part(name, vertices, np.array(faces, dtype=np.int64))


def _circle(shell: Shell, radius: float) -> Array:
    theta = 2 * np.pi * np.arange(shell.sections) / shell.sections
    return np.column_stack([radius * np.cos(theta), shell.axis_y_m + radius * np.sin(theta)])


def _clip(polygon: Array, normal: tuple[float, float], offset: float) -> Array:
    """Sutherland-Hodgman: keep the part of a convex polygon where ``normal . p <= offset``."""
    out: list[Array] = []
    n = np.asarray(normal, dtype=float)
    for i in range(len(polygon)):
        p, q = polygon[i], polygon[(i + 1) % len(polygon)]
        dp, dq = float(n @ p) - offset, float(n @ q) - offset
        if dp <= 0:
            out.append(p)
        if dp * dq < 0:
            out.append(p + (q - p) * (dp / (dp - dq)))
    return np.array(out).reshape(-1, 2)


def _disk_piece(outline: Array, x_range: tuple[float, float], y_range: tuple[float, float]) -> Array:
    """The part of a convex outline (M, 2) within the x and y ranges (infinite bounds: no cut)."""
    poly = outline
    for normal, offset in (
        ((-1.0, 0.0), -x_range[0]),
        ((1.0, 0.0), x_range[1]),
        ((0.0, -1.0), -y_range[0]),
        ((0.0, 1.0), y_range[1]),
    ):
        if math.isfinite(offset):
            poly = _clip(poly, normal, offset)
    return poly


def end_walls(shell: Shell) -> list[Part]:
    """Flat walls closing the section, inside [z_min, z_max], embedded half-way into the shell wall."""
    disk = _circle(shell, shell.inner_radius_m + shell.wall_m / 2)
    return [
        prism("end_wall_min", disk, shell.z_min_m, shell.z_min_m + shell.wall_m),
        prism("end_wall_max", disk, shell.z_max_m - shell.wall_m, shell.z_max_m),
    ]


def deck(shell: Shell) -> Part:
    """Floor deck plate; its top edges reach into the shell wall so no gap is left at the sides."""
    half = shell.half_width_at(shell.deck_top_y_m) + shell.wall_m / 2
    return box(
        "deck",
        (-half, shell.deck_top_y_m - shell.deck_m, shell.z_min_m),
        (half, shell.deck_top_y_m, shell.z_max_m),
    )


def bulkhead(shell: Shell, spec: Bulkhead, outline: Array | None = None) -> Part:
    """The bulkhead as convex prisms: disk minus the stepped opening, split into horizontal bands.

    Args:
        shell: The shell (its circle, mid-wall, is the disk's edge unless ``outline`` is given).
        spec: Position, thickness and the opening's steps.
        outline: Another convex edge (M, 2), counter-clockwise (a polygonal shell's mid-wall outline).
    """
    disk = _circle(shell, shell.inner_radius_m + shell.wall_m / 2) if outline is None else outline
    inf = math.inf
    steps = spec.steps
    for lower, upper in zip(steps, steps[1:], strict=False):
        if not math.isclose(lower.y_max_m, upper.y_min_m):
            raise ValueError(f"bulkhead steps {lower.name} and {upper.name} do not touch")
    pieces = [
        _disk_piece(disk, (-inf, inf), (-inf, steps[0].y_min_m)),
        _disk_piece(disk, (-inf, inf), (steps[-1].y_max_m, inf)),
    ]
    for step in steps:
        y_range = (step.y_min_m, step.y_max_m)
        pieces.append(_disk_piece(disk, (-inf, step.x_min_m), y_range))
        pieces.append(_disk_piece(disk, (step.x_max_m, inf), y_range))
    parts = [
        prism(f"bulkhead_{i}", p, spec.z_m, spec.z_m + spec.thickness_m)
        for i, p in enumerate(pieces)
        if len(p) >= 3
    ]
    return merge("bulkhead", parts)


def rack(spec: Rack) -> Part:
    """Face plate with one opening per bay, and an open box (five panels) behind each opening."""
    fx, d, p = spec.front_x_m, spec.depth_m, spec.panel_m
    bays = sorted(spec.bays, key=lambda b: b.z_center_m)
    boxes: list[Part] = []
    for bay in bays:
        z0, z1 = bay.z_center_m - bay.width_m / 2, bay.z_center_m + bay.width_m / 2
        y0, y1 = bay.y_center_m - bay.height_m / 2, bay.y_center_m + bay.height_m / 2
        boxes += [
            box("back", (fx + d, y0 - p, z0 - p), (fx + d + p, y1 + p, z1 + p)),
            box("bottom", (fx, y0 - p, z0 - p), (fx + d, y0, z1 + p)),
            box("top", (fx, y1, z0 - p), (fx + d, y1 + p, z1 + p)),
            box("side", (fx, y0, z0 - p), (fx + d, y1, z0)),
            box("side", (fx, y0, z1), (fx + d, y1, z1 + p)),
        ]
    # Face plate x in [fx - p, fx]: columns over each opening (above and below it) and posts between.
    y_lo = min(b.y_center_m - b.height_m / 2 for b in bays) - p - spec.margin_m
    y_hi = max(b.y_center_m + b.height_m / 2 for b in bays) + p + spec.margin_m
    z_edge = bays[0].z_center_m - bays[0].width_m / 2 - p - spec.margin_m
    for bay in bays:
        z0, z1 = bay.z_center_m - bay.width_m / 2, bay.z_center_m + bay.width_m / 2
        if z0 <= z_edge:
            raise ValueError(f"bay {bay.id} overlaps its neighbour along z")
        y0, y1 = bay.y_center_m - bay.height_m / 2, bay.y_center_m + bay.height_m / 2
        boxes.append(box("post", (fx - p, y_lo, z_edge), (fx, y_hi, z0)))
        boxes.append(box("below", (fx - p, y_lo, z0), (fx, y0, z1)))
        boxes.append(box("above", (fx - p, y1, z0), (fx, y_hi, z1)))
        z_edge = z1
    boxes.append(box("post", (fx - p, y_lo, z_edge), (fx, y_hi, z_edge + p + spec.margin_m)))
    return merge("rack", boxes)


def duct(i: int, spec: Duct) -> Part:
    """Closed cylinder along z (trimesh primitive)."""
    length = spec.z_max_m - spec.z_min_m
    transform = np.eye(4)
    transform[:3, 3] = (spec.x_m, spec.y_m, (spec.z_min_m + spec.z_max_m) / 2)
    mesh = trimesh.creation.cylinder(
        radius=spec.radius_m, height=length, sections=spec.sections, transform=transform
    )
    return Part(f"duct_{i}", np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64))


def bracket_bounds(
    shell: Shell, spec: Bracket
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Corners (lo, hi) of a bracket's box [m]."""
    return bracket_box(shell.half_width_at(spec.y_center_m), spec)


def bracket_box(
    wall_x_m: float, spec: Bracket
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Corners (lo, hi) of a bracket's box [m] on a wall whose inner surface is at |x| = ``wall_x_m``."""
    inner, outer = wall_x_m - spec.protrusion_m, wall_x_m + spec.embed_m
    x0, x1 = (inner, outer) if spec.side > 0 else (-outer, -inner)
    y0, y1 = spec.y_center_m - spec.height_m / 2, spec.y_center_m + spec.height_m / 2
    z0, z1 = spec.z_center_m - spec.length_m / 2, spec.z_center_m + spec.length_m / 2
    return (x0, y0, z0), (x1, y1, z1)


def build(spec: CabinSpec) -> list[Part]:
    """All parts of one cabin, in a fixed order."""
    shell = spec.shell
    parts = [tube(shell), deck(shell)]
    if shell.end_walls:
        parts += end_walls(shell)
    if spec.bulkhead is not None:
        parts.append(bulkhead(shell, spec.bulkhead))
    if spec.rack is not None:
        parts.append(rack(spec.rack))
    parts += [duct(i, d) for i, d in enumerate(spec.ducts)]
    parts += [box(f"bracket_{i}", *bracket_bounds(shell, b)) for i, b in enumerate(spec.brackets)]
    return parts


# ------------------------------------------------------------------------------------------------ I/O


def binary_stl_bytes(vertices: Array, faces: IntArray, header: str) -> bytes:
    """Binary STL (little-endian float32): 80-byte header, uint32 count, 50 bytes per triangle."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    record = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    records = np.zeros(len(faces), dtype=record)
    records["normal"] = normals
    records["corners"] = tri
    head = header.encode("ascii")[:80].ljust(80, b" ")
    return head + np.uint32(len(faces)).tobytes() + records.tobytes()


def glb_bytes(parts: Sequence[Part]) -> bytes:
    """GLB scene with one node per part.

    Each part is stored around its own origin and placed by its node's translation, so loading the file
    exercises the scene-graph transforms.
    """
    scene = trimesh.Scene()
    for part in parts:
        lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
        origin = np.round((lo + hi) / 2, 3)
        mesh = trimesh.Trimesh(part.vertices - origin, part.faces, process=False)
        transform = np.eye(4)
        transform[:3, 3] = origin
        scene.add_geometry(mesh, node_name=part.name, geom_name=part.name, transform=transform)
    data = scene.export(file_type="glb")
    return bytes(data)


def _r(value: float) -> float:
    return round(float(value), 6)


def _vec(values: Sequence[float]) -> list[float]:
    return [_r(v) for v in values]


def describe(spec: CabinSpec, vertices: Array, faces: IntArray) -> dict[str, Any]:
    """Manifest entry: the key dimensions a scenario needs (all in metres, base frame)."""
    shell = spec.shell
    carriage_y = CARRIAGE_CENTER_Y_M - CARRIAGE_SIZE_M[1] / 2
    entry: dict[str, Any] = {
        "name": spec.name,
        "description": spec.description,
        "units": "m",
        "n_faces": len(faces),
        "bounds_m": {"min": _vec(vertices.min(axis=0)), "max": _vec(vertices.max(axis=0))},
        "shell": {
            "inner_radius_m": shell.inner_radius_m,
            "inner_diameter_m": 2 * shell.inner_radius_m,
            "wall_m": shell.wall_m,
            "axis_m": [0.0, shell.axis_y_m],
            "z_range_m": [shell.z_min_m, shell.z_max_m],
            "end_walls": shell.end_walls,
            "ceiling_y_m": _r(shell.axis_y_m + shell.inner_radius_m),
            "deck_top_y_m": shell.deck_top_y_m,
            "deck_half_width_m": _r(shell.half_width_at(shell.deck_top_y_m)),
            "free_width_at_carriage_bottom_m": _r(2 * shell.half_width_at(carriage_y)),
        },
        "bays": [],
        "bulkhead": None,
        "ducts": [],
        "brackets": [],
    }
    if spec.rack is not None:
        rk = spec.rack
        for bay in rk.bays:
            entry["bays"].append(
                {
                    "id": bay.id,
                    "center_m": _vec((rk.front_x_m + rk.depth_m / 2, bay.y_center_m, bay.z_center_m)),
                    "opening_m": {"width_z": _r(bay.width_m), "height_y": _r(bay.height_m)},
                    "depth_m": rk.depth_m,
                    "front_x_m": rk.front_x_m,
                    "insertion_axis": [1.0, 0.0, 0.0],
                    "payload_clearance_per_side_m": {
                        "z": _r((bay.width_m - PAYLOAD_SIZE_M[0]) / 2),
                        "y": _r((bay.height_m - PAYLOAD_SIZE_M[1]) / 2),
                        "x_back": _r(rk.depth_m - PAYLOAD_SIZE_M[2]),
                    },
                }
            )
    if spec.bulkhead is not None:
        bh = spec.bulkhead
        entry["bulkhead"] = {
            "z_range_m": _vec((bh.z_m, bh.z_m + bh.thickness_m)),
            "opening_steps": [
                {
                    "name": s.name,
                    "x_range_m": _vec((s.x_min_m, s.x_max_m)),
                    "y_range_m": _vec((s.y_min_m, s.y_max_m)),
                    "width_m": _r(s.x_max_m - s.x_min_m),
                    "clears": s.clears,
                }
                for s in bh.steps
            ],
        }
    entry["ducts"] = [
        {
            "center_xy_m": _vec((d.x_m, d.y_m)),
            "radius_m": d.radius_m,
            "z_range_m": _vec((d.z_min_m, d.z_max_m)),
        }
        for d in spec.ducts
    ]
    for b in spec.brackets:
        lo, hi = bracket_bounds(shell, b)
        entry["brackets"].append({"min_m": _vec(lo), "max_m": _vec(hi)})
    return entry


def generate(out_dir: Path) -> dict[str, Any]:
    """Write every cabin's files and ``cabins.json`` into ``out_dir``; return the manifest."""
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {
        "format_version": 1,
        "units": "m",
        "frame": (
            "robot base frame: z along the cabin axis (rail at y = 0 from z = 0 to 6 m), y up, x lateral"
        ),
        "generator": "planner/meshes/generate.py",
        "payload_reference_size_m": list(PAYLOAD_SIZE_M),
        "carriage": {
            "size_m": list(CARRIAGE_SIZE_M),
            "center_m": [0.0, CARRIAGE_CENTER_Y_M, "d1"],
            "rail_z_range_m": list(RAIL_Z_RANGE_M),
        },
        "cabins": [],
    }
    for spec in CABINS:
        whole = merge(spec.name, build(spec))
        stl = binary_stl_bytes(whole.vertices, whole.faces, f"cabinplan reference cabin {spec.name} [m]")
        files = {"stl": f"{spec.name}.stl"}
        (out_dir / files["stl"]).write_bytes(stl)
        sha = {"stl": hashlib.sha256(stl).hexdigest()}
        if spec.write_glb:
            glb = glb_bytes(build(spec))
            files["glb"] = f"{spec.name}.glb"
            (out_dir / files["glb"]).write_bytes(glb)
            sha["glb"] = hashlib.sha256(glb).hexdigest()
        entry = describe(spec, whole.vertices, whole.faces)
        entry["files"] = files
        entry["sha256"] = sha
        manifest["cabins"].append(entry)
        _LOG.info("%s: %d faces, %d bytes", spec.name, len(whole.faces), len(stl))
    text = json.dumps(manifest, indent=2) + "\n"
    (out_dir / "cabins.json").write_text(text, encoding="utf-8")
    return manifest


def main(argv: Sequence[str] | None = None) -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent, help="output directory")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    generate(args.out)


if __name__ == "__main__":
    main()
