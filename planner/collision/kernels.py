"""Compiled (numba) kernels of the collision hot path.

* Certified lower bounds from sphere covers (:func:`state_bounds`): the same bounds as the numpy
  reference in :class:`planner.collision.world.CollisionWorld` (``cabin_lower_bounds`` /
  ``pair_lower_bounds``; the tests check they agree), in one pass without temporaries.
* Body poses and admissibility in closed form (:func:`body_poses`, :func:`constraints`: paper eq. 4 and
  the MDH chain eq. 10-12), equal to the CasADi model to 1e-12.
* A world's constant data packed into two flat buffers (:func:`pack`), so one state check is one call
  with a handful of arguments (:func:`packed_check`, :func:`packed_state`), and certain contacts from the
  grid's upper bound (:func:`certain_cabin_contact`).
* The certified motion walk (:func:`motion_walk`), resumable around the FCL probes that stay in Python,
  with states and per-body / per-pair bounds evaluated on demand (:func:`cabin_bound_one`,
  :func:`pair_bound_one`: the numbers of :func:`state_bounds`).
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
def cover_centres_batch(
    poses: np.ndarray, body: np.ndarray, local: np.ndarray, frac: np.ndarray
) -> np.ndarray:
    """:func:`cover_centres` for (N, B, 13) poses: (N, S, 3)."""
    out = np.empty((poses.shape[0], body.shape[0], 3))
    for k in range(poses.shape[0]):
        out[k] = cover_centres(poses[k], body, local, frac)
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
        out[k] = _capsule_capsule(poses, radius, pair_a[k], pair_b[k])


@njit(cache=True, fastmath=False)
def _capsule_capsule(poses: np.ndarray, radius: np.ndarray, a: int, b: int) -> float:
    """Exact distance of the capsules a and b: segment distance minus both radii."""
    za = poses[a, 6:9] * (0.5 * poses[a, 12])
    zb = poses[b, 6:9] * (0.5 * poses[b, 12])
    d = segment_distance(poses[a, 9:12] - za, poses[a, 9:12] + za, poses[b, 9:12] - zb, poses[b, 9:12] + zb)
    return d - radius[a] - radius[b]


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
        out[k] = _capsule_box(poses, radius, half, pair_a[k], pair_b[k], kind)


@njit(cache=True, fastmath=False)
def _capsule_box(poses: np.ndarray, radius: np.ndarray, half: np.ndarray, a: int, b: int, kind: int) -> float:
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


# ----------------------------------------------------------------------------------------------- poses
#: Body kinds of :func:`body_poses` (the order of :data:`planner.collision.bodies.BODY_NAMES`).
KIND_CODES = {
    "carriage": 0,
    "link_ab": 1,
    "link_cd": 2,
    "link_ef": 3,
    "platform": 4,
    "column": 5,
    "arm": 6,
    "slide": 7,
    "payload": 8,
}
#: Length of the admissibility vector c(q) (:meth:`planner.robots.cabin8.Cabin8.constraint_specs`).
N_CONSTRAINTS = 16


@njit(cache=True, fastmath=False, error_model="numpy")
def _root(v: float) -> float:
    """sqrt(v), NaN below 0 (as numpy: a link that cannot reach the rail gives NaN, never an exception)."""
    return math.sqrt(v) if v >= 0.0 else math.nan


@njit(cache=True, fastmath=False, error_model="numpy")
def _segment_pose(a: np.ndarray, b: np.ndarray, row: np.ndarray) -> None:
    """Capsule frame from a to b into ``row`` (13): z along b - a, centred at the midpoint, length |b - a|.

    The same construction as the CasADi pose function: x = helper x z normalised, y = z x x, with the
    helper (1, 0, 0) unless z is within ~26 degrees of it, then (0, 1, 0).
    """
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    zx, zy, zz = dx / length, dy / length, dz / length
    if abs(zx) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    xx, xy, xz = hy * zz - hz * zy, hz * zx - hx * zz, hx * zy - hy * zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    row[0], row[1], row[2] = xx, xy, xz
    row[3], row[4], row[5] = yx, yy, yz
    row[6], row[7], row[8] = zx, zy, zz
    row[9], row[10], row[11] = 0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])
    row[12] = length


@njit(cache=True, fastmath=False, error_model="numpy")
def constraints(
    q: np.ndarray, stage: np.ndarray, c: np.ndarray
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The admissibility vector c(q) into ``c`` (16); returns the stage points (x1, x2, x3, B, C, E).

    Stage (paper eq. 4): B, C = (x, y) -/+ L2/2 (cos g, sin g); x1 = x_B - sqrt(L1^2 - y_B^2),
    x2 = x_C + sqrt(L3^2 - y_C^2), E = (A + B)/2, x3 = x_E + sqrt(L4^2 - y_E^2); then the values of
    ``planner.robots.cabin8.constraint_terms`` in its order (NaN where a link cannot reach the rail).
    """
    L1, L2, L3, L4 = stage[0], stage[1], stage[2], stage[3]
    d1, x, y, g = q[0], q[1], q[2], q[3]
    h = 0.5 * L2
    cg, sg = math.cos(g), math.sin(g)
    xb, yb = x - h * cg, y - h * sg
    xc, yc = x + h * cg, y + h * sg
    x1 = xb - _root(L1 * L1 - yb * yb)
    x2 = xc + _root(L3 * L3 - yc * yc)
    xe, ye = 0.5 * (x1 + xb), 0.5 * yb
    x3 = xe + _root(L4 * L4 - ye * ye)
    c[0], c[1], c[2], c[3] = d1, x1, x2, x3
    for i in range(4, 8):
        c[i] = q[i]
    c[8], c[9], c[10], c[11] = y, g, x3 - x1, x2 - x3
    bd_x, bd_y = x2 - xb, -yb
    cross = (xc - xb) * bd_y - (yc - yb) * bd_x
    c[12] = -cross / (L2 * math.sqrt(bd_x * bd_x + bd_y * bd_y))
    c[13], c[14], c[15] = yb / L1, yc / L3, ye / L4
    return x1, x2, x3, xb, yb, xc, yc, xe, ye


