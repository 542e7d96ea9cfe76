"""The clearance grid's construction, compiled: the surface's nodes marked, then their distance transform.

:meth:`planner.collision.clearance_grid.ClearanceGrid.build` takes about a second in numpy and scipy on a
generated cabin of 4-5 million nodes (1.7 million surface samples held in memory, then
``scipy.ndimage.distance_transform_edt``, whose feature transform and distances dominate). Here:

- :func:`grid_marks` walks every triangle's sample lattice (the points of
  :func:`~planner.collision.clearance_grid.surface_samples`, computed with the same operations in the same
  order, so the same bits) and marks each sample's nearest node, without holding the samples;
- :func:`grid_bounds` is the exact Euclidean distance transform of the marked nodes by the separable
  lower-envelope algorithm (Felzenszwalb and Huttenlocher, "Distance transforms of sampled functions",
  Theory of Computing 8, 2012): squared distances in whole node steps, one pass per axis, each line the
  lower envelope of the parabolas (q - p)^2 + f(p). Squared distances are integers below 2^53, so every
  value is exact; the grid's bound is ``sqrt(d2) step - offset``, written into the grid padded by one layer
  of ``-inf``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False, inline="always")
def _mark(marked: np.ndarray, x: float, y: float, z: float, lo: np.ndarray, step: float) -> None:
    """Mark the node nearest to (x, y, z) (indices clipped to the grid, as ``np.clip(np.rint(...))``)."""
    i = int(np.rint((x - lo[0]) / step))
    j = int(np.rint((y - lo[1]) / step))
    k = int(np.rint((z - lo[2]) / step))
    i = min(max(i, 0), marked.shape[0] - 1)
    j = min(max(j, 0), marked.shape[1] - 1)
    k = min(max(k, 0), marked.shape[2] - 1)
    marked[i, j, k] = True


@njit(cache=True, fastmath=False, inline="always")
def _norm3(a0: float, a1: float, a2: float) -> float:
    """|a|, summed as numpy's ``norm(..., axis=-1)`` sums three squares (in sequence)."""
    return math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)


@njit(cache=True, fastmath=False)
def grid_marks(
    vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, step: float, spacing: float, marked: np.ndarray
) -> None:
    """Mark the grid node nearest to every surface sample of the mesh (vertices (V, 3), faces (F, 3)).

    The samples are :func:`~planner.collision.clearance_grid.surface_samples`'s: the vertices; on each
    triangle, its vertices rotated so that the longest edge is v1 -> v2, the points v0 + a e1 + b e2 with
    a = i / n1, b = j / n2, a + b <= 1 + 1e-12 (n = ceil(|e| / spacing), at least 1); and the points of
    its third edge, v1 + (k / n3) (v2 - v1). Node (i, j, k) of ``marked`` (nx, ny, nz) sits at
    lo + step (i, j, k).
    """
    for v in range(vertices.shape[0]):
        _mark(marked, vertices[v, 0], vertices[v, 1], vertices[v, 2], lo, step)
    t = np.empty((3, 3))
    lengths = np.empty(3)
    for f in range(faces.shape[0]):
        for c in range(3):
            a, b = faces[f, c], faces[f, (c + 1) % 3]
            lengths[c] = _norm3(
                vertices[b, 0] - vertices[a, 0],
                vertices[b, 1] - vertices[a, 1],
                vertices[b, 2] - vertices[a, 2],
            )
        longest = 0  # the first of equal lengths, as np.argmax
        for c in range(1, 3):
            if lengths[c] > lengths[longest]:
                longest = c
        for r, c in enumerate(((longest + 2) % 3, longest, (longest + 1) % 3)):
            for x in range(3):
                t[r, x] = vertices[faces[f, c], x]
        e10, e11, e12 = t[1, 0] - t[0, 0], t[1, 1] - t[0, 1], t[1, 2] - t[0, 2]
        e20, e21, e22 = t[2, 0] - t[0, 0], t[2, 1] - t[0, 1], t[2, 2] - t[0, 2]
        e30, e31, e32 = t[2, 0] - t[1, 0], t[2, 1] - t[1, 1], t[2, 2] - t[1, 2]
        n1 = max(1, int(math.ceil(_norm3(e10, e11, e12) / spacing)))
        n2 = max(1, int(math.ceil(_norm3(e20, e21, e22) / spacing)))
        n3 = max(1, int(math.ceil(_norm3(e30, e31, e32) / spacing)))
        for i in range(n1 + 1):
            a = i / n1
            for j in range(n2 + 1):
                b = j / n2
                if not a + b <= 1.0 + 1e-12:
                    break  # b only grows along the row
                _mark(
                    marked,
                    (t[0, 0] + a * e10) + b * e20,
                    (t[0, 1] + a * e11) + b * e21,
                    (t[0, 2] + a * e12) + b * e22,
                    lo,
                    step,
                )
        for k in range(n3 + 1):
            s = k / n3
            _mark(marked, t[1, 0] + s * e30, t[1, 1] + s * e31, t[1, 2] + s * e32, lo, step)


