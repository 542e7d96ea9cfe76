"""Compiled (numba) kernels of the collision hot path: certified lower bounds from sphere covers.

The same bounds as the numpy reference implementation in :class:`planner.collision.world.CollisionWorld`
(``cabin_lower_bounds`` / ``pair_lower_bounds``; the tests check they agree), in one pass without
temporaries: a validity check spends a few microseconds here instead of a few dozen numpy calls.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False)
def cabin_bounds(
    centres: np.ndarray,  # (S, 3) fine cover centres
    radii: np.ndarray,  # (S,)
    body_start: np.ndarray,  # (B + 1,) first sphere of each body, then S
    grid: np.ndarray,  # flat lower-bound grid (C order)
    origin: np.ndarray,  # (3,)
    inv_step: float,
    shape: np.ndarray,  # (3,) int64
) -> np.ndarray:
    """Per-body minimum over its spheres of (grid lower bound at the centre - radius)."""
    n_b = body_start.shape[0] - 1
    out = np.empty(n_b)
    sy = shape[1] * shape[2]
    sz = shape[2]
    for b in range(n_b):
        best = math.inf
        for s in range(body_start[b], body_start[b + 1]):
            i = int(math.floor((centres[s, 0] - origin[0]) * inv_step + 0.5))
            j = int(math.floor((centres[s, 1] - origin[1]) * inv_step + 0.5))
            k = int(math.floor((centres[s, 2] - origin[2]) * inv_step + 0.5))
            i = min(max(i, 0), shape[0] - 1)
            j = min(max(j, 0), shape[1] - 1)
            k = min(max(k, 0), shape[2] - 1)
            v = grid[i * sy + j * sz + k] - radii[s]
            if v < best:
                best = v
        out[b] = best
    return out


@njit(cache=True, fastmath=False)
def pair_bounds(
    centres: np.ndarray,  # (S, 3) coarse cover centres
    radii: np.ndarray,  # (S,)
    body_start: np.ndarray,  # (B + 1,)
    pair_a: np.ndarray,  # (P,)
    pair_b: np.ndarray,  # (P,)
    threshold: float,
) -> np.ndarray:
    """Per-pair lower bound of the distance: box separation, then (if not above threshold) sphere gaps."""
    n_b = body_start.shape[0] - 1
    lo = np.full((n_b, 3), math.inf)
    hi = np.full((n_b, 3), -math.inf)
    for b in range(n_b):
        for s in range(body_start[b], body_start[b + 1]):
            for d in range(3):
                lo[b, d] = min(lo[b, d], centres[s, d] - radii[s])
                hi[b, d] = max(hi[b, d], centres[s, d] + radii[s])
    n_p = pair_a.shape[0]
    out = np.empty(n_p)
    for p in range(n_p):
        a, b = pair_a[p], pair_b[p]
        sep = -math.inf
        for d in range(3):
            sep = max(sep, lo[b, d] - hi[a, d], lo[a, d] - hi[b, d])
        if sep <= threshold:
            gap = math.inf
            for s in range(body_start[a], body_start[a + 1]):
                for t in range(body_start[b], body_start[b + 1]):
                    dx = centres[s, 0] - centres[t, 0]
                    dy = centres[s, 1] - centres[t, 1]
                    dz = centres[s, 2] - centres[t, 2]
                    g = math.sqrt(dx * dx + dy * dy + dz * dz) - radii[s] - radii[t]
                    if g < gap:
                        gap = g
            sep = max(sep, gap)
        out[p] = sep
    return out


@njit(cache=True, fastmath=False)
def cover_centres(
    poses: np.ndarray,  # (B, 13): R column-major (9), p (3), capsule length (1)
    body: np.ndarray,  # (S,) body of each sphere
    local: np.ndarray,  # (S, 3) centre in the body frame (boxes)
    frac: np.ndarray,  # (S,) fraction of the capsule length along the body z axis (capsules)
) -> np.ndarray:
    """World centres (S, 3) of a sphere cover: p + R local + frac * length * z."""
    n = body.shape[0]
    out = np.empty((n, 3))
    for s in range(n):
        b = body[s]
        for i in range(3):
            v = poses[b, 9 + i] + frac[s] * poses[b, 12] * poses[b, 6 + i]
            for j in range(3):
                v += poses[b, 3 * j + i] * local[s, j]
            out[s, i] = v
    return out


@njit(cache=True, fastmath=False)
def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    """Exact distance between the segments p1-q1 and p2-q2 (clamped closest points, robust when parallel)."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = d1 @ d1
    e = d2 @ d2
    f = d2 @ r
    eps = 1e-14
    if a <= eps and e <= eps:
        return math.sqrt(r @ r)
    if a <= eps:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = d1 @ r
        if e <= eps:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = d1 @ d2
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > eps else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    w = (p1 + s * d1) - (p2 + t * d2)
    return math.sqrt(w @ w)