@njit(cache=True, fastmath=False, error_model="numpy")
def body_poses(
    q: np.ndarray,  # (8,) joints (d1, x, y, gamma, theta3, theta4, d5, theta6)
    T_tool_box: np.ndarray,  # (4, 4) payload box frame in the tool frame
    mdh: np.ndarray,  # (4, 6) per MDH link: alpha, a, theta offset, d offset, joint index, revolute (1/0)
    stage: np.ndarray,  # (4,) L1, L2, L3, L4
    kinds: np.ndarray,  # (B,) body kind codes (KIND_CODES)
    poses: np.ndarray,  # (B, 13) out: R column-major, p, capsule length
    c: np.ndarray,  # (16,) out: admissibility values c(q)
) -> None:
    """Body poses and the admissibility vector at one configuration, closed form (no CasADi call).

    Stage points and c(q) from :func:`constraints`. Chain (eq. 10-12):
    T_2 = Trans(x, y, d1) RotZ(gamma), then T_i = T_(i-1) RotX(alpha) TransX(a) RotZ(theta) TransZ(d).
    The same quantities, in the same order, as the CasADi pose function and ``constraint_terms``; the
    tests check both agree to 1e-12.
    """
    x1, x2, x3, xb, yb, xc, yc, xe, ye = constraints(q, stage, c)
    d1, x, y, g = q[0], q[1], q[2], q[3]
    cg, sg = math.cos(g), math.sin(g)
    # Serial chain: R (3, 3) and p (3,) of frames 2..6; origins kept for the capsules.
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = cg, -sg, 0.0
    R[1, 0], R[1, 1], R[1, 2] = sg, cg, 0.0
    R[2, 0], R[2, 1], R[2, 2] = 0.0, 0.0, 1.0
    p = np.empty(3)
    p[0], p[1], p[2] = x, y, d1
    R2 = R.copy()
    origins = np.empty((5, 3))  # frames 2, 3, 4, 5, 6
    origins[0] = p
    M = np.empty((3, 3))
    Rn = np.empty((3, 3))
    for i in range(4):
        alpha, a, th0, dd0 = mdh[i, 0], mdh[i, 1], mdh[i, 2], mdh[i, 3]
        j = int(mdh[i, 4])
        if mdh[i, 5] > 0.5:
            theta, d = q[j] + th0, dd0
        else:
            theta, d = th0, q[j] + dd0
        ct, st = math.cos(theta), math.sin(theta)
        cal, sal = math.cos(alpha), math.sin(alpha)
        M[0, 0], M[0, 1], M[0, 2] = ct, -st, 0.0
        M[1, 0], M[1, 1], M[1, 2] = st * cal, ct * cal, -sal
        M[2, 0], M[2, 1], M[2, 2] = st * sal, ct * sal, cal
        mp0, mp1, mp2 = a, -sal * d, cal * d
        for r in range(3):
            p[r] = p[r] + R[r, 0] * mp0 + R[r, 1] * mp1 + R[r, 2] * mp2
            for k in range(3):
                Rn[r, k] = R[r, 0] * M[0, k] + R[r, 1] * M[1, k] + R[r, 2] * M[2, k]
        R[:, :] = Rn
        origins[i + 1] = p
    pa = np.empty(3)
    pb = np.empty(3)
    for b in range(kinds.shape[0]):
        kind = kinds[b]
        row = poses[b]
        if kind == 0:  # carriage: axis-aligned at (0, -0.06, d1)
            for i in range(9):
                row[i] = 0.0
            row[0] = row[4] = row[8] = 1.0
            row[9], row[10], row[11], row[12] = 0.0, -0.06, d1, 0.0
        elif kind == 4:  # platform: frame 2
            for jj in range(3):
                for i in range(3):
                    row[3 * jj + i] = R2[i, jj]
            row[9], row[10], row[11], row[12] = origins[0, 0], origins[0, 1], origins[0, 2], 0.0
        elif kind == 8:  # payload: T_6 T_tool_box
            for jj in range(3):
                for i in range(3):
                    row[3 * jj + i] = (
                        R[i, 0] * T_tool_box[0, jj]
                        + R[i, 1] * T_tool_box[1, jj]
                        + R[i, 2] * T_tool_box[2, jj]
                    )
            for i in range(3):
                row[9 + i] = (
                    R[i, 0] * T_tool_box[0, 3]
                    + R[i, 1] * T_tool_box[1, 3]
                    + R[i, 2] * T_tool_box[2, 3]
                    + p[i]
                )
            row[12] = 0.0
        else:
            if kind == 1:  # A -> B
                pa[0], pa[1], pa[2] = x1, 0.0, d1
                pb[0], pb[1], pb[2] = xb, yb, d1
            elif kind == 2:  # C -> D
                pa[0], pa[1], pa[2] = xc, yc, d1
                pb[0], pb[1], pb[2] = x2, 0.0, d1
            elif kind == 3:  # E -> F
                pa[0], pa[1], pa[2] = xe, ye, d1
                pb[0], pb[1], pb[2] = x3, 0.0, d1
            else:  # column 2 -> 3, arm 3 -> 4, slide 4 -> 6
                first = 0 if kind == 5 else 1 if kind == 6 else 2
                last = 1 if kind == 5 else 2 if kind == 6 else 4
                pa[:] = origins[first]
                pb[:] = origins[last]
            _segment_pose(pa, pb, row)


