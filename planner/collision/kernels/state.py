"""One state check in one compiled call: poses, bounds, verdict (the hot path of OMPL's validity checks).

:func:`packed_state` gives a state's poses and certified bounds, :func:`packed_check` the verdict code the
world acts on (``CLEAR`` needs no FCL query at all), :func:`packed_poses` the poses of many states.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.collision.kernels.bounds import bounds_of_state, cabin_bounds_of_state, certain_cabin_contact
from planner.collision.kernels.buffers import Packed
from planner.collision.kernels.codes import (
    CLEAR,
    CONTACT,
    INADMISSIBLE,
    NOT_FINITE,
    STATE_INVALID,
    STATE_UNDECIDED,
    STATE_VALID,
    UNDECIDED,
)
from planner.collision.kernels.distances import pair_touches
from planner.collision.kernels.mesh import box_touches_mesh, capsule_touches_mesh
from planner.collision.kernels.packed import unpack
from planner.collision.kernels.poses import admissible, poses_at

__all__ = [
    "CLEAR",
    "CONTACT",
    "INADMISSIBLE",
    "NOT_FINITE",
    "UNDECIDED",
    "axis_sweep",
    "packed_check",
    "packed_poses",
]


@njit(cache=True, fastmath=False, error_model="numpy")
def _packed_state(
    q: np.ndarray, u: Packed, grid: np.ndarray, threshold: float, poses: np.ndarray
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Poses into ``poses`` and (cabin bounds, pair bounds, admissible) at q."""
    c = np.empty(u.c_lo.shape[0])
    poses_at(q, u, poses, c)
    return bounds_of_state(poses, u, grid, c, threshold)


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_state(
    q: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, grid: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(poses, cabin bounds, pair bounds, admissible) at q from the packed data."""
    poses = np.empty((ibuf[0], 13))
    cabin, pairs, ok = _packed_state(q, unpack(fbuf, ibuf), grid, threshold, poses)
    return poses, cabin, pairs, ok


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_poses(
    qs: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray, poses: np.ndarray, c: np.ndarray
) -> None:
    """:func:`~.poses.poses_at` at every row of ``qs`` (N, n) into ``poses`` (N, B, 13), ``c`` (N, m)."""
    u = unpack(fbuf, ibuf)
    for i in range(qs.shape[0]):
        poses_at(qs[i], u, poses[i], c[i])


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_check(
    q: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    clearance: float,
    self_clearance: float,
    upper_slack: float,
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The compiled part of a state check: (code, poses, cabin bounds, pair bounds).

    ``CLEAR``: admissible and the bounds prove every body ``clearance`` from the cabin and every pair
    ``self_clearance`` apart. ``INADMISSIBLE``: a limit or margin fails. ``CONTACT``: admissible, and
    the cabin certainly enters some body grown by ``clearance`` (:func:`~.bounds.certain_cabin_contact`;
    a negative ``upper_slack`` disables the test). ``UNDECIDED``: admissible, but some body or pair needs
    an exact (FCL) query. ``NOT_FINITE``: a joint is NaN or infinite (the poses all NaN).
    """
    poses = np.empty((ibuf[0], 13))
    for i in range(q.shape[0]):
        if not math.isfinite(q[i]):  # no poses are computed: NaN, not whatever the memory held
            poses[:, :] = math.nan
            return NOT_FINITE, poses, np.empty(0), np.empty(0)
    cabin, pairs, ok = _packed_state(q, unpack(fbuf, ibuf), grid, self_clearance, poses)
    if not ok:
        return INADMISSIBLE, poses, cabin, pairs
    code = _cabin_code(poses, cabin, clearance, fbuf, ibuf, grid, upper_slack)
    if code == CLEAR:
        for k in range(pairs.shape[0]):
            if not pairs[k] > self_clearance:
                return UNDECIDED, poses, cabin, pairs
    return code, poses, cabin, pairs


@njit(cache=True, fastmath=False, error_model="numpy")
def _cabin_code(
    poses: np.ndarray,
    cabin: np.ndarray,
    clearance: float,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    upper_slack: float,
) -> int:
    """:func:`packed_check`'s code of an admissible state from its cabin bounds alone.

    ``CLEAR`` (the cabin proven clear: the pairs decide), ``CONTACT`` or ``UNDECIDED``.
    """
    code = CLEAR
    for b in range(cabin.shape[0]):
        if not cabin[b] > clearance:
            if upper_slack >= 0.0 and certain_cabin_contact(
                b, poses, clearance, fbuf, ibuf, grid, upper_slack
            ):
                return CONTACT
            code = UNDECIDED
    return code


@njit(cache=True, fastmath=False, error_model="numpy")
def packed_valid(
    q: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    tris: np.ndarray,
    tree_bounds: np.ndarray,
    tree_links: np.ndarray,
    clearance: float,
    self_clearance: float,
    upper_slack: float,
) -> tuple[int, np.ndarray, int]:
    """A state's verdict in one call: (``STATE_*``, poses (B, 13), probes asked).

    :func:`packed_check`, then, where it leaves the state ``UNDECIDED``, the probes the collision world's
    ``is_valid`` asks in Python, in its order: each body whose cabin bound is not above ``clearance``,
    grown by it, against the cabin's triangle tree (:func:`.mesh.box_touches_mesh`,
    :func:`.mesh.capsule_touches_mesh`), then each pair whose bound is not above ``self_clearance``, each
    body grown by half of it (:func:`.distances.pair_touches`). ``STATE_VALID``: nothing touches (the
    world's obstacles are the caller's); ``STATE_UNDECIDED``: a cabin probe is needed and there is no tree.
    """
    code, poses, cabin, pairs = packed_check(q, fbuf, ibuf, grid, clearance, self_clearance, upper_slack)
    verdict, probes = _verdict(
        code, poses, cabin, pairs, fbuf, ibuf, tris, tree_bounds, tree_links, clearance, self_clearance
    )
    return verdict, poses, probes


@njit(cache=True, fastmath=False, error_model="numpy")
def _verdict(
    code: int,
    poses: np.ndarray,
    cabin: np.ndarray,
    pairs: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    tris: np.ndarray,
    tree_bounds: np.ndarray,
    tree_links: np.ndarray,
    clearance: float,
    self_clearance: float,
) -> tuple[int, int]:
    """:func:`packed_valid`'s (``STATE_*``, probes asked) from a :func:`packed_check` code.

    An ``UNDECIDED`` state gets its probes, in :func:`packed_valid`'s order.
    """
    if code == CLEAR:
        return STATE_VALID, 0
    if code != UNDECIDED:
        return STATE_INVALID, 0
    u = unpack(fbuf, ibuf)
    probes = 0
    for b in range(cabin.shape[0]):
        if cabin[b] <= clearance:
            if tris.shape[0] == 0:
                return STATE_UNDECIDED, probes
            probes += 1
            if u.radius[b] == 0.0:
                hit = box_touches_mesh(poses[b], u.half[b], clearance, tris, tree_bounds, tree_links)
            else:
                hit = capsule_touches_mesh(poses[b], u.radius[b], clearance, tris, tree_bounds, tree_links)
            if hit:
                return STATE_INVALID, probes
    for k in range(pairs.shape[0]):
        if pairs[k] <= self_clearance:
            probes += 1
            if pair_touches(poses, u.radius, u.half, u.pair_a[k], u.pair_b[k], self_clearance):
                return STATE_INVALID, probes
    return STATE_VALID, probes


#: A pair whose bound is this much [m] above the self-clearance at a posture's first valid sweep state is
#: clear at every other rail position of :func:`axis_sweep`: the rail moves every body rigidly, so the pair
#: bounds change only by the rounding of the bodies' coordinates (about 1e-15 m, six orders below).
PAIR_SETTLED_M = 1e-9


@njit(cache=True, fastmath=False, error_model="numpy")
def axis_sweep(
    q: np.ndarray,
    axis: int,
    values: np.ndarray,
    pairs_fixed: bool,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    tris: np.ndarray,
    tree_bounds: np.ndarray,
    tree_links: np.ndarray,
    clearance: float,
    self_clearance: float,
    upper_slack: float,
) -> tuple[int, int, int]:
    """:func:`packed_valid` of q with joint ``axis`` set to each of ``values`` in turn, to the first failure.

    The states are exactly the ones a caller makes by copying q and setting the joint, and each gets
    :func:`packed_valid`'s verdict and probe count. ``pairs_fixed``: the joint moves both bodies of every
    pair rigidly together (cabin8's rail: it moves every body), so the pairs' bounds do not change along
    the sweep but for rounding; then, once a state is valid with every pair bound more than
    :data:`PAIR_SETTLED_M` above ``self_clearance``, the later states skip the pairs (they would find every
    pair clear again and probe none). The loop without a call from Python per state: a transit posture
    swept along the rail, 3.8 us a state where ``is_valid`` state by state takes 8.

    Returns:
        (``STATE_VALID`` when every state is, else the first other verdict; the index of that state in
        ``values``, or ``len(values)``; the probes asked, those of a ``STATE_UNDECIDED`` state left out).
    """
    u = unpack(fbuf, ibuf)
    poses = np.empty((ibuf[0], 13))
    c = np.empty(u.c_lo.shape[0])
    probes = 0
    settled = False
    s = q.copy()
    for i in range(values.shape[0]):
        s[axis] = values[i]
        if settled:
            verdict, asked = _settled_verdict(
                s, u, fbuf, ibuf, grid, tris, tree_bounds, tree_links, clearance, upper_slack, poses, c
            )
        else:
            code, flat, cabin, pairs = packed_check(
                s, fbuf, ibuf, grid, clearance, self_clearance, upper_slack
            )
            verdict, asked = _verdict(
                code, flat, cabin, pairs, fbuf, ibuf, tris, tree_bounds, tree_links, clearance, self_clearance
            )
            if verdict == STATE_VALID and pairs_fixed:
                settled = True
                for k in range(pairs.shape[0]):
                    if not pairs[k] > self_clearance + PAIR_SETTLED_M:
                        settled = False
        if verdict == STATE_UNDECIDED:  # the caller judges this state afresh: its probes are not counted
            return verdict, i, probes
        probes += asked
        if verdict != STATE_VALID:
            return verdict, i, probes
    return STATE_VALID, values.shape[0], probes


@njit(cache=True, fastmath=False, error_model="numpy")
def _settled_verdict(
    s: np.ndarray,
    u: Packed,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    tris: np.ndarray,
    tree_bounds: np.ndarray,
    tree_links: np.ndarray,
    clearance: float,
    upper_slack: float,
    poses: np.ndarray,
    c: np.ndarray,
) -> tuple[int, int]:
    """:func:`packed_valid`'s (verdict, probes) at s when every pair is known clear: its steps without them.

    The same poses, cabin bounds, admissibility and cabin probes as :func:`packed_check` and
    :func:`_verdict` compute, in their order (``poses`` and ``c``: scratch space).
    """
    for i in range(s.shape[0]):
        if not math.isfinite(s[i]):
            return STATE_INVALID, 0
    poses_at(s, u, poses, c)
    cabin = cabin_bounds_of_state(poses, u, grid)
    if not admissible(c, u.c_lo, u.c_hi):
        return STATE_INVALID, 0
    code = _cabin_code(poses, cabin, clearance, fbuf, ibuf, grid, upper_slack)
    no_pairs = np.empty(0)  # every pair clear: none to probe
    return _verdict(code, poses, cabin, no_pairs, fbuf, ibuf, tris, tree_bounds, tree_links, clearance, 0.0)