@njit(cache=True, fastmath=False)
def capsule_pair_distances(
    poses: np.ndarray,  # (B, 13)
    radius: np.ndarray,  # (B,) capsule radius (unused for boxes)
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    is_capsule_pair: np.ndarray,  # (P,) bool
    out: np.ndarray,  # (P,) lower bounds, improved in place where both bodies are capsules
    threshold: float,
) -> None:
    """Exact distances of capsule-capsule pairs (segment distance minus both radii) into ``out``.

    Only where the bound in ``out`` is not already above ``threshold`` (the exact value is never needed
    there).
    """
    for k in range(pair_a.shape[0]):
        if not is_capsule_pair[k] or out[k] > threshold:
            continue
        a, b = pair_a[k], pair_b[k]
        za = poses[a, 6:9] * (0.5 * poses[a, 12])
        zb = poses[b, 6:9] * (0.5 * poses[b, 12])
        d = segment_distance(
            poses[a, 9:12] - za, poses[a, 9:12] + za, poses[b, 9:12] - zb, poses[b, 9:12] + zb
        )
        out[k] = d - radius[a] - radius[b]


@njit(cache=True, fastmath=False)
def state_bounds(
    poses: np.ndarray,  # (B, 13)
    fine_body: np.ndarray,
    fine_local: np.ndarray,
    fine_frac: np.ndarray,
    fine_r: np.ndarray,
    fine_bounds: np.ndarray,
    grid: np.ndarray,
    origin: np.ndarray,
    inv_step: float,
    shape: np.ndarray,
    has_grid: bool,
    coarse_body: np.ndarray,
    coarse_local: np.ndarray,
    coarse_frac: np.ndarray,
    coarse_r: np.ndarray,
    coarse_bounds: np.ndarray,
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    radius: np.ndarray,
    capsule_pair: np.ndarray,
    half: np.ndarray,
    capsule_box: np.ndarray,
    carriage: int,
    table: np.ndarray,  # exact carriage clearance along the rail (empty: none)
    table_z0: float,
    table_dz: float,
    c: np.ndarray,  # admissibility values at this state
    c_lo: np.ndarray,
    c_hi: np.ndarray,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Everything one state needs in one call.

    Returns the cabin bound per body (improved by the carriage's exact clearance table), the bound (or
    exact distance) per checked pair, and whether every admissibility value is within its bounds.
    """
    n_b = poses.shape[0]
    if has_grid:
        centres = cover_centres(poses, fine_body, fine_local, fine_frac)
        cabin = cabin_bounds(centres, fine_r, fine_bounds, grid, origin, inv_step, shape)
    else:
        cabin = np.full(n_b, math.inf)
    coarse = cover_centres(poses, coarse_body, coarse_local, coarse_frac)
    pairs = pair_bounds(coarse, coarse_r, coarse_bounds, pair_a, pair_b, threshold)
    capsule_pair_distances(poses, radius, pair_a, pair_b, capsule_pair, pairs, threshold)
    capsule_box_distances(poses, radius, half, pair_a, pair_b, capsule_box, pairs, threshold)
    if table.shape[0] > 0:
        d1 = poses[carriage, 11]  # the carriage centre's z is the rail position
        k = int(math.floor((d1 - table_z0) / table_dz + 0.5))
        k = min(max(k, 0), table.shape[0] - 1)
        exact = table[k] - abs(d1 - (table_z0 + k * table_dz))
        # Without cover spheres (the usual case) the table is the carriage's only bound.
        if exact > cabin[carriage] or cabin[carriage] == math.inf:
            cabin[carriage] = exact
    ok = True
    for i in range(c.shape[0]):
        if not (c[i] >= c_lo[i] and c[i] <= c_hi[i]):
            ok = False
    return cabin, pairs, ok


@njit(cache=True, fastmath=False)
def _point_box_distance(x: float, y: float, z: float, hx: float, hy: float, hz: float) -> float:
    dx = max(abs(x) - hx, 0.0)
    dy = max(abs(y) - hy, 0.0)
    dz = max(abs(z) - hz, 0.0)
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, fastmath=False)
def segment_box_distance(p: np.ndarray, q: np.ndarray, half: np.ndarray) -> float:
    """Distance from the segment p-q to the axis-aligned box [-half, half] (both in the box frame).

    The distance from P(t) = p + t (q - p) to a convex set is convex in t, so a golden-section search on
    [0, 1] converges to the minimum; 60 iterations shrink the interval to 3e-13 of the segment.
    """
    lo, hi = 0.0, 1.0
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    d = q - p
    t1 = hi - g * (hi - lo)
    t2 = lo + g * (hi - lo)
    f1 = _point_box_distance(p[0] + t1 * d[0], p[1] + t1 * d[1], p[2] + t1 * d[2], half[0], half[1], half[2])
    f2 = _point_box_distance(p[0] + t2 * d[0], p[1] + t2 * d[1], p[2] + t2 * d[2], half[0], half[1], half[2])
    for _ in range(60):
        if f1 <= f2:
            hi, t2, f2 = t2, t1, f1
            t1 = hi - g * (hi - lo)
            f1 = _point_box_distance(
                p[0] + t1 * d[0], p[1] + t1 * d[1], p[2] + t1 * d[2], half[0], half[1], half[2]
            )
        else:
            lo, t1, f1 = t1, t2, f2
            t2 = lo + g * (hi - lo)
            f2 = _point_box_distance(
                p[0] + t2 * d[0], p[1] + t2 * d[1], p[2] + t2 * d[2], half[0], half[1], half[2]
            )
    ends = min(
        _point_box_distance(p[0], p[1], p[2], half[0], half[1], half[2]),
        _point_box_distance(q[0], q[1], q[2], half[0], half[1], half[2]),
    )
    return min(f1, f2, ends)


@njit(cache=True, fastmath=False)
def capsule_box_distances(
    poses: np.ndarray,  # (B, 13)
    radius: np.ndarray,  # (B,)
    half: np.ndarray,  # (B, 3) box half sizes (zeros for capsules)
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    capsule_box: np.ndarray,  # (P,) int: 0 none, 1 a is the capsule, 2 b is the capsule
    out: np.ndarray,
    threshold: float,
) -> None:
    """Exact capsule-box distances (segment-to-box distance minus the radius) into ``out``.

    Only where the bound in ``out`` is not already above ``threshold``.
    """
    for k in range(pair_a.shape[0]):
        kind = capsule_box[k]
        if kind == 0 or out[k] > threshold:
            continue
        c, b = (pair_a[k], pair_b[k]) if kind == 1 else (pair_b[k], pair_a[k])
        z = poses[c, 6:9] * (0.5 * poses[c, 12])
        p0 = poses[c, 9:12] - z - poses[b, 9:12]
        p1 = poses[c, 9:12] + z - poses[b, 9:12]
        # Into the box frame: R^T v, with R column-major in poses[b, 0:9].
        a0 = np.empty(3)
        a1 = np.empty(3)
        for i in range(3):
            a0[i] = poses[b, 3 * i] * p0[0] + poses[b, 3 * i + 1] * p0[1] + poses[b, 3 * i + 2] * p0[2]
            a1[i] = poses[b, 3 * i] * p1[0] + poses[b, 3 * i + 1] * p1[1] + poses[b, 3 * i + 2] * p1[2]
        out[k] = segment_box_distance(a0, a1, half[b]) - radius[c]
