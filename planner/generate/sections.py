"""Cross-sections of generated shells: the reference cylinder, and convex polygons (octagon, box section).

A section answers the questions the generator asks of a shell wall, whatever its shape: how far the inner
surface is from the cabin axis plane at a height (``half_width_at``), how deep points are inside it
(``wall_distance``), where a ray from the axis meets it (``wall_point``), and its outline offset from the
inner surface (``outline``: the wall's outer surface, a ring frame's inner edge, an end wall's mid-wall
edge). Every outline is counter-clockwise seen from +z and sampled at the same parameters for every offset,
so point j of one outline faces point j of another (the wall and the ring frames are quads between them).

Frame: the cabin (robot base) frame of ``planner/meshes/README.md``: x lateral, y up, z along the axis;
the section is symmetric about x = 0; metres.

:class:`RoundSection` keeps the reference cabins' cylinder and its formulas exactly (the mixed family's
bytes depend on them); :class:`PolygonSection` is a convex polygon given by its inner corners.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from planner.core.types import Array
from planner.meshes.generate import Shell

SectionKind = Literal["round", "octagon", "box"]

#: Longest wall segment of a polygonal section's outline [m] (the 2.4 m cylinder's 128 segments are 59 mm).
SEGMENT_M = 0.075


def shell_over(shell: Shell, z_min: float, z_max: float) -> Shell:
    """The shell's radius over another z range (0.5 m long wall segments), every other field default."""
    return Shell(
        inner_radius_m=shell.inner_radius_m,
        z_min_m=z_min,
        z_max_m=z_max,
        z_segments=max(4, int(math.ceil((z_max - z_min) / 0.5))),
    )


@dataclass(frozen=True)
class RoundSection:
    """The cylindrical shell of the reference cabins (:class:`~planner.meshes.generate.Shell`)."""

    shell: Shell
    kind: SectionKind = "round"

    def over(self, z_min: float, z_max: float) -> RoundSection:
        """The same section over another z range."""
        return replace(self, shell=shell_over(self.shell, z_min, z_max))

    def half_width_at(self, y_m: float) -> float:
        """Half-width of the free cross-section at height ``y_m`` [m]."""
        return self.shell.half_width_at(y_m)

    def wall_x(self, y_lo: float, y_hi: float) -> float:
        """The narrowest half-width over heights [y_lo, y_hi] (the height farther from the axis)."""
        axis = self.shell.axis_y_m
        return self.shell.half_width_at(axis + max(abs(y_hi - axis), abs(y_lo - axis)))

    def wall_distance(self, xy: Array) -> Array:
        """Depth of points (N, 2) inside the inner surface [m] (negative: beyond it)."""
        return self.shell.inner_radius_m - np.hypot(xy[:, 0], xy[:, 1] - self.shell.axis_y_m)

    def inside(self, xy: Array, depth_m: float, gap_m: float) -> bool:
        """Whether every point (N, 2) is at least ``depth_m + gap_m`` inside the inner surface."""
        radius = self.shell.inner_radius_m - depth_m - gap_m
        return all(math.hypot(x, y - self.shell.axis_y_m) <= radius for x, y in xy)

    def duct_centre(self, angle: float, radius: float, gap: float) -> tuple[float, float]:
        """Centre of a duct of ``radius`` touching nothing, ``gap`` from the wall, towards ``angle``."""
        r_c = self.shell.inner_radius_m - radius - gap
        return r_c * math.cos(angle), self.shell.axis_y_m + r_c * math.sin(angle)

    def wall_point(self, angle: float) -> tuple[Array, Array]:
        """Where the ray from the axis at ``angle`` meets the inner surface, and the outward normal there."""
        n = np.array([math.cos(angle), math.sin(angle)])
        return np.array([0.0, self.shell.axis_y_m]) + self.shell.inner_radius_m * n, n

    def outline(self, offset_m: float, sections: int | None = None) -> Array:
        """The inner surface offset outwards by ``offset_m`` (M, 2); ``sections`` points around."""
        m = self.shell.sections if sections is None else sections
        theta = 2 * np.pi * np.arange(m) / m
        r = self.shell.inner_radius_m + offset_m
        return np.column_stack([r * np.cos(theta), self.shell.axis_y_m + r * np.sin(theta)])

    def rim(self, offset_m: float) -> Array:
        """The outline of flat pieces across the shell (end walls, bulkheads): the 128-gon at the offset."""
        return self.outline(offset_m)

    def describe(self) -> dict[str, float | str]:
        """The section's features for a case's record."""
        return {"shell_diameter_m": 2 * self.shell.inner_radius_m}


