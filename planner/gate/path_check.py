"""The gate's path check: every sampled configuration lies on the certified geometric path.

The certified path is a C1 (with the planner's blends C2) curve q(s) per leg
(:class:`~planner.timing.path.JointPath`); a timing stage only chooses s(t), so each sample q_k must
equal q(s) for some s. The distance of q_k from a leg is found leg by leg, by the nearest point of a
dense evaluation (a k-d tree) refined by Newton's method on f(s) = |q(s) - q_k|^2 / 2
(f' = r . q', f'' = q' . q' + r . q'', r = q(s) - q_k), which converges in a few steps from the nearest
dense point of a smooth piece. Where the sampler gives the parameter each sample was taken at (its
witness), a sample within 1e-9 of its witness point is settled by that one evaluation: the search runs for
the others only (a timed plan's 5 000 samples: one evaluation each instead of a k-d tree over 4 000
points per leg and Newton's steps).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from planner.core.types import Array, IntArray
from planner.timing.path import JointPath

#: Dense points per leg for the nearest-point start.
DENSE_POINTS = 4000
#: ... and at least this many in every piece (a short blend between long lines).
PIECE_POINTS = 64
NEWTON_STEPS = 6
#: A sample's Newton iteration stops once its step is below this fraction of the leg's parameter length
#: (at least 1): a step that small moves the nearest point by far less than the path tolerance.
NEWTON_TOL = 1e-12
#: A sample within this of its witness point (:func:`path_deviation`'s ``s_of``) needs no search [joint
#: space]: 1/1000 of the gate's tolerance (``PATH_DEVIATION_TOL``, 1e-6).
WITNESS_M = 1e-9


def path_deviation(
    q: Array, legs: tuple[JointPath, ...], leg_of: IntArray | None = None, s_of: Array | None = None
) -> Array:
    """Joint-space distance (N,) of each configuration q (N, n) from the path (an upper bound of it).

    Args:
        q: The sampled configurations (N, n).
        legs: The certified path, leg by leg.
        leg_of: The leg (N,) each sample was timed on (:func:`~planner.timing.profile.sample_legs`): each
            sample is then measured against its own leg only, which is stricter than the nearest leg (a
            sample on another leg counts as off the path) and costs one leg per sample instead of all of
            them. Without it, the distance from the nearest of the legs.
        s_of: With ``leg_of``, a parameter (N,) on each sample's leg that the sample should be at (the
            sampler's): where the sample is within :data:`WITNESS_M` of that point, that distance is the
            sample's figure (an upper bound of its distance from the path, the tolerance 1000 times
            larger); the others get the nearest-point search.
    """
    q = np.asarray(q, dtype=float)
    best = np.full(len(q), np.inf)
    for k, leg in enumerate(legs):
        rows = np.arange(len(q)) if leg_of is None else np.flatnonzero(leg_of == k)
        if len(rows) == 0:
            continue
        if s_of is not None and leg_of is not None:
            witness = np.linalg.norm(leg.evaluate(s_of[rows])[0] - q[rows], axis=1)
            best[rows] = witness
            rows = rows[~(witness <= WITNESS_M)]
            if len(rows) == 0:
                continue
        best[rows] = np.minimum(best[rows], _distance_to(leg, q[rows]))
    return best


def _distance_to(leg: JointPath, q: Array) -> Array:
    """Distance (M,) of configurations q (M, n) from one leg: nearest dense point, then Newton.

    The dense points cover every piece (at least :data:`PIECE_POINTS` each, the rest of
    :data:`DENSE_POINTS` by parameter length): a short blend between long lines gets its own points,
    else the nearest dense point may lie on a neighbouring piece and Newton's method stop at a corner
    (seen: 1.9 mm reported where the path passes within 0.75 um). Newton's point counts only where it is
    nearer than the dense point it started from, which is itself on the path.
    """
    grid = _dense_grid(leg)
    dense, _, _ = leg.evaluate(grid)
    d0, idx = cKDTree(dense).query(q)
    s = grid[idx]
    active = np.arange(len(q))  # the samples whose Newton step still moves s
    for _ in range(NEWTON_STEPS):
        p, dp, ddp = leg.evaluate(s[active])
        r = p - q[active]
        g = np.einsum("ij,ij->i", r, dp)
        h = np.einsum("ij,ij->i", dp, dp) + np.einsum("ij,ij->i", r, ddp)
        s_new = np.clip(s[active] - g / np.where(h > 1e-12, h, 1e-12), 0.0, leg.length)
        moved = np.abs(s_new - s[active]) > NEWTON_TOL * max(leg.length, 1.0)
        s[active] = s_new
        active = active[moved]
        if len(active) == 0:
            break
    d = np.linalg.norm(leg.evaluate(s)[0] - q, axis=1)
    return np.asarray(np.minimum(d, d0), dtype=float)


def _dense_grid(leg: JointPath) -> Array:
    """Parameters of the dense points: every piece's ends and at least PIECE_POINTS inside each."""
    br = leg.breaks
    total = max(float(br[-1]), 1e-12)
    parts = [
        np.linspace(a, b, max(PIECE_POINTS, int(np.ceil(DENSE_POINTS * (b - a) / total))), endpoint=False)
        for a, b in zip(br[:-1], br[1:], strict=True)
    ]
    return np.concatenate([*parts, [br[-1]]])
