"""A path's cumulative bound and the spreading of bounds along it (compiled).

The numbers of :class:`planner.collision.along.AlongPath`'s cumulative bound (each piece's reach or its
vertices' step, the smaller, summed along the path), its running-maximum spread of lower bounds and its
bound between samples, in one pass each instead of numpy's temporaries. Every sum is taken in the order
numpy's own formulas take it (down the samples in sequence) and maxima and minima are exact, with numpy's
NaN rules, so both give the same bits as the plain formulas (``tests/collision/test_along_kernels.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, fastmath=False, inline="always")
def _max(a: float, b: float) -> float:
    """np.maximum's rule: a when a >= b or a is NaN, else b (so a NaN on either side wins)."""
    return a if (a >= b or a != a) else b


@njit(cache=True, fastmath=False, inline="always")
def _min(a: float, b: float) -> float:
    """np.minimum's rule: a when a <= b or a is NaN, else b."""
    return a if (a <= b or a != a) else b


@njit(cache=True, fastmath=False)
def cumulative_bound(reach: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The cumulative bound (N, T) of each piece's reach and vertex step (N - 1, T).

    cum[0] = 0, cum[k + 1] = cum[k] + min(reach[k], steps[k]), added down the samples in order: as
    ``np.vstack([0, np.cumsum(np.minimum(reach, steps), axis=0)])``.
    """
    m, nt = reach.shape[0], reach.shape[1]
    cum = np.empty((m + 1, nt))
    for t in range(nt):
        cum[0, t] = 0.0
    for k in range(m):
        for t in range(nt):
            cum[k + 1, t] = cum[k, t] + _min(reach[k, t], steps[k, t])
    return cum


@njit(cache=True, fastmath=False)
def propagate(lower: np.ndarray, cum: np.ndarray, cols: np.ndarray) -> None:
    """Raise lower[:, t] (N, T) to max_k (lower[k, t] - |cum[j, t] - cum[k, t]|) at every j, t in ``cols``.

    In place: the forward running maximum of lower + cum less cum, the backward one of lower - cum plus
    cum, the larger of them and lower itself (the values of the input column throughout).
    """
    n = lower.shape[0]
    fwd = np.empty(n)
    for c in range(cols.shape[0]):
        t = cols[c]
        run = 0.0
        for j in range(n):
            v = lower[j, t] + cum[j, t]
            run = v if j == 0 else _max(run, v)
            fwd[j] = run - cum[j, t]
        for j in range(n - 1, -1, -1):
            v = lower[j, t] - cum[j, t]
            run = v if j == n - 1 else _max(run, v)
            lower[j, t] = _max(lower[j, t], _max(fwd[j], run + cum[j, t]))


@njit(cache=True, fastmath=False)
def between_bound(lower: np.ndarray, reach: np.ndarray, cols: np.ndarray) -> tuple[float, int]:
    """(the smallest bound between samples, the piece where it is) over columns ``cols``.

    On piece k of column t, with a = lower[k, t], b = lower[k + 1, t] and D = reach[k, t]: the larger of
    (a + b - D) / 2 and max(a, b) - D (the distance cannot fall below either along the piece). The
    smallest over every piece and column (NaN wins, as np.min), and the first piece whose row holds it
    (as np.argmin of the rows' minima).
    """
    m = reach.shape[0]
    best = np.inf
    best_k = 0
    for k in range(m):
        row = np.inf
        for c in range(cols.shape[0]):
            t = cols[c]
            a, b, d = lower[k, t], lower[k + 1, t], reach[k, t]
            v = _max(0.5 * (a + b - d), _max(a, b) - d)
            row = _min(row, v) if c > 0 else v
        if row < best or (row != row and best == best) or k == 0:
            best, best_k = row, k
    return best, best_k
