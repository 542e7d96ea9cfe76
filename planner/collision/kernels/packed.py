"""The compiled reading of a world's packed buffers (:func:`unpack`, the inverse of :func:`.buffers.pack`).

The layout and the :class:`~.buffers.Packed` fields are in :mod:`.buffers`, which imports no numba; so are
an obstacle set's (:func:`unpack_obstacles`, the inverse of :func:`.buffers.pack_obstacles`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.collision.kernels.buffers import HEADER as _HEADER
from planner.collision.kernels.buffers import OBSTACLE_HEADER as _OBSTACLE_HEADER
from planner.collision.kernels.buffers import ObstaclePacked, Packed


@njit(cache=True, fastmath=False, error_model="numpy")
def _cover_ints(ibuf: np.ndarray, o: int, n: int, n_b: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(sphere body (n,), body bounds (n_b + 1,), next offset) of a packed sphere cover at ``o``."""
    return ibuf[o : o + n], ibuf[o + n : o + n + n_b + 1], o + n + n_b + 1


@njit(cache=True, fastmath=False, error_model="numpy")
def _cover_floats(fbuf: np.ndarray, f: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(local centres (n, 3), length fractions (n,), radii (n,), next offset) of a packed cover at ``f``."""
    return (
        fbuf[f : f + 3 * n].reshape((n, 3)),
        fbuf[f + 3 * n : f + 4 * n],
        fbuf[f + 4 * n : f + 5 * n],
        f + 5 * n,
    )


@njit(cache=True, fastmath=False, error_model="numpy")
def unpack(fbuf: np.ndarray, ibuf: np.ndarray) -> Packed:
    """Views of the packed world data (:func:`pack`'s layout), by name."""
    n_b, n_s, n_c, n_p, n_t = ibuf[0], ibuf[1], ibuf[2], ibuf[3], ibuf[4]
    n_par, n_con, n_rat = ibuf[11], ibuf[12], ibuf[13]
    kinds = ibuf[_HEADER : _HEADER + n_b]
    fine_body, fine_bounds, o = _cover_ints(ibuf, _HEADER + n_b, n_s, n_b)
    coarse_body, coarse_bounds, o = _cover_ints(ibuf, o, n_c, n_b)
    pair_a = ibuf[o : o + n_p]
    pair_b = ibuf[o + n_p : o + 2 * n_p]
    capsule_pair = ibuf[o + 2 * n_p : o + 3 * n_p]
    capsule_box = ibuf[o + 3 * n_p : o + 4 * n_p]
    ratio_rows = ibuf[o + 4 * n_p : o + 4 * n_p + n_rat]
    # Floats: T_tool_box (16), kernel parameters, fine cover, grid origin (3) and 1 / step, coarse cover.
    fine_local, fine_frac, fine_r, f = _cover_floats(fbuf, 16 + n_par, n_s)
    origin, inv_step = fbuf[f : f + 3], fbuf[f + 3]
    coarse_local, coarse_frac, coarse_r, f = _cover_floats(fbuf, f + 4, n_c)
    radius = fbuf[f : f + n_b]
    half = fbuf[f + n_b : f + 4 * n_b].reshape((n_b, 3))
    table = fbuf[f + 4 * n_b : f + 4 * n_b + n_t]
    f += 4 * n_b + n_t
    return Packed(
        fbuf[0:16].reshape((4, 4)),
        ibuf[10],
        fbuf[16 : 16 + n_par],
        kinds,
        fine_body,
        fine_local,
        fine_frac,
        fine_r,
        fine_bounds,
        origin,
        inv_step,
        ibuf[7:10],
        ibuf[5] != 0,
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
        ibuf[6],
        table,
        fbuf[f],
        fbuf[f + 1],
        fbuf[f + 2 : f + 2 + n_con],
        fbuf[f + 2 + n_con : f + 2 + 2 * n_con],
        ratio_rows,
    )


@njit(cache=True, fastmath=False, error_model="numpy")
def unpack_obstacles(fbuf: np.ndarray, ibuf: np.ndarray) -> ObstaclePacked:
    """Views of an obstacle set's packed data (:func:`.buffers.pack_obstacles`'s layout), by name."""
    n_b, n_o, n_s = ibuf[0], ibuf[1], ibuf[2]
    o = _OBSTACLE_HEADER
    capsule = ibuf[o : o + n_b]
    active = ibuf[o + n_b : o + n_b + n_b * n_o].reshape((n_b, n_o))
    start = ibuf[o + n_b + n_b * n_o : o + 2 * n_b + n_b * n_o + 1]
    f = 15 * n_o
    return ObstaclePacked(
        fbuf[0 : 9 * n_o].reshape((n_o, 9)),
        fbuf[9 * n_o : 12 * n_o].reshape((n_o, 3)),
        fbuf[12 * n_o : f].reshape((n_o, 3)),
        capsule,
        fbuf[f : f + n_b],
        fbuf[f + n_b : f + 2 * n_b],
        active,
        fbuf[f + 2 * n_b : f + 2 * n_b + 3 * n_s].reshape((n_s, 3)),
        fbuf[f + 2 * n_b + 3 * n_s : f + 2 * n_b + 4 * n_s],
        fbuf[f + 2 * n_b + 4 * n_s : f + 2 * n_b + 5 * n_s],
        start,
    )