@dataclass(frozen=True)
class PolygonSection:
    """A convex polygonal shell: ``corners`` (M, 2) of the inner surface, counter-clockwise.

    ``shell`` carries the rest (wall, axis height, z range, deck); its ``inner_radius_m`` is the
    polygon's inscribed radius about the axis (a size, not used for geometry).
    """

    shell: Shell
    kind: SectionKind
    corners: tuple[tuple[float, float], ...]

    def over(self, z_min: float, z_max: float) -> PolygonSection:
        """The same section over another z range."""
        return replace(self, shell=shell_over(self.shell, z_min, z_max))

    def _planes(self) -> tuple[Array, Array]:
        """Outward unit normals (M, 2) and offsets (M,) of the edges: inside is ``n . p <= c``."""
        p = np.array(self.corners)
        d = np.roll(p, -1, axis=0) - p
        n = np.column_stack([d[:, 1], -d[:, 0]]) / np.linalg.norm(d, axis=1, keepdims=True)
        return n, np.einsum("ij,ij->i", n, p)

    def half_width_at(self, y_m: float) -> float:
        """Half-width of the free cross-section at height ``y_m`` [m] (0 outside the section's heights)."""
        p = np.array(self.corners)
        xs = [
            a[0] + (b[0] - a[0]) * (y_m - a[1]) / (b[1] - a[1])
            for a, b in zip(p, np.roll(p, -1, axis=0), strict=True)
            if min(a[1], b[1]) <= y_m <= max(a[1], b[1]) and a[1] != b[1]
        ]
        return float(max(xs)) if xs else 0.0

    def wall_x(self, y_lo: float, y_hi: float) -> float:
        """The narrowest half-width over heights [y_lo, y_hi] (at an end: the half-width is concave)."""
        return min(self.half_width_at(y_lo), self.half_width_at(y_hi))

    def wall_distance(self, xy: Array) -> Array:
        """Depth of points (N, 2) inside the inner surface [m] (negative: beyond it)."""
        n, c = self._planes()
        return np.min(c[None, :] - xy @ n.T, axis=1)

    def inside(self, xy: Array, depth_m: float, gap_m: float) -> bool:
        """Whether every point (N, 2) is at least ``depth_m + gap_m`` inside the inner surface."""
        return bool(np.all(self.wall_distance(np.asarray(xy, dtype=float)) >= depth_m + gap_m))

    def wall_point(self, angle: float) -> tuple[Array, Array]:
        """Where the ray from the axis at ``angle`` meets the inner surface, and that edge's normal."""
        n, c = self._planes()
        o = np.array([0.0, self.shell.axis_y_m])
        u = np.array([math.cos(angle), math.sin(angle)])
        along = n @ u
        t = np.where(along > 1e-12, (c - n @ o) / np.where(along > 1e-12, along, 1.0), np.inf)
        i = int(np.argmin(t))
        return o + t[i] * u, n[i]

    def duct_centre(self, angle: float, radius: float, gap: float) -> tuple[float, float]:
        """Centre of a duct ``gap`` from the wall edge the ray at ``angle`` meets (nearer at a corner)."""
        p, n = self.wall_point(angle)
        x, y = p - (radius + gap) * n
        return float(x), float(y)

    def rim(self, offset_m: float) -> Array:
        """The corners (M, 2) of the inner surface offset outwards by ``offset_m``.

        Each edge is moved along its normal; the outline of flat pieces across the shell (end walls,
        bulkheads).
        """
        n, c = self._planes()
        return np.array(
            [
                np.linalg.solve(np.array([n[i - 1], n[i]]), np.array([c[i - 1], c[i]]) + offset_m)
                for i in range(len(n))
            ]
        )

    def outline(self, offset_m: float, sections: int | None = None) -> Array:
        """The inner surface offset outwards by ``offset_m`` (M, 2): each edge moved along its normal.

        Every edge is split into ``ceil(length / SEGMENT_M)`` equal pieces (of the inner outline, so the
        points of every offset face each other); ``sections`` is ignored.
        """
        corners = self.rim(offset_m)  # corner i: edges i - 1 and i, moved out
        inner = np.array(self.corners)
        m = len(inner)
        points = []
        for i in range(m):
            length = float(np.linalg.norm(inner[(i + 1) % m] - inner[i]))
            pieces = max(1, math.ceil(length / SEGMENT_M))
            s = np.arange(pieces)[:, None] / pieces
            points.append(corners[i] + s * (corners[(i + 1) % m] - corners[i]))
        return np.vstack(points)

    def describe(self) -> dict[str, float | str]:
        """The section's features for a case's record."""
        p = np.array(self.corners)
        return {
            "section": self.kind,
            "section_width_m": float(np.round(p[:, 0].max() - p[:, 0].min(), 4)),
            "section_height_m": float(np.round(p[:, 1].max() - p[:, 1].min(), 4)),
        }


Section = RoundSection | PolygonSection


def octagon(shell: Shell, apothem_m: float) -> PolygonSection:
    """A regular octagon about the axis with flat floor, ceiling and sides ``apothem_m`` from it."""
    r = apothem_m / math.cos(math.pi / 8)
    angles = -3 * math.pi / 8 + np.arange(8) * math.pi / 4
    corners = tuple(
        (float(np.round(r * math.cos(a), 6)), float(np.round(shell.axis_y_m + r * math.sin(a), 6)))
        for a in angles
    )
    return PolygonSection(replace(shell, inner_radius_m=apothem_m), "octagon", corners)


def box_section(
    shell: Shell, half_width_m: float, floor_y_m: float, ceiling_y_m: float, chamfer_m: float
) -> PolygonSection:
    """A rectangular section with 45-degree chamfered corners (``chamfer_m`` along each side)."""
    w, lo, hi, c = half_width_m, floor_y_m, ceiling_y_m, chamfer_m
    corners: tuple[tuple[float, float], ...] = ((-w + c, lo), (w - c, lo), (w, lo + c), (w, hi - c))
    corners += ((w - c, hi), (-w + c, hi), (-w, hi - c), (-w, lo + c))
    inscribed = min(w, shell.axis_y_m - lo, hi - shell.axis_y_m)
    return PolygonSection(replace(shell, inner_radius_m=inscribed), "box", corners)


__all__ = [
    "SEGMENT_M",
    "PolygonSection",
    "RoundSection",
    "Section",
    "SectionKind",
    "box_section",
    "octagon",
    "shell_over",
]
