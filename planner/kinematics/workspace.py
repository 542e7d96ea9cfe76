"""Reachable position workspace at a fixed orientation by boundary search (pprs6 paper, section 4).

The paper's search (Fig. 4) runs the inverse kinematics over a 3-D grid of platform-centre positions and
keeps the points whose drives are within their ranges (eq. 15). We do the same, vectorised, and then
*locate the boundary*: between every admissible grid point and an inadmissible neighbour along x, y or z
the crossing is found by bisection (to well below a micrometre). The extents are the extremes of those
boundary points, so they do not depend on where the grid happens to fall; the volume integrates the
admissible z-intervals of every (x, y) column, with their refined ends, over the column's cell area.

The search is generic: any admissibility predicate over (M, 3) positions works.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.core.exceptions import InvalidInput
from planner.core.types import Array, BoolArray

Predicate = Callable[[Array], BoolArray]


@dataclass(frozen=True)
class Workspace:
    """Result of a boundary search.

    Attributes:
        axes: Grid coordinates along x, y, z [m], each (n_k,).
        inside: (n_x, n_y, n_z) bool, the grid points that are admissible.
        boundary: (K, 3) refined boundary points [m].
        volume_m3: Volume of the admissible set [m^3].
        extents_m: (3, 2) min and max of x, y, z over the boundary [m].
        step_m: Grid step [m].
    """

    axes: tuple[Array, Array, Array] = field(repr=False)
    inside: BoolArray = field(repr=False)
    boundary: Array = field(repr=False)
    volume_m3: float
    extents_m: Array
    step_m: float

    @property
    def n_inside(self) -> int:
        """Number of admissible grid points."""
        return int(self.inside.sum())

    def to_dict(self) -> dict[str, object]:
        """JSON-serialisable figures (no grids)."""
        names = ("x", "y", "z")
        return {
            "volume_m3": self.volume_m3,
            "extents_m": {n: [float(a), float(b)] for n, (a, b) in zip(names, self.extents_m, strict=True)},
            "size_m": {n: float(b - a) for n, (a, b) in zip(names, self.extents_m, strict=True)},
            "step_m": self.step_m,
            "grid_points": int(self.inside.size),
            "inside_points": self.n_inside,
            "boundary_points": len(self.boundary),
        }


def _bisect(admissible: Predicate, a: Array, b: Array, iterations: int) -> Array:
    """Boundary points between admissible a (K, 3) and inadmissible b (K, 3) by bisection."""
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        ok = admissible(mid)
        a = np.where(ok[:, None], mid, a)
        b = np.where(ok[:, None], b, mid)
    return 0.5 * (a + b)


def _refine_extent(
    admissible: Predicate, bnd: Array, axis: int, side: int, step_m: float, iterations: int
) -> Array:
    """More boundary points around the extreme of one axis (an extreme is usually hit between grid lines).

    Around the 8 most extreme boundary points, a local grid of 9 x 9 offsets in the two other axes (two
    rounds, the window shrinking from +-1 step to +-1/4 step around the best point) is bisected along the
    axis, from a point one step inwards (when admissible) to one step outwards.
    """
    sign = 1.0 if side == 1 else -1.0
    others = [k for k in range(3) if k != axis]
    order = np.argsort(sign * bnd[:, axis])[::-1][:8]
    centres = bnd[order]
    found = [np.zeros((0, 3))]
    half = step_m
    for _ in range(2):
        offs = np.linspace(-half, half, 9)
        g1, g2 = np.meshgrid(offs, offs, indexing="ij")
        pts = np.repeat(centres, g1.size, axis=0)
        pts[:, others[0]] += np.tile(g1.ravel(), len(centres))
        pts[:, others[1]] += np.tile(g2.ravel(), len(centres))
        inner = pts.copy()
        inner[:, axis] -= sign * step_m
        outer = pts.copy()
        outer[:, axis] += sign * step_m
        ok = admissible(inner) & ~admissible(outer)
        if not ok.any():
            break
        b = _bisect(admissible, inner[ok], outer[ok], iterations)
        found.append(b)
        centres = b[np.argsort(sign * b[:, axis])[::-1][:4]]
        half *= 0.25
    return np.concatenate(found)


def boundary_search(
    admissible: Predicate,
    bounds_m: Array,
    step_m: float,
    iterations: int = 32,
    max_points: int = 8_000_000,
) -> Workspace:
    """The admissible set of positions inside a box, with its refined boundary, volume and extents.

    Args:
        admissible: Vectorised predicate, positions (M, 3) [m] -> (M,) bool.
        bounds_m: (3, 2) search box [m]; it must contain the whole workspace (checked: no admissible
            point may lie on the box faces).
        step_m: Grid step [m].
        iterations: Bisection steps per boundary crossing (the crossing is located to step / 2^iterations).
        max_points: Refuse grids larger than this.

    Raises:
        InvalidInput: a non-positive step, an oversized grid, or a box that cuts the workspace.
    """
    bounds = np.asarray(bounds_m, dtype=float)
    if not (np.isfinite(step_m) and step_m > 0):
        raise InvalidInput(f"step_m: must be a positive length, got {step_m}", field="step_m")
    ax = [np.arange(lo, hi + 0.5 * step_m, step_m) for lo, hi in bounds]
    axes: tuple[Array, Array, Array] = (ax[0], ax[1], ax[2])
    shape = tuple(len(a) for a in axes)
    if int(np.prod(shape)) > max_points:
        raise InvalidInput(
            f"step_m: a grid of {shape} points exceeds {max_points}; use a larger step", field="step_m"
        )
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([X, Y, Z], axis=-1)
    inside = admissible(pts.reshape(-1, 3)).reshape(shape)
    faces = [inside[0], inside[-1], inside[:, 0], inside[:, -1], inside[:, :, 0], inside[:, :, -1]]
    if any(f.any() for f in faces):
        raise InvalidInput("bounds_m: the search box cuts the workspace; enlarge it", field="bounds_m")
    boundary = []
    z_low: list[Array] = []
    z_high: list[Array] = []
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        a_in, b_in = inside[tuple(lo)], inside[tuple(hi)]
        p_lo, p_hi = pts[tuple(lo)], pts[tuple(hi)]
        enter = ~a_in & b_in  # outside -> inside along +axis
        leave = a_in & ~b_in  # inside -> outside
        entry = _bisect(admissible, p_hi[enter], p_lo[enter], iterations)
        exit_ = _bisect(admissible, p_lo[leave], p_hi[leave], iterations)
        boundary += [entry, exit_]
        if axis == 2:
            # Column intervals: crossings along z in the same (i, j) column pair up in order.
            ij_e = np.argwhere(enter)[:, :2]
            ij_l = np.argwhere(leave)[:, :2]
            order_e = np.lexsort((np.argwhere(enter)[:, 2], ij_e[:, 1], ij_e[:, 0]))
            order_l = np.lexsort((np.argwhere(leave)[:, 2], ij_l[:, 1], ij_l[:, 0]))
            z_low.append(entry[order_e, 2])
            z_high.append(exit_[order_l, 2])
    bnd = np.concatenate(boundary) if boundary else np.zeros((0, 3))
    if len(bnd) == 0:
        return Workspace(axes, inside, bnd, 0.0, np.full((3, 2), np.nan), float(step_m))
    volume = float(np.sum(np.concatenate(z_high) - np.concatenate(z_low)) * step_m**2)
    extents = np.column_stack([bnd.min(axis=0), bnd.max(axis=0)])
    extra = [
        _refine_extent(admissible, bnd, axis, side, step_m, iterations)
        for axis in range(3)
        for side in (0, 1)
    ]
    bnd = np.concatenate([bnd, *extra])
    extents = np.column_stack([bnd.min(axis=0), bnd.max(axis=0)])
    return Workspace(axes, inside, bnd, volume, extents, float(step_m))


def two_pass_search(
    admissible: Predicate, bounds_m: Array, step_m: float, coarse_step_m: float, iterations: int = 32
) -> Workspace:
    """Boundary search in a box found by a coarse pass: cheap when the workspace is small in its box.

    The coarse pass (``coarse_step_m``) locates the workspace's extents in the generous ``bounds_m``; the
    fine pass searches that box grown by two coarse steps (clipped to ``bounds_m``). Features thinner than
    the coarse step can be missed by the coarse pass only if they stick out of the grown box.
    """
    coarse = boundary_search(admissible, bounds_m, coarse_step_m, iterations=8)
    bounds = np.asarray(bounds_m, dtype=float)
    if not np.all(np.isfinite(coarse.extents_m)):
        return boundary_search(admissible, bounds, step_m, iterations)
    margin = 2.0 * coarse_step_m
    box = np.column_stack(
        [
            np.maximum(coarse.extents_m[:, 0] - margin, bounds[:, 0]),
            np.minimum(coarse.extents_m[:, 1] + margin, bounds[:, 1]),
        ]
    )
    return boundary_search(admissible, box, step_m, iterations)
