"""A certified lower bound of the distance to a mesh, on a regular grid (built once per cabin).

Construction. The mesh surface is sampled so that every surface point lies within ``e_s`` of a sample
(:func:`surface_samples`). Each sample marks its nearest grid node (within ``h sqrt(3)/2``); an exact
Euclidean distance transform then gives, for every node g, the distance ``d_m(g)`` to the nearest marked
node. For any surface point p there is a sample x with |p - x| <= e_s and a marked node m with
|x - m| <= h sqrt(3)/2, so ``|g - p| >= d_m(g) - h sqrt(3)/2 - e_s``.

Query. For a point q whose nearest node is g, |q - g| <= h sqrt(3)/2 and the distance is 1-Lipschitz, so
``d(q) >= d_m(g) - h sqrt(3) - e_s``: the grid stores exactly that bound. Points outside the grid box get
``-inf`` (unknown). A sphere of radius r centred at q is certainly clear of the mesh by ``LB(q) - r``.

Upper bound. The same grid bounds the distance from above: the nearest marked node m of g is within
``h sqrt(3)/2`` of a surface sample, so ``d(q) <= |q - g| + d_m(g) + h sqrt(3)/2 <= LB(q) + 2 h sqrt(3) +
e_s`` (:attr:`ClearanceGrid.upper_slack`) wherever LB(q) is finite. The world uses it only to recognise
certain contacts (a surface point strictly inside a grown body); clearance is always proven by LB.

Build cost: about a second for a 6 m cabin at 3 cm (one distance transform); :func:`cached_build`
keeps built grids on disk, keyed by the mesh content, pose and step.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from planner.core.cache import cache_dir
from planner.core.types import Array, IntArray

log = logging.getLogger(__name__)


def surface_samples(vertices: Array, faces: IntArray, spacing: float) -> Array:
    """Points on every triangle such that each surface point is within 2 * spacing of one of them.

    A triangle (v0, v1, v2) is sampled at v0 + a (v1 - v0) + b (v2 - v0) on a lattice with steps at most
    ``spacing`` along both edges (a + b <= 1), and along its third edge. Any point of the triangle lies in a
    lattice parallelogram (half-diagonal <= spacing) or in a boundary sliver next to the third edge (within
    spacing of a lattice point or an edge sample), hence within 2 * spacing of a sample.
    """
    tri = vertices[faces]
    out = [vertices]
    # Use the longest edge as the 'third' edge so the lattice is spanned by the two shorter ones.
    e = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], axis=1)
    lengths = np.linalg.norm(e, axis=2)
    longest = np.argmax(lengths, axis=1)
    # Rotate vertex order so that the longest edge is v1 -> v2 (opposite v0).
    order = np.stack([(longest + 2) % 3, longest % 3, (longest + 1) % 3], axis=1)
    tri = np.take_along_axis(tri, order[:, :, None], axis=1)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n1 = np.maximum(1, np.ceil(np.linalg.norm(e1, axis=1) / spacing)).astype(int)
    n2 = np.maximum(1, np.ceil(np.linalg.norm(e2, axis=1) / spacing)).astype(int)
    n3 = np.maximum(1, np.ceil(np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1) / spacing)).astype(int)
    for key in np.unique(np.column_stack([n1, n2]), axis=0):
        sel = (n1 == key[0]) & (n2 == key[1])
        a, b = np.meshgrid(np.arange(key[0] + 1) / key[0], np.arange(key[1] + 1) / key[1], indexing="ij")
        keep = a + b <= 1.0 + 1e-12
        a, b = a[keep], b[keep]
        pts = tri[sel, 0][:, None] + a[None, :, None] * e1[sel][:, None] + b[None, :, None] * e2[sel][:, None]
        out.append(pts.reshape(-1, 3))
    for n in np.unique(n3):
        sel = n3 == n
        t = np.arange(n + 1) / n
        pts = tri[sel, 1][:, None] + t[None, :, None] * (tri[sel, 2] - tri[sel, 1])[:, None]
        out.append(pts.reshape(-1, 3))
    return np.concatenate(out)


@dataclass(frozen=True)
class ClearanceGrid:
    """Lower bounds of the distance to a mesh at the nodes of a regular grid (see the module doc).

    Attributes:
        origin: Position of node (0, 0, 0) [m].
        step: Node spacing h [m].
        lower_bound: (nx, ny, nz) array of d_s - e_s - h sqrt(3)/2 [m] (may be negative near the surface).
    """

    origin: Array
    step: float
    lower_bound: Array
    sample_spacing: float = 0.015

    @property
    def upper_slack(self) -> float:
        """``d(q) <= query(q) + upper_slack`` [m] wherever ``query(q)`` is finite (see the module doc)."""
        return 2.0 * self.step * math.sqrt(3.0) + 2.0 * self.sample_spacing

    @classmethod
    def build(
        cls,
        vertices: Array,
        faces: IntArray,
        step: float = 0.03,
        sample_spacing: float = 0.015,
        padding: float = 0.5,
    ) -> ClearanceGrid:
        """Grid over the mesh's bounding box grown by ``padding`` [m], node spacing ``step`` [m]."""
        lo = vertices.min(axis=0) - padding
        hi = vertices.max(axis=0) + padding
        shape = tuple(int(n) for n in np.ceil((hi - lo) / step).astype(int) + 1)
        samples = surface_samples(vertices, faces, sample_spacing)
        idx = np.clip(np.rint((samples - lo) / step).astype(np.int64), 0, np.array(shape) - 1)
        free = np.ones(shape, dtype=bool)
        free[idx[:, 0], idx[:, 1], idx[:, 2]] = False
        d_marked = ndimage.distance_transform_edt(free, sampling=step)
        bound = d_marked - step * math.sqrt(3.0) - 2.0 * sample_spacing
        # One layer of -inf around the grid: clipped indices of outside points land there.
        return cls(lo - step, float(step), np.pad(bound, 1, constant_values=-np.inf), float(sample_spacing))

    def query(self, points: Array) -> Array:
        """Certified lower bound of the distance from each point (..., 3) to the mesh [m]; -inf outside."""
        shape = self.lower_bound.shape
        idx = np.rint((points - self.origin) * (1.0 / self.step)).astype(np.int64)
        np.clip(idx, 0, np.array(shape) - 1, out=idx)
        flat = idx @ np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
        return self.lower_bound.reshape(-1)[flat]


