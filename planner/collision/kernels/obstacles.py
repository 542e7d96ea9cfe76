"""Certified lower bounds of the bodies' distances to the obstacles (installed units, fixtures), compiled.

An obstacle lies inside its bounding box (centre p_o, rotation R_o, half extents h_o); the distance of a
point x to that box, |max(|(x - p_o) R_o| - h_o, 0)|, computed as x R_o - p_o R_o, bounds the point's
distance to the obstacle from below. A sphere of radius r about x therefore keeps at least that distance
minus r, and a body inside a union of spheres at least the smallest of those:

* **coarse**: each body's bounding sphere about its centre (a box: its half-diagonal; a capsule: its radius
  plus half its current length);
* **fine**: each body's fine sphere cover (the one the cabin's bounds use), where the coarse bound is not
  above a threshold -- both bound the distance from below, the larger one counts.

Allowed pairs (body, obstacle) are +inf. These are the bounds of
:class:`~planner.collision.obstacles.ObstacleSet`, whose numpy route (kept in :mod:`planner.collision.oracle`
as the tests' reference) evaluates the same sums in the same order: the numbers are equal bit for bit.
A body without fine spheres gets no refinement (its fine bound is -inf).

The kernels read an obstacle set's packed data (:func:`.buffers.obstacle_data`) by name
(:func:`.packed.unpack_obstacles`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.collision.kernels.buffers import ObstaclePacked
from planner.collision.kernels.packed import unpack_obstacles


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def box_distance(
    x: float, y: float, z: float, R: np.ndarray, origin: np.ndarray, half: np.ndarray, o: int
) -> float:
    """Distance of the point (x, y, z) to obstacle o's bounding box (0 inside), in numpy's order of sums."""
    e0 = abs(x * R[o, 0] + y * R[o, 3] + z * R[o, 6] - origin[o, 0]) - half[o, 0]
    e1 = abs(x * R[o, 1] + y * R[o, 4] + z * R[o, 7] - origin[o, 1]) - half[o, 1]
    e2 = abs(x * R[o, 2] + y * R[o, 5] + z * R[o, 8] - origin[o, 2]) - half[o, 2]
    if e0 < 0.0:  # numpy's maximum(e, 0): NaN stays NaN
        e0 = 0.0
    if e1 < 0.0:
        e1 = 0.0
    if e2 < 0.0:
        e2 = 0.0
    return math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _maximum(a: float, b: float) -> float:
    """The larger of a and b as numpy's maximum gives it: NaN if either is NaN."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a >= b else b


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def coarse_bound(pose: np.ndarray, b: int, u: ObstaclePacked, o: int) -> float:
    """Body b's bounding sphere (pose (13,)) against obstacle o's bounding box (every pair, allowed too)."""
    radius = u.capsule_r[b] + 0.5 * pose[12] if u.capsule[b] else u.box_r[b]
    return box_distance(pose[9], pose[10], pose[11], u.R, u.origin_local, u.half, o) - radius


@njit(cache=True, fastmath=False, error_model="numpy")
def fine_bounds(pose: np.ndarray, b: int, u: ObstaclePacked, out: np.ndarray) -> None:
    """Body b's fine-cover bounds (pose (13,)) against every obstacle into ``out`` (O,).

    Sphere s's centre p + R local_s + frac_s * length * z, summed as numpy sums it; the smallest bound of
    the spheres (NaN if one is NaN, as numpy's minimum); -inf for a body without spheres.
    """
    R, origin, half = u.R, u.origin_local, u.half
    local, frac, radii, start = u.local, u.frac, u.radii, u.start
    n_o = out.shape[0]
    empty = start[b] == start[b + 1]
    for o in range(n_o):
        out[o] = -math.inf if empty else math.inf
    for s in range(start[b], start[b + 1]):
        fl = frac[s] * pose[12]
        l0, l1, l2 = local[s, 0], local[s, 1], local[s, 2]
        cx = pose[9] + (l0 * pose[0] + l1 * pose[3] + l2 * pose[6]) + pose[6] * fl
        cy = pose[10] + (l0 * pose[1] + l1 * pose[4] + l2 * pose[7]) + pose[7] * fl
        cz = pose[11] + (l0 * pose[2] + l1 * pose[5] + l2 * pose[8]) + pose[8] * fl
        r = radii[s]
        for o in range(n_o):
            v = box_distance(cx, cy, cz, R, origin, half, o) - r
            if v < out[o] or math.isnan(v):  # a NaN stays (v < NaN is false)
                out[o] = v


@njit(cache=True, fastmath=False, error_model="numpy")
def state_obstacle_bounds(
    poses: np.ndarray, u: ObstaclePacked, threshold: np.ndarray, out: np.ndarray
) -> None:
    """:func:`obstacle_bounds` on unpacked data, into ``out`` (B, O)."""
    n_b, n_o = out.shape[0], out.shape[1]
    active = u.active
    fine = np.empty(n_o)
    for b in range(n_b):
        pose = poses[b]
        near = False
        for o in range(n_o):
            v = coarse_bound(pose, b, u, o) if active[b, o] else math.inf
            out[b, o] = v
            if v <= threshold[b]:
                near = True
        if near:
            fine_bounds(pose, b, u, fine)
            for o in range(n_o):
                if active[b, o]:
                    out[b, o] = _maximum(out[b, o], fine[o])


@njit(cache=True, fastmath=False, error_model="numpy")
def obstacle_bounds(
    poses: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, threshold: np.ndarray
) -> np.ndarray:
    """Certified lower bounds (B, O) of each body's distance to each obstacle at one state.

    ``poses`` (B, 13); ``threshold`` (B,): a body with some coarse bound not above its threshold has every
    checked pair refined by its fine cover (the larger bound). Allowed pairs are +inf.
    """
    u = unpack_obstacles(fbuf, ibuf)
    out = np.empty((poses.shape[0], u.half.shape[0]))
    state_obstacle_bounds(poses, u, threshold, out)
    return out


@njit(cache=True, fastmath=False, error_model="numpy")
def obstacle_coarse_batch(
    poses: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, allowed_too: bool
) -> np.ndarray:
    """Coarse bounds (N, B, O) at N states ``poses`` (N, B, 13); allowed pairs +inf unless ``allowed_too``."""
    u = unpack_obstacles(fbuf, ibuf)
    n, n_b, n_o = poses.shape[0], poses.shape[1], u.half.shape[0]
    out = np.empty((n, n_b, n_o))
    for k in range(n):
        for b in range(n_b):
            for o in range(n_o):
                if allowed_too or u.active[b, o]:
                    out[k, b, o] = coarse_bound(poses[k, b], b, u, o)
                else:
                    out[k, b, o] = math.inf
    return out


@njit(cache=True, fastmath=False, error_model="numpy")
def obstacle_fine_batch(
    poses: np.ndarray, rows: np.ndarray, b: int, fbuf: np.ndarray, ibuf: np.ndarray
) -> np.ndarray:
    """Fine-cover bounds (n, O) of body b at the states ``rows`` (n,) of ``poses`` (N, B, 13), every pair."""
    u = unpack_obstacles(fbuf, ibuf)
    out = np.empty((rows.shape[0], u.half.shape[0]))
    for r in range(rows.shape[0]):
        fine_bounds(poses[rows[r], b], b, u, out[r])
    return out
