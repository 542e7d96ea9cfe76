"""The gate's path check: every sampled configuration lies on the certified geometric path.

The certified path is a C1 (with the planner's blends C2) curve q(s) per leg
(:class:`~planner.timing.path.JointPath`); a timing stage only chooses s(t), so each sample q_k must
equal q(s) for some s. The distance of q_k from a leg is found leg by leg, by the nearest point of a
dense evaluation (a k-d tree) refined by Newton's method on f(s) = |q(s) - q_k|^2 / 2
(f' = r . q', f'' = q' . q' + r . q'', r = q(s) - q_k), which converges in a few steps from the nearest
dense point of a smooth piece.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from planner.core.types import Array, IntArray
from planner.timing.path import JointPath

#: Dense points per leg for the nearest-point start.
DENSE_POINTS = 4000
NEWTON_STEPS = 6


def path_deviation(q: Array, legs: tuple[JointPath, ...], leg_of: IntArray | None = None) -> Array:
    """Joint-space distance (N,) of each configuration q (N, n) from the path.

    Args:
        q: The sampled configurations (N, n).
        legs: The certified path, leg by leg.
        leg_of: The leg (N,) each sample was timed on (:func:`~planner.timing.profile.sample_legs`): each
            sample is then measured against its own leg only, which is stricter than the nearest leg (a
            sample on another leg counts as off the path) and costs one leg per sample instead of all of
            them. Without it, the distance from the nearest of the legs.
    """
    q = np.asarray(q, dtype=float)
    best = np.full(len(q), np.inf)
    for k, leg in enumerate(legs):
        rows = np.arange(len(q)) if leg_of is None else np.flatnonzero(leg_of == k)
        if len(rows) == 0:
            continue
        best[rows] = np.minimum(best[rows], _distance_to(leg, q[rows]))
    return best


def _distance_to(leg: JointPath, q: Array) -> Array:
    """Distance (M,) of configurations q (M, n) from one leg: nearest dense point, then Newton."""
    grid = np.linspace(0.0, leg.length, DENSE_POINTS)
    _, idx = cKDTree(leg.evaluate(grid)[0]).query(q)
    s = grid[idx]
    for _ in range(NEWTON_STEPS):
        p, dp, ddp = leg.evaluate(s)
        r = p - q
        g = np.einsum("ij,ij->i", r, dp)
        h = np.einsum("ij,ij->i", dp, dp) + np.einsum("ij,ij->i", r, ddp)
        s = np.clip(s - g / np.where(h > 1e-12, h, 1e-12), 0.0, leg.length)
    return np.asarray(np.linalg.norm(leg.evaluate(s)[0] - q, axis=1), dtype=float)
