"""Time-aware corner cutting of a certified joint-space polyline.

The sampling planner and its simplifier shorten a path in (scaled) Euclidean length, which does not see
that drives run concurrently: a posture change at a standstill followed by a rail move costs the sum of
both times, while the same change made *during* the rail move costs only the longer one. Around a
hatch this is the difference between reconfiguring at the start's rail position and reconfiguring on the
way to the hatch.

At a corner C between P and N (segments P -> C and C -> N, both certified), a cut replaces C by the chord
A -> B with A = C + alpha (P - C) and B = C + beta (N - C), for alpha, beta in :data:`CUT_FRACTIONS`
and beta in :data:`CUT_ENDS` (1 reaches the neighbouring waypoint itself). The parts P -> A and B -> N lie
on certified segments, so only the chord needs the certified motion check. The time of a segment is
estimated as its slowest drive's time at its velocity limit (the drive-map Jacobian at C). For each beta
the longest certified alpha is found by trying the fractions longest first, those that would gain enough
only: a refused chord's walk stops at the first state it cannot prove (0.2 ms on average on cluttered
and octagonal cabins), a certified one walks the whole chord (5.6 ms), so one certified walk per beta
costs least (a bisection, which assumed validity monotone in alpha, proved two or three). The cut with
the largest estimated gain is kept. Deterministic (no random choices).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planner.core.types import Array
from planner.robots.cabin8 import Cabin8

#: How far back along the incoming segment a cut may start (fractions of the segment, longest first),
#: and how far along the outgoing one it may end.
CUT_FRACTIONS = (1.0, 0.75, 0.55, 0.4, 0.28, 0.18, 0.1)
CUT_ENDS = (1.0, 0.5)
#: A cut must save at least this much estimated time [s] (0.05 s gave the same durations, 20% more checks).
MIN_GAIN_S = 0.2
#: Passes over the corners (each stops early when it changed nothing).
PASSES = 2


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
    cuts = checks = 0
    saved = 0.0
    settled: set[bytes] = set()
    for _ in range(PASSES):
        changed = False
        i = 1
        while i < len(path) - 1:
            if deadline():
                return np.array(path), CutStats(cuts, checks, saved)
            p, c, n = path[i - 1], path[i], path[i + 1]
            key = p.tobytes() + c.tobytes() + n.tobytes()
            if key in settled:  # this very corner found nothing before
                i += 1
                continue
            t_in, t_out = segment_times(robot, c, np.stack([p, c]), np.stack([c, n]))
            best: tuple[float, Array, Array, float, float] | None = None
            for beta in CUT_ENDS:
                A = c[None, :] + frac[:, None] * (p - c)[None, :]
                B = np.repeat((c + beta * (n - c))[None, :], len(frac), axis=0)
                gain = (
                    t_in
                    + t_out
                    - ((1.0 - frac) * t_in + segment_times(robot, c, A, B) + (1.0 - beta) * t_out)
                )
                floor = max(MIN_GAIN_S, best[0] if best is not None else 0.0)
                if gain.max() <= floor:
                    continue
                # The longest certified cut, longest first: a refused chord costs little (its walk stops
                # at the first state it cannot prove, 0.2 ms on average), a certified one its whole walk
                # (5.6 ms): one certified walk per beta, where a bisection proved two or three.
                found = -1
                for m in np.flatnonzero(gain > floor).tolist():
                    checks += 1
                    if motion_ok(A[m], B[m]):
                        found = m
                        break
                if found >= 0:
                    best = (float(gain[found]), A[found], B[found], float(frac[found]), beta)
            step = 1
            if best is None:
                settled.add(key)
            else:
                g, a_pt, b_pt, alpha, beta = best
                keep = [q for q, f in ((a_pt, alpha), (b_pt, beta)) if f < 1.0]
                path[i : i + 1] = keep
                step = len(keep)  # 0: the corner vanished, P and N are neighbours now
                cuts += 1
                saved += g
                changed = True
            i += step
        if not changed:
            break
    return np.array(path), CutStats(cuts, checks, saved)
