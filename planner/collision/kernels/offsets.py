"""How far bodies move between poses, and how far a run's vertices stray from their chords (compiled).

The numbers of :func:`planner.collision.sweep.task_offsets` (each body's move between poses, per task) and
:func:`planner.collision.sweep.hull_deviation`, and the swept hulls' vertices along a path, in one pass
over the poses instead of numpy's dozen temporaries: every sum is written out in the order numpy's own
reductions add (pairwise over 9 terms, in sequence over 3), so both give the same bits as the plain numpy
formulas (``tests/collision/test_sweep.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False, inline="always")
def _offset(a: np.ndarray, c: np.ndarray, box: bool, half: float) -> float:
    """How far any point of a body moves between its poses a and c (13,): an upper bound [m].

    A box (half-diagonal ``half``): |dp| + |dR|_F h; a capsule: |dp| + |d(z L)| / 2.
    """
    d9, d10, d11 = c[9] - a[9], c[10] - a[10], c[11] - a[11]
    dp = math.sqrt((d9 * d9 + d10 * d10) + d11 * d11)
    if box:  # |dR|_F: the 9 squares summed pairwise, then the ninth (numpy's order)
        r0, r1, r2, r3 = c[0] - a[0], c[1] - a[1], c[2] - a[2], c[3] - a[3]
        r4, r5, r6, r7, r8 = c[4] - a[4], c[5] - a[5], c[6] - a[6], c[7] - a[7], c[8] - a[8]
        sq = ((r0 * r0 + r1 * r1) + (r2 * r2 + r3 * r3)) + ((r4 * r4 + r5 * r5) + (r6 * r6 + r7 * r7))
        sq += r8 * r8
        return dp + math.sqrt(sq) * half
    z0 = c[6] * c[12] - a[6] * a[12]
    z1 = c[7] * c[12] - a[7] * a[12]
    z2 = c[8] * c[12] - a[8] * a[12]
    return dp + 0.5 * math.sqrt((z0 * z0 + z1 * z1) + z2 * z2)


@njit(cache=True, fastmath=False)
def task_offsets(
    poses_a: np.ndarray,
    poses_b: np.ndarray,
    box: np.ndarray,
    half: np.ndarray,
    col_a: np.ndarray,
    col_b: np.ndarray,
) -> np.ndarray:
    """(M, T) bounds of how far each task's bodies move between poses_a and poses_b (M, B, 13).

    Per body (``box[b]``, half-diagonal ``half[b]``): |dp| + |dR|_F h for a box, |dp| + |d(z L)| / 2 for
    a capsule; per task column, body col_a[t]'s, plus body col_b[t]'s when >= 0.

    A task of one body (against the cabin or an obstacle) moves by that body's offset; a pair's relative
    distance by at most the sum of both bodies' offsets.
    """
    m, nb, nt = poses_a.shape[0], poses_a.shape[1], col_a.shape[0]
    body = np.empty(nb)
    out = np.empty((m, nt))
    for k in range(m):
        for b in range(nb):
            body[b] = _offset(poses_a[k, b], poses_b[k, b], box[b], half[b])
        for t in range(nt):
            v = body[col_a[t]]
            if col_b[t] >= 0:
                v = v + body[col_b[t]]
            out[k, t] = v
    return out


@njit(cache=True, fastmath=False)
def hull_deviation(verts: np.ndarray) -> float:
    """The largest distance of verts[s, v] (n, V, 3) from the chord [verts[0, v], verts[-1, v]] [m]."""
    n, nv = verts.shape[0], verts.shape[1]
    worst = 0.0
    for v in range(nv):
        a0, a1, a2 = verts[0, v, 0], verts[0, v, 1], verts[0, v, 2]
        b0, b1, b2 = verts[n - 1, v, 0] - a0, verts[n - 1, v, 1] - a1, verts[n - 1, v, 2] - a2
        den = (b0 * b0 + b1 * b1) + b2 * b2
        if not den > 0.0:
            den = 1.0
        for s in range(n):
            r0, r1, r2 = verts[s, v, 0] - a0, verts[s, v, 1] - a1, verts[s, v, 2] - a2
            t = ((r0 * b0 + r1 * b1) + r2 * b2) / den
            t = min(max(t, 0.0), 1.0)
            o0, o1, o2 = r0 - t * b0, r1 - t * b1, r2 - t * b2
            e2 = (o0 * o0 + o1 * o1) + o2 * o2
            if e2 > worst:
                worst = e2
    return math.sqrt(worst)


@njit(cache=True, fastmath=False, inline="always")
def _vertices_of(pose: np.ndarray, local: np.ndarray, box: bool, out: np.ndarray) -> None:
    """One pose's vertices into out (V, 3): a box's corners p + R local[v], a capsule's p -+ z L / 2.

    The sums in :func:`planner.collision.sweep.body_vertices`' order: ((p + l0 x) + l1 y) + l2 z.
    """
    if box:
        for v in range(local.shape[0]):
            l0, l1, l2 = local[v, 0], local[v, 1], local[v, 2]
            for r in range(3):
                out[v, r] = ((pose[9 + r] + l0 * pose[r]) + l1 * pose[3 + r]) + l2 * pose[6 + r]
    else:
        h = 0.5 * pose[12]
        for r in range(3):
            half = h * pose[6 + r]
            out[0, r] = pose[9 + r] - half
            out[1, r] = pose[9 + r] + half


@njit(cache=True, fastmath=False)
def path_vertices(poses: np.ndarray, b: int, local: np.ndarray, box: bool) -> np.ndarray:
    """Body b's vertices (N, V, 3) at poses (N, B, 13): a box's 8 corners (``local``), a capsule's 2 ends."""
    n = poses.shape[0]
    nv = local.shape[0] if box else 2
    out = np.empty((n, nv, 3))
    for s in range(n):
        _vertices_of(poses[s, b], local, box, out[s])
    return out


@njit(cache=True, fastmath=False)
def pair_vertices(poses: np.ndarray, a: int, b: int, local: np.ndarray, box: bool) -> np.ndarray:
    """Body a's vertices (N, V, 3) in body b's frame at poses (N, B, 13) (``local``, ``box``: a's shape).

    a's pose in b's frame (R_b^T R_a, R_b^T (p_a - p_b)), then its vertices. Each 3-term product is
    summed as numpy's einsum sums it in :func:`planner.collision.sweep.relative_poses` (two running sums
    over alternate terms: (t0 + t2) + t1), so the bits are the same (``tests/collision/test_sweep.py``).
    """
    n = poses.shape[0]
    nv = local.shape[0] if box else 2
    out = np.empty((n, nv, 3))
    rel = np.empty(13)
    for s in range(n):
        pa, pb = poses[s, a], poses[s, b]
        for k in range(3):
            for i in range(3):  # R[i, k] = sum_j Rb[j, i] Ra[j, k], stored column-major at 3 k + i
                even = pb[3 * i] * pa[3 * k] + pb[3 * i + 2] * pa[3 * k + 2]
                rel[3 * k + i] = even + pb[3 * i + 1] * pa[3 * k + 1]
        d0, d1, d2 = pa[9] - pb[9], pa[10] - pb[10], pa[11] - pb[11]
        for i in range(3):
            rel[9 + i] = (pb[3 * i] * d0 + pb[3 * i + 2] * d2) + pb[3 * i + 1] * d1
        rel[12] = pa[12]
        _vertices_of(rel, local, box, out[s])
    return out
