"""Time-aware corner cutting of a certified joint-space polyline.

The sampling planner and its simplifier shorten a path in (scaled) Euclidean length, which does not see
that drives run concurrently: a posture change at a standstill followed by a rail move costs the sum of
both times, while the same change made *during* the rail move costs only the longer one. Around a
hatch this is the difference between reconfiguring at the start's rail position and reconfiguring on the
way to the hatch.

At a corner C between P and N (segments P -> C and C -> N, both certified), a cut replaces C by the chord
A -> B with A = C + alpha (P - C) and B = C + beta (N - C), for alpha, beta in :data:`CUT_FRACTIONS`
(1 reaches the neighbouring waypoint itself). The parts P -> A and B -> N lie on certified segments, so
only the chord needs the certified motion check. The time of a segment is estimated as its slowest drive's
time at its velocity limit (the drive-map Jacobian at C); the candidates with the largest estimated gain
are tried first, at most :data:`ATTEMPTS_PER_CORNER` per corner, and the first certified one is kept.
Deterministic (no random choices): the same path gives the same result.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.robots.cabin8 import Cabin8

Array = NDArray[np.float64]

#: How far back along each neighbouring segment a cut may start or end (fractions of the segment).
CUT_FRACTIONS = (1.0, 0.75, 0.55, 0.4, 0.28, 0.18, 0.1)
#: Certified motion checks tried per corner and pass (in order of estimated gain).
ATTEMPTS_PER_CORNER = 4
#: A cut must save at least this much estimated time [s].
MIN_GAIN_S = 0.05
#: Passes over the corners (each stops early when it changed nothing).
PASSES = 3


@dataclass(frozen=True)
class CutStats:
    """What corner cutting did: corners cut, motion checks spent and the estimated time saved [s]."""

    cuts: int
    checks: int
    saved_s: float


def segment_times(robot: Cabin8, q_at: Array, a: Array, b: Array) -> Array:
    """Estimated times of straight segments a -> b (N, 8): slowest drive at v_max, Jacobian at ``q_at``."""
    G, _ = robot.drive_map_jacobian(q_at)
    du = (np.atleast_2d(b) - np.atleast_2d(a)) @ G.T
    return np.max(np.abs(du) / robot.limits.v_max[None, :], axis=1)


def polyline_time(robot: Cabin8, waypoints: Array) -> float:
    """Estimated time of a polyline: the sum of its segments' times (rest at every corner ignored)."""
    return float(
        sum(segment_times(robot, a, a, b)[0] for a, b in zip(waypoints[:-1], waypoints[1:], strict=True))
    )


def cut_corners(
    robot: Cabin8,
    waypoints: Array,
    motion_ok: Callable[[Array, Array], bool],
    deadline: Callable[[], bool] = lambda: False,
) -> tuple[Array, CutStats]:
    """Cut the corners of a certified polyline where that saves time (see the module docstring).

    Args:
        robot: The robot (drive map and velocity limits).
        waypoints: (N, 8) joint waypoints; every segment is certified.
        motion_ok: The certified check of a straight motion (collision, limits, forces).
        deadline: Returns True when the caller's time is up; the path so far is returned.

    Returns:
        The new waypoints (the same end points; every segment certified) and what was done.
    """
    path = [np.asarray(q, dtype=float) for q in waypoints]
    frac = np.array(CUT_FRACTIONS)
    alpha, beta = (g.ravel() for g in np.meshgrid(frac, frac, indexing="ij"))
    cuts = checks = 0
    saved = 0.0
    for _ in range(PASSES):
        changed = False
        i = 1
        while i < len(path) - 1:
            if deadline():
                return np.array(path), CutStats(cuts, checks, saved)
            p, c, n = path[i - 1], path[i], path[i + 1]
            t_in, t_out = segment_times(robot, c, np.stack([p, c]), np.stack([c, n]))
            A = c[None, :] + alpha[:, None] * (p - c)[None, :]
            B = c[None, :] + beta[:, None] * (n - c)[None, :]
            new = (1.0 - alpha) * t_in + segment_times(robot, c, A, B) + (1.0 - beta) * t_out
            gain = t_in + t_out - new
            order = [k for k in np.argsort(-gain, kind="stable") if gain[k] >= MIN_GAIN_S]
            step = 1
            for k in order[:ATTEMPTS_PER_CORNER]:
                checks += 1
                if motion_ok(A[k], B[k]):
                    keep = [q for q, f in ((A[k], alpha[k]), (B[k], beta[k])) if f < 1.0]
                    path[i : i + 1] = keep
                    if alpha[k] == 1.0 and beta[k] == 1.0:
                        step = 0  # the corner vanished: P and N are neighbours now
                    else:
                        step = len(keep)
                    cuts += 1
                    saved += float(gain[k])
                    changed = True
                    break
            i += step
        if not changed:
            break
    return np.array(path), CutStats(cuts, checks, saved)
