"""Exact distances between the robot's convex bodies (segments, capsules, boxes), compiled.

Capsule-capsule pairs: the distance of their axes' segments minus both radii (:func:`segment_distance`,
clamped closest points). Capsule-box pairs: the distance of the capsule's axis to the box in the box frame
minus the radius (:func:`segment_box_distance`, a golden-section search on a convex function). A pair's
probe on grown bodies (:func:`pair_touches`) uses the same distances, and separating axes for two boxes.
Poses are rows of 13 values: R column-major (9), centre p (3), capsule length (1).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False)
def dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """The dot product of two 3-vectors given by their components, summed in sequence (numpy's order)."""
    return (a0 * b0 + a1 * b1) + a2 * b2


@njit(cache=True, fastmath=False)
def segment_segment_sq(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray) -> float:
    """Squared distance between the segments [p, q] and [r, s].

    Ericson, Real-Time Collision Detection, 5.1.9: clamped closest points, robust when parallel or
    degenerate; no temporaries, as the cabin's triangle tests call it 36 times a box-triangle pair
    (:mod:`.mesh`).
    """
    d10, d11, d12 = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    d20, d21, d22 = s[0] - r[0], s[1] - r[1], s[2] - r[2]
    r0, r1, r2 = p[0] - r[0], p[1] - r[1], p[2] - r[2]
    a = dot3(d10, d11, d12, d10, d11, d12)
    e = dot3(d20, d21, d22, d20, d21, d22)
    f = dot3(d20, d21, d22, r0, r1, r2)
    eps = 1e-14
    if a <= eps and e <= eps:
        return dot3(r0, r1, r2, r0, r1, r2)
    if a <= eps:
        sc = 0.0
        tc = min(max(f / e, 0.0), 1.0)
    else:
        c = dot3(d10, d11, d12, r0, r1, r2)
        if e <= eps:
            tc = 0.0
            sc = min(max(-c / a, 0.0), 1.0)
        else:
            b = dot3(d10, d11, d12, d20, d21, d22)
            den = a * e - b * b
            sc = min(max((b * f - c * e) / den, 0.0), 1.0) if den > eps else 0.0
            tc = (b * sc + f) / e
            if tc < 0.0:
                tc = 0.0
                sc = min(max(-c / a, 0.0), 1.0)
            elif tc > 1.0:
                tc = 1.0
                sc = min(max((b - c) / a, 0.0), 1.0)
    x0 = (p[0] + d10 * sc) - (r[0] + d20 * tc)
    x1 = (p[1] + d11 * sc) - (r[1] + d21 * tc)
    x2 = (p[2] + d12 * sc) - (r[2] + d22 * tc)
    return dot3(x0, x1, x2, x0, x1, x2)


@njit(cache=True, fastmath=False)
def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    """Exact distance between the segments p1-q1 and p2-q2 (:func:`segment_segment_sq`)."""
    return math.sqrt(segment_segment_sq(p1, q1, p2, q2))


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
        out[k] = capsule_capsule_distance(poses, radius, pair_a[k], pair_b[k])


@njit(cache=True, fastmath=False)
def capsule_capsule_distance(poses: np.ndarray, radius: np.ndarray, a: int, b: int) -> float:
    """Exact distance of the capsules a and b: segment distance minus both radii."""
    za = poses[a, 6:9] * (0.5 * poses[a, 12])
    zb = poses[b, 6:9] * (0.5 * poses[b, 12])
    d = segment_distance(poses[a, 9:12] - za, poses[a, 9:12] + za, poses[b, 9:12] - zb, poses[b, 9:12] + zb)
    return d - radius[a] - radius[b]


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
        out[k] = capsule_box_distance(poses, radius, half, pair_a[k], pair_b[k], kind)


@njit(cache=True, fastmath=False)
def capsule_box_distance(
    poses: np.ndarray, radius: np.ndarray, half: np.ndarray, a: int, b: int, kind: int
) -> float:
    """Exact capsule-box distance of pair (a, b); ``kind`` 1: a is the capsule, 2: b is."""
    c, b = (a, b) if kind == 1 else (b, a)
    z = poses[c, 6:9] * (0.5 * poses[c, 12])
    p0 = poses[c, 9:12] - z - poses[b, 9:12]
    p1 = poses[c, 9:12] + z - poses[b, 9:12]
    # Into the box frame: R^T v, with R column-major in poses[b, 0:9].
    a0 = np.empty(3)
    a1 = np.empty(3)
    for i in range(3):
        a0[i] = poses[b, 3 * i] * p0[0] + poses[b, 3 * i + 1] * p0[1] + poses[b, 3 * i + 2] * p0[2]
        a1[i] = poses[b, 3 * i] * p1[0] + poses[b, 3 * i + 1] * p1[1] + poses[b, 3 * i + 2] * p1[2]
    return segment_box_distance(a0, a1, half[b]) - radius[c]


@njit(cache=True, fastmath=False)
def _boxes_overlap(pa: np.ndarray, ha: np.ndarray, pb: np.ndarray, hb: np.ndarray, grow: float) -> bool:
    """Whether two boxes, each grown as a box by ``grow`` (its faces moved out), overlap (closed sets).

    Poses ``pa``, ``pb`` (13,): R column-major, centre; half extents ``ha``, ``hb``. The separating axis
    test on the 15 axes of two boxes: their 6 face normals and the 9 cross products of their edges (a
    product of parallel edges, of length below 1e-12, is skipped: the face normals decide that case).
    """
    t0, t1, t2 = pb[9] - pa[9], pb[10] - pa[10], pb[11] - pa[11]
    axes = np.empty((15, 3))
    for i in range(3):
        for c in range(3):
            axes[i, c] = pa[3 * i + c]
            axes[3 + i, c] = pb[3 * i + c]
    n = 6
    for i in range(3):
        for j in range(3):
            u0, u1, u2 = pa[3 * i], pa[3 * i + 1], pa[3 * i + 2]
            v0, v1, v2 = pb[3 * j], pb[3 * j + 1], pb[3 * j + 2]
            x0, x1, x2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
            if dot3(x0, x1, x2, x0, x1, x2) > 1e-24:
                axes[n, 0], axes[n, 1], axes[n, 2] = x0, x1, x2
                n += 1
    for k in range(n):
        l0, l1, l2 = axes[k, 0], axes[k, 1], axes[k, 2]
        reach = 0.0
        for i in range(3):
            reach += (ha[i] + grow) * abs(dot3(pa[3 * i], pa[3 * i + 1], pa[3 * i + 2], l0, l1, l2))
            reach += (hb[i] + grow) * abs(dot3(pb[3 * i], pb[3 * i + 1], pb[3 * i + 2], l0, l1, l2))
        if abs(dot3(t0, t1, t2, l0, l1, l2)) > reach:
            return False
    return True


@njit(cache=True, fastmath=False)
def pair_touches(
    poses: np.ndarray,  # (B, 13)
    radius: np.ndarray,  # (B,) capsule radius (0 for boxes)
    half: np.ndarray,  # (B, 3) box half extents (zeros for capsules)
    a: int,
    b: int,
    grow: float,
) -> bool:
    """Whether bodies a and b, each grown by ``grow`` / 2 (a box as a box, a capsule's radius), touch.

    FCL's verdict on the same grown shapes (``Probes.pair_hit``), exact: two capsules by their axes'
    distance (:func:`capsule_capsule_distance`), a capsule and a box by the axis's distance to the grown
    box (:func:`segment_box_distance`), two boxes by separating axes (:func:`_boxes_overlap`). FCL's own
    GJK misses two capsules' contact by up to 1 um.
    """
    g = 0.5 * grow
    if radius[a] > 0.0 and radius[b] > 0.0:
        return capsule_capsule_distance(poses, radius, a, b) <= grow
    if radius[a] > 0.0 or radius[b] > 0.0:
        c, x = (a, b) if radius[a] > 0.0 else (b, a)
        z = poses[c, 6:9] * (0.5 * poses[c, 12])
        p0 = poses[c, 9:12] - z - poses[x, 9:12]
        p1 = poses[c, 9:12] + z - poses[x, 9:12]
        s0 = np.empty(3)
        s1 = np.empty(3)
        grown = np.empty(3)
        for i in range(3):  # into the box frame: R^T v, R column-major in poses[x, 0:9]
            s0[i] = poses[x, 3 * i] * p0[0] + poses[x, 3 * i + 1] * p0[1] + poses[x, 3 * i + 2] * p0[2]
            s1[i] = poses[x, 3 * i] * p1[0] + poses[x, 3 * i + 1] * p1[1] + poses[x, 3 * i + 2] * p1[2]
            grown[i] = half[x, i] + g
        return segment_box_distance(s0, s1, grown) <= radius[c] + g
    return _boxes_overlap(poses[a], half[a], poses[b], half[b], g)
