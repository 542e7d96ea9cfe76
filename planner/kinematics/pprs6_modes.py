"""Every assembly mode of the pprs6 forward kinematics that a set of starts finds (issue 15).

The forward problem of the 2PPRS-RPRS platform has several solutions for one set of drives: near the level
platform two of them, with yaws of opposite sign, coalesce (the type-II singularity of
:mod:`planner.kinematics.pprs6`). Newton from one start returns the solution connected to that start,
which for a pose of negative yaw started from the (positively yawed) home pose is the *other* mode --
millimetres and tenths of a radian away, with the same drives. So :func:`assembly_modes` runs the damped
Newton of :func:`~planner.kinematics.pprs6.forward` from many starts at once (the caller's guess, the
home pose, the level-platform estimate, and that estimate with yaws over +-:data:`YAW_SPAN_RAD` and tilts
of +-:data:`TILT_RAD`), keeps the converged poses that reproduce the drives and close every chain, merges
those closer than :data:`SAME_MODE` (translation [m], rotations times r), and marks the one reached from
home and the one nearest the guess. Starts are a finite sample: a mode no start reaches is not listed
(the count is "modes found", not a proof of their number).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.kinematics import pprs6 as kin

Array = NDArray[np.float64]

YAW_SPAN_RAD = 0.8
YAW_STEPS = 9
TILT_RAD = 0.15
SAME_MODE = 1e-6


@dataclass(frozen=True)
class AssemblyModes:
    """Distinct poses (K, 6) reproducing one set of drives, with the marked ones.

    Attributes:
        poses: The modes found, (K, 6), sorted by distance to the home-connected one.
        home: Index of the mode Newton reaches from the home pose (None if it reaches none).
        nearest_guess: Index of the mode nearest the guess (None without a guess).
        starts: Number of starts tried.
    """

    poses: Array
    home: int | None
    nearest_guess: int | None
    starts: int


def _starts(geom: kin.Pprs6Geometry, drives: Array, guess: Array | None, home: Array) -> Array:
    level = kin.level_guess(geom, drives[None])[0]
    starts = [home, level] if guess is None else [guess, home, level]
    for yaw in np.linspace(-YAW_SPAN_RAD, YAW_SPAN_RAD, YAW_STEPS):
        for tilt in ((0.0, 0.0), (TILT_RAD, TILT_RAD), (-TILT_RAD, -TILT_RAD)):
            s = level.copy()
            s[3], s[4], s[5] = yaw, tilt[0], tilt[1]
            starts.append(s)
    return np.array(starts)


def _distance(geom: kin.Pprs6Geometry, a: Array, b: Array) -> Array:
    w = np.array([1.0, 1.0, 1.0, geom.r, geom.r, geom.r])
    return np.asarray(np.max(np.abs(a - b) * w, axis=-1))


def assembly_modes(
    geom: kin.Pprs6Geometry, drives: Array, home: Array, guess: Array | None = None
) -> AssemblyModes:
    """The assembly modes found for one set of drives (module docstring).

    Args:
        geom: Mechanism geometry.
        drives: Drive positions (6,).
        home: The home pose (6,) (the mode connected to it is marked).
        guess: Optional pose (6,) (the mode nearest it is marked; it is also a start).
    """
    q = np.asarray(drives, dtype=float)
    starts = _starts(geom, q, guess, np.asarray(home, dtype=float))
    x, ok, _ = kin.forward(geom, np.broadcast_to(q, starts.shape).copy(), starts)
    found: list[Array] = []
    from_start: list[int | None] = []
    for xi, oki in zip(x, ok, strict=True):
        if not oki:
            from_start.append(None)
            continue
        for k, f in enumerate(found):
            if _distance(geom, xi, f) <= SAME_MODE:
                from_start.append(k)
                break
        else:
            found.append(xi)
            from_start.append(len(found) - 1)
    home_start = 0 if guess is None else 1
    home_mode = from_start[home_start]
    if not found:
        return AssemblyModes(np.zeros((0, 6)), None, None, len(starts))
    poses = np.array(found)
    ref = poses[home_mode] if home_mode is not None else poses[0]
    order = np.argsort(_distance(geom, poses, ref), kind="stable")
    poses = poses[order]
    rank = {int(old): new for new, old in enumerate(order)}
    home_idx = None if home_mode is None else rank[home_mode]
    near = None if guess is None else int(np.argmin(_distance(geom, poses, np.asarray(guess, dtype=float))))
    return AssemblyModes(poses, home_idx, near, len(starts))
