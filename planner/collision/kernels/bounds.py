"""Certified distance lower bounds from sphere covers, compiled.

* Cabin: a sphere of radius r centred at x cannot come closer to the cabin than LB(x) - r, with LB the
  clearance grid's lower bound (:class:`~planner.collision.clearance_grid.ClearanceGrid`); a body's bound
  is the minimum over its fine spheres (:func:`cabin_bound`), improved for the carriage (it moves with d1
  only) by its exact clearance table along the rail, which is 1-Lipschitz in d1.
* Pairs: the separation of the two bodies' boxes (from their coarse covers) along the axes; where that is
  not above a threshold, also the smallest sphere gap |c_s - c_t| - r_s - r_t (the larger bound counts),
  and for capsule-capsule / capsule-box pairs the exact distance (:mod:`.distances`).
* :func:`state_bounds`: all of them at one state in one pass; :func:`cabin_bound` / :func:`pair_bound`:
  one entry on demand, with the same arithmetic in the same order (so the same numbers) -- the motion walk
  reads few bounds at most of its states. The numpy route of :mod:`planner.collision.oracle` computes
  the same bounds vectorised (the tests check they agree).
* :func:`certain_cabin_contact`: a contact proven by the grid's upper bound, without FCL.

All kernels read a world's data by name from :class:`~.buffers.Packed` (``u``), every field they need at
the top of the function: a field read further down makes numba reference-count the whole tuple again
(measured: 35 instead of 10 reference counts in :func:`cabin_bound`, 15% slower).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.collision.kernels.buffers import Packed
from planner.collision.kernels.distances import (
    capsule_box_distance,
    capsule_box_distances,
    capsule_capsule_distance,
    capsule_pair_distances,
)
from planner.collision.kernels.packed import unpack
from planner.collision.kernels.poses import admissible


@njit(cache=True, fastmath=False, inline="always")
def sphere_centre(
    poses: np.ndarray, b: int, local: np.ndarray, frac: np.ndarray, s: int
) -> tuple[float, float, float]:
    """World centre of sphere s of body b: p + frac * length * z + R local (in this order of sums)."""
    fl = frac[s] * poses[b, 12]
    lx, ly, lz = local[s, 0], local[s, 1], local[s, 2]
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
    return cx, cy, cz


@njit(cache=True, fastmath=False, inline="always")
def grid_value(
    grid: np.ndarray, x: float, y: float, z: float, origin: np.ndarray, inv_step: float, shape: np.ndarray
) -> float:
    """The grid's value at the node nearest to (x, y, z), clamped into the grid (flat C-order grid)."""
    i = int(math.floor((x - origin[0]) * inv_step + 0.5))
    j = int(math.floor((y - origin[1]) * inv_step + 0.5))
    k = int(math.floor((z - origin[2]) * inv_step + 0.5))
    i = min(max(i, 0), shape[0] - 1)
    j = min(max(j, 0), shape[1] - 1)
    k = min(max(k, 0), shape[2] - 1)
    return grid[i * (shape[1] * shape[2]) + j * shape[2] + k]


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
        out[s, 0], out[s, 1], out[s, 2] = sphere_centre(poses, body[s], local, frac, s)
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
def cover_extents(
    poses: np.ndarray, body: np.ndarray, local: np.ndarray, frac: np.ndarray, r: np.ndarray
) -> np.ndarray:
    """(N, 2): max over the spheres of |x| + r and of y + r, for poses (N, B, 13) (NaN if any is NaN).

    The numbers numpy gives on :func:`cover_centres_batch`'s centres (``np.max(np.abs(c[..., 0]) + r)``,
    ``np.max(c[..., 1] + r)``: the same sums, and a maximum is exact whatever the order), without the
    (N, S, 3) centres.
    """
    out = np.empty((poses.shape[0], 2))
    for k in range(poses.shape[0]):
        lateral, height = -math.inf, -math.inf
        for s in range(body.shape[0]):
            cx, cy, _ = sphere_centre(poses[k], body[s], local, frac, s)
            a = abs(cx) + r[s]
            h = cy + r[s]
            if not math.isnan(lateral) and (a > lateral or math.isnan(a)):  # NaN sticks, as numpy's
                lateral = a
            if not math.isnan(height) and (h > height or math.isnan(h)):
                height = h
        out[k, 0], out[k, 1] = lateral, height
    return out