#: Bump when the grid's construction changes: cached grids of an older version are not used.
GRID_VERSION = 1


def cached_build(key: str, vertices: Array, faces: IntArray, step: float) -> ClearanceGrid:
    """:meth:`ClearanceGrid.build`, cached on disk by ``key`` (the mesh's content and pose) and ``step``.

    Building costs about a second for a reference cabin (a Euclidean distance transform); loading the
    cached grid, milliseconds. The file is written atomically; a missing, unreadable or mismatched file is
    simply rebuilt, so the cache can never change a result.
    """
    folder = cache_dir()
    name = hashlib.sha256(f"{key}|{step!r}|{GRID_VERSION}".encode()).hexdigest()[:32]
    path = folder / f"grid-{name}.npz" if folder is not None else None
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                grid = ClearanceGrid(
                    np.array(data["origin"]),
                    float(data["step"]),
                    np.array(data["lower_bound"]),
                    float(data["sample_spacing"]) if "sample_spacing" in data else 0.015,
                )
            if grid.step == float(step) and grid.lower_bound.ndim == 3 and grid.origin.shape == (3,):
                return grid
        except (OSError, ValueError, KeyError):
            log.warning("clearance grid cache %s unreadable; rebuilding", path)
    grid = ClearanceGrid.build(vertices, faces, step=step)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as tmp:
                np.savez(
                    tmp,
                    origin=grid.origin,
                    step=grid.step,
                    lower_bound=grid.lower_bound,
                    sample_spacing=grid.sample_spacing,
                )
            os.replace(tmp.name, path)
        except OSError as exc:
            log.warning("clearance grid cache not written (%s)", exc)
    return grid
