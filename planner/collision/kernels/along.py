"""A sampled path's certified bounds and its cover, compiled (the gate's batched pass).

:func:`bounds_at` evaluates, from the body poses of a sampled path (:func:`~.state.packed_poses`), each
body's cabin lower bound and each checked pair's lower bound at the chosen samples, without a return to
Python per sample; :func:`cover_walk` is the certificate of :meth:`planner.collision.along.AlongPath.certify`
(bounds on demand, returning to Python only for an exact FCL distance).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.collision.kernels.bounds import bounds_of_state, cabin_bound, pair_bound, pair_scratch
from planner.collision.kernels.codes import (
    BOUND,
    COVER_DONE,
    COVER_EXACT,
    CW_K,
    CW_PENDING,
    CW_POS,
    CW_TASK,
    EXACT,
    PROBED,
    SPREAD,
)
from planner.collision.kernels.packed import unpack


@njit(cache=True, fastmath=False, error_model="numpy")
def bounds_at(
    idx: np.ndarray,  # (K,) sample indices
    poses: np.ndarray,  # (N, B, 13) body poses of every sample
    c: np.ndarray,  # (N, m) admissibility values of every sample
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    threshold: float,
    cabin: np.ndarray,  # (K, B) out
    pairs: np.ndarray,  # (K, P) out
) -> None:
    """Cabin bounds and pair bounds at the samples ``idx``, written in place (row r for sample idx[r]).

    Row r holds what :func:`~.state.packed_state` gives at sample ``idx[r]``: the cabin lower bound of
    every body (fine sphere cover on the clearance grid, the carriage's exact table) and every checked
    pair's lower bound (the exact distance of capsule pairs where the bound is not above ``threshold``).
    """
    u = unpack(fbuf, ibuf)
    for r in range(idx.shape[0]):
        k = idx[r]
        cab, par, _ = bounds_of_state(poses[k], u, grid, c[k], threshold)
        cabin[r, :] = cab
        pairs[r, :] = par


@njit(cache=True, fastmath=False, error_model="numpy")
def _spread(lower: np.ndarray, cum: np.ndarray, k: int, t: int, floor: float) -> None:
    """Raise column t to lower[k, t] - |C(j) - C(k)| both ways from k, while that is above ``floor``."""
    d = lower[k, t]
    ck = cum[k, t]
    for j in range(k + 1, lower.shape[0]):
        v = d - (cum[j, t] - ck)
        if v < floor:
            break
        if v > lower[j, t]:
            lower[j, t] = v
    for j in range(k - 1, -1, -1):
        v = d - (ck - cum[j, t])
        if v < floor:
            break
        if v > lower[j, t]:
            lower[j, t] = v


@njit(cache=True, fastmath=False, error_model="numpy")
def cover_walk(
    ci: np.ndarray,  # (CW_SIZE,) int64 state, resumable
    need: np.ndarray,  # (T,) clearance + margin of each task
    n_cabin: int,  # tasks < n_cabin are bodies against the cabin, the rest pairs
    poses: np.ndarray,  # (N, B, 13)
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    threshold: float,
    cum: np.ndarray,  # (N, T) cumulative reach
    reach: np.ndarray,  # (N - 1, T) reach of each piece
    lower: np.ndarray,  # (N, T) lower bounds, in place
    state: np.ndarray,  # (N, T) int64: SPREAD, BOUND, PROBED, EXACT, in place
    left: np.ndarray,  # (N - 1,) bool out: pieces to walk
) -> int:
    """Cover every piece of every task by the spare clearance proven at its ends (see ``collision.along``).

    Task by task, piece by piece: piece k is covered when s_k, s_{k+1} >= 0 and s_k + s_{k+1} >= D_k
    (s = lower - need). An uncovered piece gets the certified bound at its start, then at its end (each
    raises the column around it), then asks the caller for more evidence at its start, then at its end
    (``COVER_EXACT``: sample ``ci[CW_K]``, task ``ci[CW_TASK]``; the caller raises ``lower`` there by FCL
    probes on the grown body (state ``PROBED``), then by the exact distance (``EXACT``), and calls again),
    and a piece still uncovered with exact distances at both ends is marked in ``left``.
    """
    u = unpack(fbuf, ibuf)
    scratch = pair_scratch(u)
    n = lower.shape[0]
    n_tasks = lower.shape[1]
    pending = ci[CW_PENDING]
    if pending >= 0:
        ci[CW_PENDING] = -1
        _spread(lower, cum, ci[CW_K], ci[CW_TASK], need[ci[CW_TASK]])
    while ci[CW_TASK] < n_tasks:
        t = ci[CW_TASK]
        nd = need[t]
        k = ci[CW_POS]
        while k < n - 1:
            a = lower[k, t] - nd
            b = lower[k + 1, t] - nd
            if a >= 0.0 and b >= 0.0 and a + b >= reach[k, t]:
                k += 1
                continue
            s = k if state[k, t] == SPREAD else (k + 1 if state[k + 1, t] == SPREAD else -1)
            if s >= 0:
                if t < n_cabin:
                    v = cabin_bound(t, poses[s], u, grid)
                else:
                    v = pair_bound(t - n_cabin, poses[s], u, threshold, scratch)
                state[s, t] = BOUND
                if v > lower[s, t]:
                    lower[s, t] = v
                    _spread(lower, cum, s, t, nd)
                continue
            s = -1
            for level in (PROBED, EXACT):  # probes at both ends before an exact distance at either
                if state[k, t] < level:
                    s = k
                    break
                if state[k + 1, t] < level:
                    s = k + 1
                    break
            if s >= 0:
                ci[CW_POS] = k
                ci[CW_K] = s
                ci[CW_PENDING] = 1
                return COVER_EXACT
            left[k] = True
            k += 1
        ci[CW_TASK] = t + 1
        ci[CW_POS] = 0
    return COVER_DONE