@njit(cache=True, fastmath=False, error_model="numpy")
def admissible(c: np.ndarray, c_lo: np.ndarray, c_hi: np.ndarray) -> bool:
    """Every admissibility value within its (already tolerance-widened) bounds; NaN is not."""
    for i in range(c.shape[0]):
        if not (c[i] >= c_lo[i] and c[i] <= c_hi[i]):
            return False
    return True


# ------------------------------------------------------------------------------------- packed world
# A world's constant kernel data travels in two flat buffers (float64, int64) plus the grid: a Python call
# into a compiled function costs ~0.1 us per argument, so four arguments instead of thirty-odd matter on
# a 20 us hot path. ``pack`` lays them out, ``_unpack`` takes views (no copies) in the same order.
_HEADER = 10


def pack(
    T_tool_box: np.ndarray,
    mdh: np.ndarray,
    stage: np.ndarray,
    kinds: np.ndarray,
    fine: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],  # body, local, frac, r, bounds
    origin: np.ndarray,
    inv_step: float,
    shape: np.ndarray,
    has_grid: bool,
    coarse: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    radius: np.ndarray,
    capsule_pair: np.ndarray,
    half: np.ndarray,
    capsule_box: np.ndarray,
    carriage: int,
    table: np.ndarray,
    table_z0: float,
    table_dz: float,
    c_lo: np.ndarray,
    c_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(fbuf, ibuf) of a world's kernel data, in the layout :func:`_unpack` reads."""
    n_b, n_s, n_c, n_p, n_t = len(kinds), len(fine[3]), len(coarse[3]), len(pair_a), len(table)
    header = [n_b, n_s, n_c, n_p, n_t, int(has_grid), int(carriage), *(int(x) for x in shape)]
    ints = [
        np.array(header + [0] * (_HEADER - len(header))),
        kinds,
        fine[0],
        fine[4],
        coarse[0],
        coarse[4],
        pair_a,
        pair_b,
        np.asarray(capsule_pair, dtype=np.int64),
        capsule_box,
    ]
    floats = [
        T_tool_box.ravel(),
        mdh.ravel(),
        stage,
        fine[1].ravel(),
        fine[2],
        fine[3],
        origin,
        np.array([inv_step]),
        coarse[1].ravel(),
        coarse[2],
        coarse[3],
        radius,
        half.ravel(),
        table,
        np.array([table_z0, table_dz]),
        c_lo,
        c_hi,
    ]
    fbuf = np.ascontiguousarray(np.concatenate([np.asarray(f, dtype=np.float64).ravel() for f in floats]))
    ibuf = np.ascontiguousarray(np.concatenate([np.asarray(i, dtype=np.int64).ravel() for i in ints]))
    return fbuf, ibuf


@njit(cache=True, fastmath=False, error_model="numpy")
def _unpack(fbuf: np.ndarray, ibuf: np.ndarray):  # type: ignore[no-untyped-def]
    """Views of the packed world data, in the order :func:`state_bounds` takes them (grid excluded)."""
    n_b, n_s, n_c, n_p, n_t = ibuf[0], ibuf[1], ibuf[2], ibuf[3], ibuf[4]
    has_grid, carriage = ibuf[5] != 0, ibuf[6]
    shape = ibuf[7:10]
    o = _HEADER
    kinds = ibuf[o : o + n_b]
    o += n_b
    fine_body = ibuf[o : o + n_s]
    o += n_s
    fine_bounds = ibuf[o : o + n_b + 1]
    o += n_b + 1
    coarse_body = ibuf[o : o + n_c]
    o += n_c
    coarse_bounds = ibuf[o : o + n_b + 1]
    o += n_b + 1
    pair_a = ibuf[o : o + n_p]
    o += n_p
    pair_b = ibuf[o : o + n_p]
    o += n_p
    capsule_pair = ibuf[o : o + n_p]
    o += n_p
    capsule_box = ibuf[o : o + n_p]
    f = 0
    T = fbuf[f : f + 16].reshape((4, 4))
    f += 16
    mdh = fbuf[f : f + 24].reshape((4, 6))
    f += 24
    stage = fbuf[f : f + 4]
    f += 4
    fine_local = fbuf[f : f + 3 * n_s].reshape((n_s, 3))
    f += 3 * n_s
    fine_frac = fbuf[f : f + n_s]
    f += n_s
    fine_r = fbuf[f : f + n_s]
    f += n_s
    origin = fbuf[f : f + 3]
    f += 3
    inv_step = fbuf[f]
    f += 1
    coarse_local = fbuf[f : f + 3 * n_c].reshape((n_c, 3))
    f += 3 * n_c
    coarse_frac = fbuf[f : f + n_c]
    f += n_c
    coarse_r = fbuf[f : f + n_c]
    f += n_c
    radius = fbuf[f : f + n_b]
    f += n_b
    half = fbuf[f : f + 3 * n_b].reshape((n_b, 3))
    f += 3 * n_b
    table = fbuf[f : f + n_t]
    f += n_t
    z0, dz = fbuf[f], fbuf[f + 1]
    f += 2
    c_lo = fbuf[f : f + N_CONSTRAINTS]
    f += N_CONSTRAINTS
    c_hi = fbuf[f : f + N_CONSTRAINTS]
    return (
        T,
        mdh,
        stage,
        kinds,
        fine_body,
        fine_local,
        fine_frac,
        fine_r,
        fine_bounds,
        origin,
        inv_step,
        shape,
        has_grid,
        coarse_body,
        coarse_local,
        coarse_frac,
        coarse_r,
        coarse_bounds,
        pair_a,
        pair_b,
        radius,
        capsule_pair,
        half,
        capsule_box,
        carriage,
        table,
        z0,
        dz,
        c_lo,
        c_hi,
    )


