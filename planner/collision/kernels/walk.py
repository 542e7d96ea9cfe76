"""The certified motion walk and the path-run rule, compiled.

:func:`motion_walk` is the walk of :mod:`planner.collision.motion` (the maths is in
:meth:`planner.collision.world.CollisionWorld.check_motion`): states and per-body / per-pair bounds are
evaluated on demand, and the walk returns to Python only when a robot pair needs FCL probes on its grown
bodies (a body against the cabin is probed here, on the cabin's triangles: :mod:`.mesh`).
Around it: the limit samples (:func:`first_inadmissible`), the reach bounds of a segment
(:func:`end_ratio`, :func:`segment_reach`) and the run rule of ``check_path`` (:func:`run_extent`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.collision.kernels.bounds import cabin_bound, pair_bound, pair_scratch
from planner.collision.kernels.buffers import Packed
from planner.collision.kernels.codes import (
    CF_CLEARANCE,
    CF_E,
    CF_EPREV,
    CF_FLOOR,
    CF_LAST,
    CF_LEVEL0,
    CF_LOCAL,
    CF_MARGIN,
    CF_OWN,
    CF_PROBE_PROVEN,
    CF_SMALLEST,
    CF_TFAIL,
    CF_THRESHOLD,
    CF_TSTOP,
    CI_CABIN,
    CI_COUNT,
    CI_I,
    CI_LEVELS,
    CI_N,
    CI_PHASE,
    CI_PREV,
    CI_QUERIES,
    CI_SLOT,
    CI_TASK,
    MAX_LEVELS,
    WALK_DONE,
    WALK_FAIL,
    WALK_GROW,
    WALK_PROBE,
)
from planner.collision.kernels.mesh import (
    box_mesh_distance,
    box_touches_mesh,
    capsule_mesh_distance,
    capsule_touches_mesh,
)
from planner.collision.kernels.packed import unpack
from planner.collision.kernels.poses import admissible, constraints_at, poses_at


@njit(cache=True, fastmath=False, error_model="numpy")
def first_inadmissible(
    q_a: np.ndarray, dq: np.ndarray, n_fine: int, fbuf: np.ndarray, ibuf: np.ndarray
) -> int:
    """First of the samples t_i = i / n_fine (as ``numpy.linspace``) where c(q) fails; -1: none."""
    u = unpack(fbuf, ibuf)
    c_lo, c_hi = u.c_lo, u.c_hi
    c = np.empty(c_lo.shape[0])
    q = np.empty(q_a.shape[0])
    step = 1.0 / n_fine
    for i in range(n_fine + 1):
        t = i * step if i < n_fine else 1.0
        for j in range(q.shape[0]):
            q[j] = q_a[j] + t * dq[j]
        constraints_at(q, u, c)
        if not admissible(c, c_lo, c_hi):
            return i
    return -1


@njit(cache=True, fastmath=False, error_model="numpy")
def end_ratio(q_a: np.ndarray, q_b: np.ndarray, fbuf: np.ndarray, ibuf: np.ndarray) -> float:
    """Largest slope ratio at the two ends; 1 if one is not finite.

    The ratio is c(q) at the model's ``ratio_rows`` (cabin8: the link heights y_B/L1, y_C/L3, y_E/L4).
    """
    u = unpack(fbuf, ibuf)
    c = np.empty(u.c_lo.shape[0])
    out = -math.inf
    for end in range(2):
        constraints_at(q_a if end == 0 else q_b, u, c)
        for i in u.ratio_rows:
            if not math.isfinite(c[i]):
                return 1.0
            out = max(out, c[i])
    return out


@njit(cache=True, fastmath=False, error_model="numpy")
def segment_reach(
    rho: np.ndarray,  # (B, n_joints) static reach bounds
    link: np.ndarray,  # (B,) bool: slope-dependent (cabin8's stage links: y and gamma bounds grow with k)
    k: float,  # slope bound of the links along the segment
    h: float,  # L2 / 2
    pair_a: np.ndarray,
    pair_b: np.ndarray,
    rigid: np.ndarray,  # (P, n_joints) bool: joint j moves both bodies of pair p rigidly
    adq: np.ndarray,  # (n_joints,) |q_b - q_a|
) -> tuple[np.ndarray, np.ndarray]:
    """Displacement bounds over the segment: bodies rho . |dq|, pairs (rho_a + rho_b, rigid joints 0) . |dq|.

    ``bodies.segment_reach_bounds`` with the segment's slope bound, then the products, in one pass.
    """
    n_b = rho.shape[0]
    r = rho.copy()
    for b in range(n_b):
        if link[b]:
            r[b, 2] = max(1.0, k)  # y
            r[b, 3] = h * (1.0 + k)  # gamma
    reach = np.zeros(n_b)
    for b in range(n_b):
        for j in range(adq.shape[0]):
            reach[b] += r[b, j] * adq[j]
    n_p = pair_a.shape[0]
    pair = np.zeros(n_p)
    for p in range(n_p):
        for j in range(adq.shape[0]):
            if not rigid[p, j]:
                pair[p] += (r[pair_a[p], j] + r[pair_b[p], j]) * adq[j]
    return reach, pair


@njit(cache=True, fastmath=False, error_model="numpy")
def run_extent(qs: np.ndarray, i: int, j: int, rho: np.ndarray, max_extra: float) -> tuple[int, float]:
    """The run of :meth:`CollisionWorld.check_path` from sample i: (its last sample, its extra clearance).

    Starting at j, the run is halved until the samples' reach-weighted deviation from the chord
    q_i -> q_j (parameterised alike: sample k at (k - i) / (j - i)), doubled for self pairs, plus 1e-6, is
    at most ``max_extra``; a single piece has no extra.
    """
    n_j = qs.shape[1]
    while j > i + 1:
        m = j - i
        worst = 0.0
        for a in range(n_j):
            e = 0.0
            step = qs[j, a] - qs[i, a]
            for k in range(1, m):
                d = abs(qs[i + k, a] - (qs[i, a] + (k / m) * step))
                if d > e:
                    e = d
            worst += rho[a] * e
        extra = worst * 2.0 + 1e-6
        if extra <= max_extra:
            return j, extra
        j = i + max(1, m // 2)
    return j, 0.0


@njit(cache=True, fastmath=False, error_model="numpy")
def _walk_state(
    i: int,
    ci: np.ndarray,
    q_a: np.ndarray,
    dq: np.ndarray,
    u: Packed,
    slot_of: np.ndarray,
    poses: np.ndarray,
    cabin: np.ndarray,
    pairs: np.ndarray,
) -> int:
    """Slot of state i (t = i / n), its poses evaluated on first use; -1 when the store is full."""
    s = slot_of[i]
    if s >= 0:
        return s
    s = ci[CI_COUNT]
    if s == poses.shape[0]:
        return -1
    t = i / ci[CI_N]
    q = np.empty(q_a.shape[0])
    for j in range(q.shape[0]):
        q[j] = q_a[j] + t * dq[j]
    poses_at(q, u, poses[s], np.empty(u.c_lo.shape[0]))
    cabin[s, :] = math.nan  # bounds are evaluated on demand (:func:`_walk_bound`)
    pairs[s, :] = math.nan
    slot_of[i] = s
    ci[CI_COUNT] = s + 1
    return s


@njit(cache=True, fastmath=False, error_model="numpy")
def _walk_bound(s, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch):  # type: ignore[no-untyped-def]
    """The bound of body/pair idx at slot s (NaN in the store: not yet evaluated)."""
    if is_cabin:
        v = cabin[s, idx]
        if math.isnan(v):
            v = cabin[s, idx] = cabin_bound(idx, poses[s], u, grid)
        return v
    v = pairs[s, idx]
    if math.isnan(v):
        v = pairs[s, idx] = pair_bound(idx, poses[s], u, threshold, scratch)
    return v


@njit(cache=True, fastmath=False, error_model="numpy")
def probe_levels(cf: np.ndarray, m: int, above: float, start: float, mm: float) -> int:
    """Append the levels ``start``, ``start / 2``, ... above ``mm``, then ``mm``, to ``cf[CF_LEVEL0 + m:]``.

    Only levels strictly below ``above`` (the last one listed: a grown body that hit at a level hits at
    every larger one) and at most ``MAX_LEVELS`` in all, the margin always last. Returns the new count.
    """
    level = start
    while level > mm and m < MAX_LEVELS - 1:
        if level < above:
            cf[CF_LEVEL0 + m] = above = level
            m += 1
        level *= 0.5
    if mm < above:
        cf[CF_LEVEL0 + m] = mm
        m += 1
    return m


@njit(cache=True, fastmath=False, error_model="numpy")
def motion_walk(
    ci: np.ndarray,
    cf: np.ndarray,
    q_a: np.ndarray,
    q_b: np.ndarray,
    dq: np.ndarray,
    reach: np.ndarray,
    pair_reach: np.ndarray,
    fbuf: np.ndarray,
    ibuf: np.ndarray,
    grid: np.ndarray,
    tris: np.ndarray,
    tree_bounds: np.ndarray,
    tree_links: np.ndarray,
    slot_of: np.ndarray,
    poses: np.ndarray,
    cabin: np.ndarray,
    pairs: np.ndarray,
) -> int:
    """The certified motion walk of ``CollisionWorld.check_motion``, resumable around FCL probes.

    Tasks: every body against the cabin (if any), then every checked pair. For each, both end states
    first (spare clearance f0, f1 >= margin with f0 + f1 >= D covers the segment), the carriage by its
    exact table, else the walk: at state i the spare clearance E (the bound, or an FCL probe on the grown
    body), then the next state at t + (E + margin) / D snapped down onto the schedule t = i / n.

    Returns ``WALK_PROBE`` when the walk needs FCL: ``ci[CI_SLOT]`` is the state's slot, the
    ``ci[CI_LEVELS]`` levels to try in order are at ``cf[CF_LEVEL0:]``, ``cf[CF_E]`` the bound's E; the
    caller writes the first level that did not collide (or leaves E) into ``cf[CF_E]`` and calls again.
    A body against the cabin, with the cabin's tree given (``tris``, ``tree_bounds``, ``tree_links``:
    :func:`.mesh.mesh_tree`; empty: none), is probed here, level by level, by the same test
    (:func:`.mesh.box_touches_mesh` on a box grown by the level, as FCL's grown box;
    :func:`.mesh.capsule_touches_mesh` on a capsule; counted in ``ci[CI_QUERIES]``), and where every level
    touched, its exact distance to the cabin decides as the caller's does (:func:`.mesh.box_mesh_distance`,
    :func:`.mesh.capsule_mesh_distance`): only pairs return ``WALK_PROBE``.
    ``WALK_FAIL``: no margin could be proven (task ``ci[CI_TASK]``, at ``cf[CF_TFAIL]``). ``WALK_GROW``:
    the state store is full (enlarge and call again). ``WALK_DONE``: every task is certified.
    """
    u = unpack(fbuf, ibuf)
    capsule_pair, capsule_box, carriage = u.capsule_pair, u.capsule_box, u.carriage
    table, z0, dz = u.table, u.table_z0, u.table_dz
    scratch = pair_scratch(u)
    threshold = cf[CF_THRESHOLD]
    n_b = reach.shape[0]
    n_cabin = n_b if ci[CI_CABIN] else 0
    n_tasks = n_cabin + pair_reach.shape[0]
    n = ci[CI_N]
    mm = cf[CF_MARGIN]
    while ci[CI_TASK] < n_tasks:
        task = ci[CI_TASK]
        is_cabin = task < n_cabin
        idx = task if is_cabin else task - n_cabin
        D = reach[idx] if is_cabin else pair_reach[idx]
        base = cf[CF_CLEARANCE] if is_cabin else cf[CF_OWN]
        exact = (not is_cabin) and (capsule_pair[idx] != 0 or capsule_box[idx] > 0)
        phase = ci[CI_PHASE]
        if phase == 0:  # a new task: both end states
            s0 = _walk_state(0, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s0 < 0:
                return WALK_GROW
            s1 = _walk_state(n, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s1 < 0:
                return WALK_GROW
            f0 = _walk_bound(s0, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            f1 = _walk_bound(s1, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            if f0 >= mm and f1 >= mm and f0 + f1 >= D:
                ci[CI_TASK] += 1
                continue
            if is_cabin and idx == carriage and table.shape[0] > 0:
                # The carriage moves with d1 only: its exact clearance table covers the whole segment.
                lo, hi = min(q_a[0], q_b[0]), max(q_a[0], q_b[0])
                nt = table.shape[0]
                if not (lo < z0 or hi > z0 + dz * (nt - 1)):
                    k0 = int(min(max(math.floor((lo - z0) / dz), 0.0), nt - 1.0))
                    k1 = int(min(max(math.ceil((hi - z0) / dz), 0.0), nt - 1.0))
                    if table[k0 : k1 + 1].min() - 0.5 * dz > cf[CF_CLEARANCE]:
                        ci[CI_TASK] += 1
                        continue
            cf[CF_TSTOP] = 1.0 - f1 / D if f1 >= mm and D > 0.0 else 1.0
            ci[CI_I] = 0
            ci[CI_PREV] = -1
            cf[CF_LAST] = cf[CF_LOCAL] = mm
            ci[CI_PHASE] = phase = 2
        i = ci[CI_I]
        local = cf[CF_LOCAL]  # the margin this state must prove (the walk's, or less near a tight state)
        if phase == 2:  # at state i: the bound's spare clearance, then probes if they can prove more
            s = _walk_state(i, ci, q_a, dq, u, slot_of, poses, cabin, pairs)
            if s < 0:
                return WALK_GROW
            free = _walk_bound(s, is_cabin, idx, threshold, u, grid, poses, cabin, pairs, scratch) - base
            E = free if free >= local else 0.0
            m = 0
            above = math.inf  # the last level listed: a level at or above one that hit would hit too
            if D > 0.0 and not exact and (E == 0.0 or cf[CF_PROBE_PROVEN] != 0.0):
                level = min(0.3, max(2.0 * cf[CF_LAST], 2.0 * E, 4.0 * local))
                if level > E:
                    cf[CF_LEVEL0 + m] = above = level
                    m += 1
            if E == 0.0 and not exact:
                # Then the level proven last time (the spare clearance changes little from state to state)
                # halved down to the margin, strictly decreasing (see ``probe_levels``).
                m = probe_levels(cf, m, above, max(cf[CF_LAST], 2.0 * local), local)
            probe = m > 0
            if probe and is_cabin and tris.shape[0] > 0:  # a body against the cabin: probed here
                r_b = u.radius[idx]  # 0: a box; else a capsule
                lowest = math.inf
                clear = False
                for r in range(m):
                    level = cf[CF_LEVEL0 + r]
                    lowest = min(lowest, level)
                    ci[CI_QUERIES] += 1
                    grow = base + level
                    if r_b == 0.0:
                        hit = box_touches_mesh(
                            poses[s, idx], u.half[idx], grow, tris, tree_bounds, tree_links
                        )
                    else:
                        hit = capsule_touches_mesh(poses[s, idx], r_b, grow, tris, tree_bounds, tree_links)
                    if not hit:
                        E = level
                        clear = True
                        break
                if not clear and lowest <= local + 1e-12:
                    # Every grown body touched. A grown box is a larger box: near its edges and corners it
                    # overstates the clearance it tests by up to (sqrt 3 - 1) times the growth, so the exact
                    # distance decides; it is below sqrt 3 times the smallest growth that touched.
                    cap = math.sqrt(3.0) * (base + lowest) + 1e-6
                    body = poses[s, idx]
                    if r_b == 0.0:
                        d = box_mesh_distance(body, u.half[idx], cap, tris, tree_bounds, tree_links)
                    else:
                        d = capsule_mesh_distance(body, r_b, cap, tris, tree_bounds, tree_links)
                    if d - base >= local:
                        E = d - base
                probe = False
            if probe:
                ci[CI_SLOT] = s
                ci[CI_LEVELS] = m
                cf[CF_E] = E
                ci[CI_PHASE] = 1
                return WALK_PROBE
        else:  # phase 1: the caller's probe result
            E = cf[CF_E]
        cf[CF_LAST] = max(E, local)
        t = i / n
        if E == 0.0:
            if local <= cf[CF_FLOOR]:
                cf[CF_TFAIL] = t
                return WALK_FAIL
            # Near a tight state: halve the margin and step again from the last proven state (or test the
            # first state again): the new state is no farther than the proven margin and the new one reach.
            local = cf[CF_LOCAL] = max(cf[CF_FLOOR], 0.5 * local)
            cf[CF_SMALLEST] = min(cf[CF_SMALLEST], local)
            prev = ci[CI_PREV]
            if prev >= 0:
                back = int(math.floor((prev / n + (cf[CF_EPREV] + local) / D) * n + 1e-9))
                ci[CI_I] = min(i, max(prev + 1, back))
            ci[CI_PHASE] = 2
            continue
        ci[CI_PREV] = i
        cf[CF_EPREV] = E
        if E >= 2.0 * local:  # room again: back towards the walk's margin
            local = cf[CF_LOCAL] = min(mm, 2.0 * local)
        if i == n or D <= 0.0 or t + E / D >= cf[CF_TSTOP]:
            ci[CI_TASK] += 1
            ci[CI_PHASE] = 0
            continue
        ci[CI_I] = min(n, max(i + 1, int(math.floor((t + (E + local) / D) * n + 1e-9))))
        ci[CI_PHASE] = 2
    return WALK_DONE
