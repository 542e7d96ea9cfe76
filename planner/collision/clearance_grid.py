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

Build. Compiled (:mod:`.kernels.grid`): the samples mark their nodes as they are generated, then the exact
distance transform runs one lower-envelope pass per axis. About 0.1 s for a generated cabin of 4-5 million
nodes at 3 cm, where numpy's samples and ``scipy.ndimage.distance_transform_edt`` took 0.6-1.2 s
(``tests/collision/test_world.py`` compares the two). :func:`cached_build` keeps built grids on disk,
keyed by the mesh content, pose and step.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.collision.kernels.entries import DEFAULT as KERNELS
from planner.core.cache import DATA_PATTERNS, cache_dir, prune, touch, write_atomic
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
        marked = np.zeros(shape, dtype=bool)
        vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        faces = np.ascontiguousarray(faces, dtype=np.int64)
        KERNELS.grid_marks(vertices, faces, lo, step, sample_spacing, marked)
        # One layer of -inf around the grid: clipped indices of outside points land there.
        bound = KERNELS.grid_bounds(marked, step, step * math.sqrt(3.0) + 2.0 * sample_spacing)
        return cls(lo - step, float(step), bound, float(sample_spacing))

    def query(self, points: Array) -> Array:
        """Certified lower bound of the distance from each point (..., 3) to the mesh [m]; -inf outside."""
        shape = self.lower_bound.shape
        idx = np.rint((points - self.origin) * (1.0 / self.step)).astype(np.int64)
        np.clip(idx, 0, np.array(shape) - 1, out=idx)
        flat = idx @ np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
        return self.lower_bound.reshape(-1)[flat]


#: Bump when the grid's construction or its cache layout changes: cached grids of an older one are not used.
GRID_VERSION = 3


def cached_build(key: str, vertices: Array, faces: IntArray, step: float) -> ClearanceGrid:
    """:meth:`ClearanceGrid.build`, cached on disk by ``key`` (the mesh's content and pose) and ``step``.

    Building costs about a second for a reference cabin (a Euclidean distance transform). A cached grid is
    two files: the bounds as a ``.npy`` that is memory-mapped, not read (a plan touches a few pages of a
    30-45 MB grid: loading it whole cost a CLI call 0.1-0.2 s), and a ``.json`` with the grid's frame,
    written last, so a reader never sees half an entry. A missing, unreadable or mismatched entry is
    simply rebuilt, so the cache can never change a result; the folder is kept within its size bound
    (:func:`planner.core.cache.prune`).
    """
    folder = cache_dir()
    name = hashlib.sha256(f"{key}|{step!r}|{GRID_VERSION}".encode()).hexdigest()[:32]
    if folder is not None:
        grid = _read_cached(folder / f"grid-{name}.json", folder / f"grid-{name}.npy", step)
        if grid is not None:
            return grid
    grid = ClearanceGrid.build(vertices, faces, step=step)
    if folder is not None:
        _write_cached(folder, name, grid)
    return grid


def _read_cached(meta_path: Path, data_path: Path, step: float) -> ClearanceGrid | None:
    try:
        meta = json.loads(meta_path.read_text())
        bounds = np.load(data_path, mmap_mode="r", allow_pickle=False)
        grid = ClearanceGrid(
            np.array(meta["origin"], dtype=float),
            float(meta["step"]),
            bounds,
            float(meta["sample_spacing"]),
        )
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("clearance grid cache %s unreadable; rebuilding", data_path)
        return None
    if (
        grid.step != float(step)
        or bounds.ndim != 3
        or list(bounds.shape) != list(meta.get("shape", ()))
        or bounds.dtype != np.float64
        or grid.origin.shape != (3,)
    ):
        log.warning("clearance grid cache %s does not match its description; rebuilding", data_path)
        return None
    touch(meta_path, data_path)
    return grid


def _write_cached(folder: Path, name: str, grid: ClearanceGrid) -> None:
    meta = {
        "origin": grid.origin.tolist(),
        "step": grid.step,
        "sample_spacing": grid.sample_spacing,
        "shape": list(grid.lower_bound.shape),
    }
    bounds = np.ascontiguousarray(grid.lower_bound, dtype=np.float64)
    try:
        write_atomic(folder / f"grid-{name}.npy", lambda f: np.save(f, bounds, allow_pickle=False))
        write_atomic(folder / f"grid-{name}.json", lambda f: json.dump(meta, f), text=True)  # last: complete
        prune(folder, DATA_PATTERNS)
    except OSError as exc:
        log.warning("clearance grid cache not written (%s)", exc)