@njit(cache=True, fastmath=False, error_model="numpy")
def cabin_bound(b: int, poses: np.ndarray, u: Packed, grid: np.ndarray) -> float:
    """Cabin lower bound of body b: its fine spheres on the grid, then the carriage's exact table."""
    local, frac, r, bounds = u.fine_local, u.fine_frac, u.fine_r, u.fine_bounds
    origin, inv_step, shape, has_grid = u.origin, u.inv_step, u.shape, u.has_grid
    carriage, table, z0, dz = u.carriage, u.table, u.table_z0, u.table_dz
    best = math.inf
    if has_grid:
        for s in range(bounds[b], bounds[b + 1]):
            cx, cy, cz = sphere_centre(poses, b, local, frac, s)
            v = grid_value(grid, cx, cy, cz, origin, inv_step, shape) - r[s]
            if v < best:
                best = v
    return carriage_bound(best, poses[b, 11], table, z0, dz) if b == carriage else best


@njit(cache=True, fastmath=False, error_model="numpy")
def carriage_bound(bound: float, d1: float, table: np.ndarray, z0: float, dz: float) -> float:
    """The carriage's cabin bound at rail position d1 (its centre's z): its exact table where it has one.

    The table's nearest sample minus the distance to it (the clearance is 1-Lipschitz in d1), if larger
    than ``bound`` -- or instead of it where the carriage has no cover spheres (``bound`` infinite).
    """
    if table.shape[0] == 0:
        return bound
    k = int(math.floor((d1 - z0) / dz + 0.5))
    k = min(max(k, 0), table.shape[0] - 1)
    exact = table[k] - abs(d1 - (z0 + k * dz))
    return exact if exact > bound or bound == math.inf else bound


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
    for b in range(n_b):
        best = math.inf
        for s in range(body_start[b], body_start[b + 1]):
            v = (
                grid_value(grid, centres[s, 0], centres[s, 1], centres[s, 2], origin, inv_step, shape)
                - radii[s]
            )
            if v < best:
                best = v
        out[b] = best
    return out


@njit(cache=True, fastmath=False)
def cabin_bounds_of_state(poses: np.ndarray, u: Packed, grid: np.ndarray) -> np.ndarray:
    """The cabin part of :func:`bounds_of_state`: each body's bound (B,), the carriage's by its table."""
    if u.has_grid:
        centres = cover_centres(poses, u.fine_body, u.fine_local, u.fine_frac)
        cabin = cabin_bounds(centres, u.fine_r, u.fine_bounds, grid, u.origin, u.inv_step, u.shape)
    else:
        cabin = np.full(poses.shape[0], math.inf)
    carriage = u.carriage
    if carriage >= 0:
        cabin[carriage] = carriage_bound(
            cabin[carriage], poses[carriage, 11], u.table, u.table_z0, u.table_dz
        )
    return cabin