@njit(cache=True, fastmath=False, error_model="numpy")
def _packed_state(
    q: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, grid: np.ndarray, threshold: float, poses: np.ndarray
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Poses into ``poses`` and (cabin bounds, pair bounds, admissible) at q, from the packed data."""
    (
        T,
        mdh,
        stage,
        kinds,
        fine_body,
        fine_local,
        fine_frac,
        fine_r,
        fine_bounds,
        origin,
        inv_step,
        shape,
        has_grid,
        coarse_body,
        coarse_local,
        coarse_frac,
        coarse_r,
        coarse_bounds,
        pair_a,
        pair_b,
        radius,
        capsule_pair,
        half,
        capsule_box,
        carriage,
        table,
        z0,
        dz,
        c_lo,
        c_hi,
    ) = _unpack(fbuf, ibuf)
    c = np.empty(N_CONSTRAINTS)
    body_poses(q, T, mdh, stage, kinds, poses, c)
    return state_bounds(
        poses,
        fine_body,
        fine_local,
        fine_frac,
        fine_r,
        fine_bounds,
        grid,
        origin,
        inv_step,
        shape,
        has_grid,
        coarse_body,
        coarse_local,
        coarse_frac,
        coarse_r,
        coarse_bounds,
        pair_a,
        pair_b,
        radius,
        capsule_pair,
        half,
        capsule_box,
        carriage,
        table,
        z0,
        dz,
        c,
        c_lo,
        c_hi,
        threshold,
    )


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_state(
    q: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, grid: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(poses, cabin bounds, pair bounds, admissible) at q: :func:`state_full` on the packed data."""
    poses = np.empty((ibuf[0], 13))
    cabin, pairs, ok = _packed_state(q, fbuf, ibuf, grid, threshold, poses)
    return poses, cabin, pairs, ok


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_poses(
    qs: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, poses: np.ndarray, c: np.ndarray
) -> None:
    """:func:`body_poses` at every row of ``qs`` (N, 8) into ``poses`` (N, B, 13) and ``c`` (N, 16)."""
    u = _unpack(fbuf, ibuf)
    for i in range(qs.shape[0]):
        body_poses(qs[i], u[0], u[1], u[2], u[3], poses[i], c[i])


@njit(cache=True, fastmath=False, error_model="numpy")
def run_extent(qs: np.ndarray, i: int, j: int, rho: np.ndarray, max_extra: float) -> tuple[int, float]:
    """The run of :meth:`CollisionWorld.check_path` from sample i: (its last sample, its extra clearance).

    Starting at j, the run is halved until the samples' reach-weighted deviation from the chord
    q_i -> q_j (parameterised alike: sample k at (k - i) / (j - i)), doubled for self pairs, plus 1e-6, is
    at most ``max_extra``; a single piece has no extra.
    """
    n_j = qs.shape[1]
    while j > i + 1:
        m = j - i
        worst = 0.0
        for a in range(n_j):
            e = 0.0
            step = qs[j, a] - qs[i, a]
            for k in range(1, m):
                d = abs(qs[i + k, a] - (qs[i, a] + (k / m) * step))
                if d > e:
                    e = d
            worst += rho[a] * e
        extra = worst * 2.0 + 1e-6
        if extra <= max_extra:
            return j, extra
        j = i + max(1, m // 2)
    return j, 0.0


#: Codes of :func:`packed_check`.
CLEAR, INADMISSIBLE, UNDECIDED, NOT_FINITE, CONTACT = 0, 1, 2, 3, 4


@njit(cache=True, fastmath=False, error_model="numpy")
def certain_cabin_contact(
    b: int,
    poses: np.ndarray,
    clearance: float,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    upper_slack: float,
) -> bool:
    """True when the cabin surface certainly enters body b grown by ``clearance`` (FCL would report it).

    At a fine-cover centre x the grid bounds the distance to the surface from above by
    UB(x) = LB(x) + ``upper_slack`` (where LB is finite); if the ball of radius UB(x) about x lies inside
    the grown body (box: UB(x) < min_i (h_i + clearance - |x_i|) in the body frame; capsule, x on the
    axis: UB(x) < r + clearance), a surface point -- hence a triangle -- lies strictly inside it.
    """
    u = _unpack(fbuf, ibuf)
    fine_local, fine_frac, fine_bounds = u[5], u[6], u[8]
    origin, inv_step, shape, has_grid = u[9], u[10], u[11], u[12]
    radius, half = u[20], u[22]
    if not has_grid:
        return False
    is_box = half[b, 0] > 0.0
    sy = shape[1] * shape[2]
    sz = shape[2]
    centre = np.empty(3)
    for s in range(fine_bounds[b], fine_bounds[b + 1]):
        if is_box:
            inner = math.inf
            for i in range(3):
                inner = min(inner, half[b, i] + clearance - abs(fine_local[s, i]))
        else:
            inner = radius[b] + clearance
        if inner <= upper_slack:  # UB >= upper_slack: cannot fit
            continue
        for i in range(3):
            v = poses[b, 9 + i] + fine_frac[s] * poses[b, 12] * poses[b, 6 + i]
            for j in range(3):
                v += poses[b, 3 * j + i] * fine_local[s, j]
            centre[i] = v
        i0 = min(max(int(math.floor((centre[0] - origin[0]) * inv_step + 0.5)), 0), shape[0] - 1)
        j0 = min(max(int(math.floor((centre[1] - origin[1]) * inv_step + 0.5)), 0), shape[1] - 1)
        k0 = min(max(int(math.floor((centre[2] - origin[2]) * inv_step + 0.5)), 0), shape[2] - 1)
        lb = grid[i0 * sy + j0 * sz + k0]
        if math.isfinite(lb) and lb + upper_slack + 1e-6 < inner:
            return True
    return False


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_check(
    q: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    clearance: float,
    self_clearance: float,
    upper_slack: float,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The compiled part of a state check: (code, poses, cabin bounds, pair bounds).

    ``CLEAR``: admissible and the bounds prove every body ``clearance`` from the cabin and every pair
    ``self_clearance`` apart. ``INADMISSIBLE``: a limit or margin fails. ``CONTACT``: admissible, and
    the cabin certainly enters some body grown by ``clearance`` (:func:`certain_cabin_contact`; a
    negative ``upper_slack`` disables the test). ``UNDECIDED``: admissible, but some body or pair needs
    an exact (FCL) query. ``NOT_FINITE``: a joint is NaN or infinite.
    """
    poses = np.empty((ibuf[0], 13))
    for i in range(q.shape[0]):
        if not math.isfinite(q[i]):
            return NOT_FINITE, poses, np.empty(0), np.empty(0)
    cabin, pairs, ok = _packed_state(q, fbuf, ibuf, grid, self_clearance, poses)
    if not ok:
        return INADMISSIBLE, poses, cabin, pairs
    code = CLEAR
    for b in range(cabin.shape[0]):
        if not cabin[b] > clearance:
            if upper_slack >= 0.0 and certain_cabin_contact(
                b, poses, clearance, fbuf, ibuf, grid, upper_slack
            ):
                return CONTACT, poses, cabin, pairs
            code = UNDECIDED
    if code == CLEAR:
        for k in range(pairs.shape[0]):
            if not pairs[k] > self_clearance:
                return UNDECIDED, poses, cabin, pairs
    return code, poses, cabin, pairs


# ------------------------------------------------------------------------------- bounds one by one
# The motion walk reads few bounds at most of its states: these compute one body's or one pair's entry of
# :func:`state_bounds` on demand, with the same arithmetic in the same order (so the same numbers).
@njit(cache=True, fastmath=False, error_model="numpy")
def cabin_bound_one(b: int, poses: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, grid: np.ndarray) -> float:
    """Entry b of the cabin bounds of :func:`state_bounds` (sphere cover on the grid, carriage table)."""
    return _cabin_bound(b, poses, _unpack(fbuf, ibuf), grid)


@njit(cache=True, fastmath=False, error_model="numpy")
def _cabin_bound(b, poses, u, grid):  # type: ignore[no-untyped-def]
    """:func:`cabin_bound_one` on unpacked data ``u`` (:func:`_unpack`), without allocations."""
    fine_local, fine_frac, fine_r, fine_bounds = u[5], u[6], u[7], u[8]
    origin, inv_step, shape, has_grid = u[9], u[10], u[11], u[12]
    carriage, table, table_z0, table_dz = u[24], u[25], u[26], u[27]
    best = math.inf
    if has_grid:
        sy = shape[1] * shape[2]
        sz = shape[2]
        for s in range(fine_bounds[b], fine_bounds[b + 1]):
            # The arithmetic of :func:`cover_centres`, component by component.
            lx, ly, lz, fl = fine_local[s, 0], fine_local[s, 1], fine_local[s, 2], fine_frac[s] * poses[b, 12]
            cx = poses[b, 9] + fl * poses[b, 6]
            cx += poses[b, 0] * lx
            cx += poses[b, 3] * ly
            cx += poses[b, 6] * lz
            cy = poses[b, 10] + fl * poses[b, 7]
            cy += poses[b, 1] * lx
            cy += poses[b, 4] * ly
            cy += poses[b, 7] * lz
            cz = poses[b, 11] + fl * poses[b, 8]
            cz += poses[b, 2] * lx
            cz += poses[b, 5] * ly
            cz += poses[b, 8] * lz
            i0 = int(math.floor((cx - origin[0]) * inv_step + 0.5))
            j0 = int(math.floor((cy - origin[1]) * inv_step + 0.5))
            k0 = int(math.floor((cz - origin[2]) * inv_step + 0.5))
            i0 = min(max(i0, 0), shape[0] - 1)
            j0 = min(max(j0, 0), shape[1] - 1)
            k0 = min(max(k0, 0), shape[2] - 1)
            v = grid[i0 * sy + j0 * sz + k0] - fine_r[s]
            if v < best:
                best = v
    if table.shape[0] > 0 and b == carriage:
        d1 = poses[carriage, 11]
        k = int(math.floor((d1 - table_z0) / table_dz + 0.5))
        k = min(max(k, 0), table.shape[0] - 1)
        exact = table[k] - abs(d1 - (table_z0 + k * table_dz))
        if exact > best or best == math.inf:
            best = exact
    return best


@njit(cache=True, fastmath=False, error_model="numpy")
def _coarse_box(b, poses, local, frac, r, bounds, out):  # type: ignore[no-untyped-def]
    """Coarse cover centres of body b into ``out`` (as :func:`cover_centres`); their box (lo, hi) x 3."""
    lo0 = lo1 = lo2 = math.inf
    hi0 = hi1 = hi2 = -math.inf
    for m in range(bounds[b + 1] - bounds[b]):
        s = bounds[b] + m
        for i in range(3):
            v = poses[b, 9 + i] + frac[s] * poses[b, 12] * poses[b, 6 + i]
            for j in range(3):
                v += poses[b, 3 * j + i] * local[s, j]
            out[m, i] = v
        lo0 = min(lo0, out[m, 0] - r[s])
        lo1 = min(lo1, out[m, 1] - r[s])
        lo2 = min(lo2, out[m, 2] - r[s])
        hi0 = max(hi0, out[m, 0] + r[s])
        hi1 = max(hi1, out[m, 1] + r[s])
        hi2 = max(hi2, out[m, 2] + r[s])
    return lo0, lo1, lo2, hi0, hi1, hi2


@njit(cache=True, fastmath=False, error_model="numpy")
def pair_bound_one(k: int, poses: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, threshold: float) -> float:
    """Entry k of the pair bounds of :func:`state_bounds` (box separation, sphere gaps, exact distances)."""
    u = _unpack(fbuf, ibuf)
    n = 0
    for b in range(u[17].shape[0] - 1):
        n = max(n, u[17][b + 1] - u[17][b])
    return _pair_bound(k, poses, u, threshold, np.empty((2 * n, 3)))


@njit(cache=True, fastmath=False, error_model="numpy")
def _pair_bound(k, poses, u, threshold, scratch):  # type: ignore[no-untyped-def]
    """:func:`pair_bound_one` on unpacked data; ``scratch`` holds two bodies' coarse centres."""
    coarse_local, coarse_frac, coarse_r, coarse_bounds = u[14], u[15], u[16], u[17]
    pair_a, pair_b, radius, capsule_pair, half, capsule_box = u[18], u[19], u[20], u[21], u[22], u[23]
    a, b = pair_a[k], pair_b[k]
    na = coarse_bounds[a + 1] - coarse_bounds[a]
    nb = coarse_bounds[b + 1] - coarse_bounds[b]
    ca_ = scratch[:na]
    cb_ = scratch[na : na + nb]
    la0, la1, la2, ha0, ha1, ha2 = _coarse_box(
        a, poses, coarse_local, coarse_frac, coarse_r, coarse_bounds, ca_
    )
    lb0, lb1, lb2, hb0, hb1, hb2 = _coarse_box(
        b, poses, coarse_local, coarse_frac, coarse_r, coarse_bounds, cb_
    )
    sep = -math.inf
    sep = max(sep, lb0 - ha0, la0 - hb0)
    sep = max(sep, lb1 - ha1, la1 - hb1)
    sep = max(sep, lb2 - ha2, la2 - hb2)
    if sep <= threshold:
        gap = math.inf
        for s in range(na):
            rs = coarse_r[coarse_bounds[a] + s]
            for t in range(nb):
                dx = ca_[s, 0] - cb_[t, 0]
                dy = ca_[s, 1] - cb_[t, 1]
                dz = ca_[s, 2] - cb_[t, 2]
                g = math.sqrt(dx * dx + dy * dy + dz * dz) - rs - coarse_r[coarse_bounds[b] + t]
                if g < gap:
                    gap = g
        sep = max(sep, gap)
    if capsule_pair[k] and not sep > threshold:
        return _capsule_capsule(poses, radius, a, b)
    kind = capsule_box[k]
    if kind != 0 and not sep > threshold:
        return _capsule_box(poses, radius, half, a, b, kind)
    return sep


# ------------------------------------------------------------------------------------- motion walk
@njit(cache=True, fastmath=False, error_model="numpy")
def first_inadmissible(
    q_a: np.ndarray, dq: np.ndarray, n_fine: int, fbuf: np.ndarray, ibuf: np.ndarray
) -> int:
    """First of the samples t_i = i / n_fine (as ``numpy.linspace``) where c(q) fails; -1: none."""
    u = _unpack(fbuf, ibuf)
    stage, c_lo, c_hi = u[2], u[28], u[29]
    c = np.empty(N_CONSTRAINTS)
    q = np.empty(q_a.shape[0])
    step = 1.0 / n_fine
    for i in range(n_fine + 1):
        t = i * step if i < n_fine else 1.0
        for j in range(q.shape[0]):
            q[j] = q_a[j] + t * dq[j]
        constraints(q, stage, c)
        if not admissible(c, c_lo, c_hi):
            return i
    return -1


@njit(cache=True, fastmath=False, error_model="numpy")
def end_ratio(q_a: np.ndarray, q_b: np.ndarray, fbuf: np.ndarray) -> float:
    """Largest link-height ratio (y_B/L1, y_C/L3, y_E/L4) at the two ends; 1 if one is not finite."""
    stage = fbuf[40:44]  # after T_tool_box (16) and mdh (24), see ``pack``
    c = np.empty(N_CONSTRAINTS)
    out = -math.inf
    for end in range(2):
        constraints(q_a if end == 0 else q_b, stage, c)
        for i in range(N_CONSTRAINTS - 3, N_CONSTRAINTS):
            if not math.isfinite(c[i]):
                return 1.0
            out = max(out, c[i])
    return out


@njit(cache=True, fastmath=False, error_model="numpy")
def segment_reach(
    rho: np.ndarray,  # (B, 8) static reach bounds
    link: np.ndarray,  # (B,) bool: a stage link (its y and gamma bounds depend on the slope)
    k: float,  # slope bound of the links along the segment
    h: float,  # L2 / 2
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    rigid: np.ndarray,  # (P, 8) bool: joint j moves both bodies of pair p rigidly
    adq: np.ndarray,  # (8,) |q_b - q_a|
) -> tuple[np.ndarray, np.ndarray]:
    """Displacement bounds over the segment: bodies rho . |dq|, pairs (rho_a + rho_b, rigid joints 0) . |dq|.

    ``bodies.segment_reach_bounds`` with the segment's slope bound, then the products, in one pass.
    """
    n_b = rho.shape[0]
    r = rho.copy()
    for b in range(n_b):
        if link[b]:
            r[b, 2] = max(1.0, k)  # y
            r[b, 3] = h * (1.0 + k)  # gamma
    reach = np.zeros(n_b)
    for b in range(n_b):
        for j in range(8):
            reach[b] += r[b, j] * adq[j]
    n_p = pair_a.shape[0]
    pair = np.zeros(n_p)
    for p in range(n_p):
        for j in range(8):
            if not rigid[p, j]:
                pair[p] += (r[pair_a[p], j] + r[pair_b[p], j]) * adq[j]
    return reach, pair


#: Codes of :func:`motion_walk`.
WALK_DONE, WALK_PROBE, WALK_FAIL, WALK_GROW = 0, 1, 2, 3
#: Slots of the walk's integer (``ci``) and float (``cf``) context arrays.
CI_TASK, CI_I, CI_PHASE, CI_N, CI_COUNT, CI_SLOT, CI_LEVELS, CI_CABIN = 0, 1, 2, 3, 4, 5, 6, 7
CF_LAST, CF_E, CF_TSTOP, CF_CLEARANCE, CF_OWN, CF_MARGIN, CF_THRESHOLD, CF_TFAIL, CF_PROBE_PROVEN = range(9)
CF_LEVEL0 = 9
CI_SIZE, CF_SIZE = 8, 13


@njit(cache=True, fastmath=False, error_model="numpy")
def _walk_state(i, ci, q_a, dq, u, slot_of, poses, cabin, pairs):  # type: ignore[no-untyped-def]
    """Slot of state i (t = i / n), its poses evaluated on first use; -1 when the store is full."""
    s = slot_of[i]
    if s >= 0:
        return s
    s = ci[CI_COUNT]
    if s == poses.shape[0]:
        return -1
    t = i / ci[CI_N]
    q = np.empty(q_a.shape[0])
    for j in range(q.shape[0]):
        q[j] = q_a[j] + t * dq[j]
    body_poses(q, u[0], u[1], u[2], u[3], poses[s], np.empty(N_CONSTRAINTS))
    cabin[s, :] = math.nan  # bounds are evaluated on demand (:func:`_walk_bound`)
    pairs[s, :] = math.nan
    slot_of[i] = s
    ci[CI_COUNT] = s + 1
    return s


@njit(cache=True, fastmath=False, error_model="numpy")
def _walk_bound(s, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch):  # type: ignore[no-untyped-def]
    """The bound of body/pair idx at slot s (NaN in the store: not yet evaluated)."""
    if is_cabin:
        v = cabin[s, idx]
        if math.isnan(v):
            v = cabin[s, idx] = _cabin_bound(idx, poses[s], u, grid)
        return v
    v = pairs[s, idx]
    if math.isnan(v):
        v = pairs[s, idx] = _pair_bound(idx, poses[s], u, threshold, scratch)
    return v


@njit(cache=True, fastmath=False, error_model="numpy")
def motion_walk(
    ci: np.ndarray,
    cf: np.ndarray,
    q_a: np.ndarray,
    q_b: np.ndarray,
    dq: np.ndarray,
    reach: np.ndarray,
    pair_reach: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    slot_of: np.ndarray,
    poses: np.ndarray,
    cabin: np.ndarray,
    pairs: np.ndarray,
) -> int:
    """The certified motion walk of ``CollisionWorld.check_motion``, resumable around FCL probes.

    Tasks: every body against the cabin (if any), then every checked pair. For each, both end states
    first (spare clearance f0, f1 >= margin with f0 + f1 >= D covers the segment), the carriage by its
    exact table, else the walk: at state i the spare clearance E (the bound, or an FCL probe on the grown
    body), then the next state at t + (E + margin) / D snapped down onto the schedule t = i / n.

    Returns ``WALK_PROBE`` when the walk needs FCL: ``ci[CI_SLOT]`` is the state's slot, the
    ``ci[CI_LEVELS]`` levels to try in order are at ``cf[CF_LEVEL0:]``, ``cf[CF_E]`` the bound's E; the
    caller writes the first level that did not collide (or leaves E) into ``cf[CF_E]`` and calls again.
    ``WALK_FAIL``: no margin could be proven (task ``ci[CI_TASK]``, at ``cf[CF_TFAIL]``). ``WALK_GROW``:
    the state store is full (enlarge and call again). ``WALK_DONE``: every task is certified.
    """
    u = _unpack(fbuf, ibuf)
    capsule_pair, capsule_box, carriage = u[21], u[23], u[24]
    table, z0, dz = u[25], u[26], u[27]
    most = 0
    for b in range(u[17].shape[0] - 1):
        most = max(most, u[17][b + 1] - u[17][b])
    scratch = np.empty((2 * most, 3))
    threshold = cf[CF_THRESHOLD]
    n_b = reach.shape[0]
    n_cabin = n_b if ci[CI_CABIN] else 0
    n_tasks = n_cabin + pair_reach.shape[0]
    n = ci[CI_N]
    mm = cf[CF_MARGIN]
    while ci[CI_TASK] < n_tasks:
        task = ci[CI_TASK]
        is_cabin = task < n_cabin
        idx = task if is_cabin else task - n_cabin
        D = reach[idx] if is_cabin else pair_reach[idx]
        base = cf[CF_CLEARANCE] if is_cabin else cf[CF_OWN]
        exact = (not is_cabin) and (capsule_pair[idx] != 0 or capsule_box[idx] > 0)
        phase = ci[CI_PHASE]
        if phase == 0:  # a new task: both end states
            s0 = _walk_state(0, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s0 < 0:
                return WALK_GROW
            s1 = _walk_state(n, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s1 < 0:
                return WALK_GROW
            f0 = _walk_bound(s0, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            f1 = _walk_bound(s1, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            if f0 >= mm and f1 >= mm and f0 + f1 >= D:
                ci[CI_TASK] += 1
                continue
            if is_cabin and idx == carriage and table.shape[0] > 0:
                # The carriage moves with d1 only: its exact clearance table covers the whole segment.
                lo, hi = min(q_a[0], q_b[0]), max(q_a[0], q_b[0])
                nt = table.shape[0]
                if not (lo < z0 or hi > z0 + dz * (nt - 1)):
                    k0 = int(min(max(math.floor((lo - z0) / dz), 0.0), nt - 1.0))
                    k1 = int(min(max(math.ceil((hi - z0) / dz), 0.0), nt - 1.0))
                    if table[k0 : k1 + 1].min() - 0.5 * dz > cf[CF_CLEARANCE]:
                        ci[CI_TASK] += 1
                        continue
            cf[CF_TSTOP] = 1.0 - f1 / D if f1 >= mm and D > 0.0 else 1.0
            ci[CI_I] = 0
            cf[CF_LAST] = mm
            ci[CI_PHASE] = phase = 2
        i = ci[CI_I]
        if phase == 2:  # at state i: the bound's spare clearance, then probes if they can prove more
            s = _walk_state(i, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s < 0:
                return WALK_GROW
            free = _walk_bound(s, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            E = free if free >= mm else 0.0
            m = 0
            if D > 0.0 and not exact and (E == 0.0 or cf[CF_PROBE_PROVEN] != 0.0):
                level = min(0.3, max(2.0 * cf[CF_LAST], 2.0 * E, 4.0 * mm))
                if level > E:
                    cf[CF_LEVEL0 + m] = level
                    m += 1
            if E == 0.0 and not exact:
                for level in (4 * mm, 2 * mm, mm):
                    cf[CF_LEVEL0 + m] = level
                    m += 1
            if m > 0:
                ci[CI_SLOT] = s
                ci[CI_LEVELS] = m
                cf[CF_E] = E
                ci[CI_PHASE] = 1
                return WALK_PROBE
        else:  # phase 1: the caller's probe result
            E = cf[CF_E]
        cf[CF_LAST] = max(E, mm)
        t = i / n
        if E == 0.0:
            cf[CF_TFAIL] = t
            return WALK_FAIL
        if i == n or D <= 0.0 or t + E / D >= cf[CF_TSTOP]:
            ci[CI_TASK] += 1
            ci[CI_PHASE] = 0
            continue
        ci[CI_I] = min(n, max(i + 1, int(math.floor((t + (E + mm) / D) * n + 1e-9))))
        ci[CI_PHASE] = 2
    return WALK_DONE
