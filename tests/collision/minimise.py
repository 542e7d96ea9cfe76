"""Independent minimisations of convex hulls' distances (SLSQP), to check the compiled distances."""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize


def qp_distance(pts: np.ndarray, v: np.ndarray, f: np.ndarray, near: float) -> float:
    """Min |x - y| over x in conv(pts), y in a triangle within ``near`` + 1 mm of their boxes (SLSQP)."""
    lo, hi = pts.min(axis=0) - near - 1e-3, pts.max(axis=0) + near + 1e-3
    best = np.inf
    for tri in v[f]:
        if np.any(tri.max(axis=0) < lo) or np.any(tri.min(axis=0) > hi):
            continue
        m = (pts[:, None, :] - tri[None, :, :]).reshape(-1, 3)
        n = len(m)
        res = minimize(
            lambda w, m=m: float(np.sum((w @ m) ** 2)),
            np.full(n, 1.0 / n),
            jac=lambda w, m=m: 2.0 * m @ (w @ m),
            bounds=[(0.0, 1.0)] * n,
            constraints=[{"type": "eq", "fun": lambda w: w.sum() - 1.0}],
            method="SLSQP",
            options={"ftol": 1e-16, "maxiter": 1000},
        )
        best = min(best, float(np.sqrt(res.fun)))
    return best


def hull_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Min |x - y| over x in conv(a), y in conv(b) (point sets (n, 3), (m, 3)), by SLSQP on both weights."""
    na = len(a)

    def gap(w: np.ndarray) -> np.ndarray:
        return np.asarray(w[:na] @ a - w[na:] @ b)

    res = minimize(
        lambda w: float(gap(w) @ gap(w)),
        np.concatenate([np.full(na, 1.0 / na), np.full(len(b), 1.0 / len(b))]),
        jac=lambda w: 2.0 * np.concatenate([a @ gap(w), -(b @ gap(w))]),
        bounds=[(0.0, 1.0)] * (na + len(b)),
        constraints=[
            {"type": "eq", "fun": lambda w: w[:na].sum() - 1.0},
            {"type": "eq", "fun": lambda w: w[na:].sum() - 1.0},
        ],
        method="SLSQP",
        options={"ftol": 1e-16, "maxiter": 1000},
    )
    return float(np.sqrt(res.fun))