@njit(cache=True, fastmath=False)
def bounds_of_state(
    poses: np.ndarray, u: Packed, grid: np.ndarray, c: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Everything one state needs in one call, on unpacked data: see :func:`state_bounds`."""
    coarse_body, coarse_local, coarse_frac, coarse_r, coarse_bounds = (
        u.coarse_body, u.coarse_local, u.coarse_frac, u.coarse_r, u.coarse_bounds
    )  # fmt: skip
    pair_a, pair_b, radius, half, capsule_pair, capsule_box = (
        u.pair_a, u.pair_b, u.radius, u.half, u.capsule_pair, u.capsule_box
    )  # fmt: skip
    cabin = cabin_bounds_of_state(poses, u, grid)
    coarse = cover_centres(poses, coarse_body, coarse_local, coarse_frac)
    pairs = pair_bounds(coarse, coarse_r, coarse_bounds, pair_a, pair_b, threshold)
    capsule_pair_distances(poses, radius, pair_a, pair_b, capsule_pair, pairs, threshold)
    capsule_box_distances(poses, radius, half, pair_a, pair_b, capsule_box, pairs, threshold)
    return cabin, pairs, admissible(c, u.c_lo, u.c_hi)


@njit(cache=True, fastmath=False, error_model="numpy")
def state_bounds(
    poses: np.ndarray,  # (B, 13)
    c: np.ndarray,  # (m,) admissibility values at this state
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The bounds of one state from its poses: (cabin bound per body, pair bound per pair, admissible).

    The cabin bound per body is improved by the carriage's exact clearance table; a pair's bound is its
    exact distance where one is known and the bound is not above ``threshold``; admissible: every value
    of c within its bounds.
    """
    return bounds_of_state(poses, unpack(fbuf, ibuf), grid, c, threshold)


@njit(cache=True, fastmath=False, error_model="numpy")
def _coarse_box(b, poses, local, frac, r, bounds, out):  # type: ignore[no-untyped-def]
    """Coarse cover centres of body b into ``out`` (as :func:`cover_centres`); their box (lo, hi) x 3."""
    lo0 = lo1 = lo2 = math.inf
    hi0 = hi1 = hi2 = -math.inf
    for m in range(bounds[b + 1] - bounds[b]):
        s = bounds[b] + m
        out[m, 0], out[m, 1], out[m, 2] = sphere_centre(poses, b, local, frac, s)
        lo0 = min(lo0, out[m, 0] - r[s])
        lo1 = min(lo1, out[m, 1] - r[s])
        lo2 = min(lo2, out[m, 2] - r[s])
        hi0 = max(hi0, out[m, 0] + r[s])
        hi1 = max(hi1, out[m, 1] + r[s])
        hi2 = max(hi2, out[m, 2] + r[s])
    return lo0, lo1, lo2, hi0, hi1, hi2


@njit(cache=True, fastmath=False, error_model="numpy")
def pair_scratch(u: Packed) -> np.ndarray:
    """Scratch space for :func:`pair_bound`: the coarse centres of the two largest covers."""
    bounds = u.coarse_bounds
    most = 0
    for b in range(bounds.shape[0] - 1):
        most = max(most, bounds[b + 1] - bounds[b])
    return np.empty((2 * most, 3))


@njit(cache=True, fastmath=False, error_model="numpy")
def pair_bound(k: int, poses: np.ndarray, u: Packed, threshold: float, scratch: np.ndarray) -> float:
    """Entry k of the pair bounds of :func:`state_bounds`; ``scratch`` from :func:`pair_scratch`."""
    local, frac, r, bounds = u.coarse_local, u.coarse_frac, u.coarse_r, u.coarse_bounds
    radius, half, capsule_pair, capsule_box = u.radius, u.half, u.capsule_pair, u.capsule_box
    a, b = u.pair_a[k], u.pair_b[k]
    na = bounds[a + 1] - bounds[a]
    nb = bounds[b + 1] - bounds[b]
    ca_ = scratch[:na]
    cb_ = scratch[na : na + nb]
    la0, la1, la2, ha0, ha1, ha2 = _coarse_box(a, poses, local, frac, r, bounds, ca_)
    lb0, lb1, lb2, hb0, hb1, hb2 = _coarse_box(b, poses, local, frac, r, bounds, cb_)
    sep = -math.inf
    sep = max(sep, lb0 - ha0, la0 - hb0)
    sep = max(sep, lb1 - ha1, la1 - hb1)
    sep = max(sep, lb2 - ha2, la2 - hb2)
    if sep <= threshold:
        gap = math.inf
        for s in range(na):
            rs = r[bounds[a] + s]
            for t in range(nb):
                dx = ca_[s, 0] - cb_[t, 0]
                dy = ca_[s, 1] - cb_[t, 1]
                dz = ca_[s, 2] - cb_[t, 2]
                g = math.sqrt(dx * dx + dy * dy + dz * dz) - rs - r[bounds[b] + t]
                if g < gap:
                    gap = g
        sep = max(sep, gap)
    if capsule_pair[k] and not sep > threshold:
        return capsule_capsule_distance(poses, radius, a, b)
    kind = capsule_box[k]
    if kind != 0 and not sep > threshold:
        return capsule_box_distance(poses, radius, half, a, b, kind)
    return sep


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
    return certain_contact(b, poses, clearance, unpack(fbuf, ibuf), grid, upper_slack)


@njit(cache=True, fastmath=False, error_model="numpy")
def certain_contact(
    b: int, poses: np.ndarray, clearance: float, u: Packed, grid: np.ndarray, upper_slack: float
) -> bool:
    """:func:`certain_cabin_contact` on unpacked data."""
    half, local, frac, bounds = u.half, u.fine_local, u.fine_frac, u.fine_bounds
    origin, inv_step, shape, radius, has_grid = u.origin, u.inv_step, u.shape, u.radius, u.has_grid
    if not has_grid:
        return False
    is_box = half[b, 0] > 0.0
    for s in range(bounds[b], bounds[b + 1]):
        if is_box:
            inner = math.inf
            for i in range(3):
                inner = min(inner, half[b, i] + clearance - abs(local[s, i]))
        else:
            inner = radius[b] + clearance
        if inner <= upper_slack:  # UB >= upper_slack: cannot fit
            continue
        cx, cy, cz = sphere_centre(poses, b, local, frac, s)
        lb = grid_value(grid, cx, cy, cz, origin, inv_step, shape)
        if math.isfinite(lb) and lb + upper_slack + 1e-6 < inner:
            return True
    return False