@njit(cache=True, fastmath=False)
def _envelope(f: np.ndarray, n: int, d: np.ndarray, v: np.ndarray, z: np.ndarray) -> None:
    """d[q] = min over p of (q - p)^2 + f[p], q < n (f[p] = inf: no parabola); all inf when every f is."""
    k = -1
    for q in range(n):
        fq = f[q]
        if fq == np.inf:
            continue
        hq = fq + float(q * q)
        s = -np.inf
        while k >= 0:
            p = v[k]
            s = (hq - (f[p] + float(p * p))) / float(2 * (q - p))
            if s <= z[k]:
                k -= 1
                s = -np.inf
            else:
                break
        k += 1
        v[k] = q
        z[k] = s
    if k < 0:
        for q in range(n):
            d[q] = np.inf
        return
    j = 0
    for q in range(n):
        while j < k and z[j + 1] < q:
            j += 1
        p = v[j]
        d[q] = float((q - p) * (q - p)) + f[p]


@njit(cache=True, fastmath=False)
def _rows(slab: np.ndarray, dst: np.ndarray, v: np.ndarray, z: np.ndarray) -> None:
    """Each row of ``slab`` (lines, n) replaced by its lower envelope (:func:`_envelope`), in place."""
    n = slab.shape[1]
    for k in range(slab.shape[0]):
        _envelope(slab[k], n, dst, v, z)
        for q in range(n):
            slab[k, q] = dst[q]


@njit(cache=True, fastmath=False)
def grid_bounds(marked: np.ndarray, step: float, offset: float, out: np.ndarray) -> None:
    """``out[1 + i, 1 + j, 1 + k] = step * (distance in node steps to the nearest marked node) - offset``.

    ``marked`` (nx, ny, nz); ``out`` (nx + 2, ny + 2, nz + 2): its outer layer is set to ``-inf``. The
    distance is exact (the squared distances are whole numbers); ``inf`` when nothing is marked.
    """
    nx, ny, nz = marked.shape
    m = max(nx, max(ny, nz))
    work = np.empty((nx, ny, nz))
    v = np.empty(m, dtype=np.int64)
    z = np.empty(m + 1)
    dst = np.empty(m)
    # Along z: the squared distance to the nearest marked node of each line (two scans).
    for i in range(nx):
        for j in range(ny):
            last = -1
            for k in range(nz):
                if marked[i, j, k]:
                    last = k
                work[i, j, k] = np.inf if last < 0 else float((k - last) * (k - last))
            last = -1
            for k in range(nz - 1, -1, -1):
                if marked[i, j, k]:
                    last = k
                if last >= 0:
                    w = float((last - k) * (last - k))
                    if w < work[i, j, k]:
                        work[i, j, k] = w
    # Along y, one x-slab at a time (held transposed, so that each line is contiguous).
    slab = np.empty((nz, ny))
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                slab[k, j] = work[i, j, k]
        _rows(slab, dst, v, z)
        for j in range(ny):
            for k in range(nz):
                work[i, j, k] = slab[k, j]
    # Along x, one y-slab at a time; the result written into the padded grid.
    out[:] = -np.inf
    slab = np.empty((nz, nx))
    for j in range(ny):
        for i in range(nx):
            for k in range(nz):
                slab[k, i] = work[i, j, k]
        _rows(slab, dst, v, z)
        for i in range(nx):
            for k in range(nz):
                out[i + 1, j + 1, k + 1] = math.sqrt(slab[k, i]) * step - offset
