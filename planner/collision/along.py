"""A sampled path in one batched pass: certified clearance along the whole polyline, and its true minimum.

The path is the polyline through N joint samples q_0..q_{N-1} (straight joint-space pieces between
consecutive samples, as :meth:`~planner.collision.world.CollisionWorld.check_path` certifies it). A *task*
is one body against the cabin, one checked pair of bodies, or one body against one obstacle (an installed
unit, a fixture: :mod:`.obstacles`); for task t, d_t(q) is its exact distance. A world's *allowed* pairs
(body, obstacle) are tasks too, but only measured for their own report (:meth:`AlongPath.allowed_clearance`).

One compiled call gives every sample's body poses and admissibility values; certified lower bounds
L[k, t] <= d_t(q_k) come on demand (:func:`~planner.collision.kernels.along.bounds_at` and the compiled walk
for the cabin and pair tasks: sphere covers on the cabin's clearance grid, pairs by their covers, exact for
capsules; for the obstacle tasks each body's bounding sphere against the obstacle's bounding box at every
sample in one vectorised pass, its fine sphere cover where that falls short). Along piece k no point of a
body moves more than D[k, t] = rho_t . |q_{k+1} - q_k| (the reach bounds of :mod:`planner.collision.bodies`
with the slope bound of the whole path, pairs by their relative reach), and from sample k to k + 1 no more
than its vertices do (:func:`~planner.collision.sweep.task_offsets` of consecutive samples); C_t, growing
by the smaller of the two from sample to sample, makes d_t 1-Lipschitz over the samples (C_t(q_0) = 0). Hence:

* an exact distance d at sample k bounds every other sample: L[j, t] >= d - |C_t(j) - C_t(k)| (the bounds
  are propagated both ways by running maxima);
* on piece k, d_t >= max((L_k + L_{k+1} - D) / 2, max(L_k, L_{k+1}) - D) (two cones meeting), the lower
  bound *between* samples;
* piece k keeps ``need`` (the clearance plus the walk's margin) everywhere when L_k, L_{k+1} >= need and
  (L_k - need) + (L_{k+1} - need) >= D[k, t]: the spare clearance proven at its two ends covers it;
* one swept-hull query (:mod:`.sweep`) bounds a body's distance at every sample of a run at once (exact for
  a body translating on a line).

:meth:`AlongPath.certify` proves every piece so -- the cabin's and the pairs' in one compiled walk
(:func:`~planner.collision.kernels.along.cover_walk`), the obstacles' alike on their bounds: bounds on
demand where the spare clearance proven so far runs out, swept hulls over adaptive windows of samples,
probes and exact distances only where those fall short; a piece whose two exact end distances still cannot
cover it is walked by the world's certified motion check
(:meth:`~planner.collision.world.CollisionWorld.check_motion`, obstacles included), which decides. It is
never weaker than ``check_path``: what it certifies keeps ``clearance + margin`` everywhere.
:meth:`AlongPath.clearance` then finds the exact minimum of the sample distances of every task by branch
and bound on the same bounds (swept hulls for long runs of samples, where a flat distance settles at
once), and the certified lower bound between samples.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable

import numpy as np

from planner.collision.bodies import BodySet, pair_reach_bounds
from planner.collision.kernels.buffers import KernelData
from planner.collision.kernels.codes import (
    BOUND,
    COVER_EXACT,
    CW_K,
    CW_PENDING,
    CW_SIZE,
    CW_TASK,
    EXACT,
    PROBED,
    SPREAD,
)
from planner.collision.kernels.entries import Kernels
from planner.collision.motion import LIMIT_STEP
from planner.collision.obstacles import ObstacleSet
from planner.collision.probes import Probes
from planner.collision.reports import (
    AlongReport,
    BodyState,
    ClearanceAlong,
    MotionReport,
    limit_contacts,
)
from planner.collision.sweep import (
    body_vertices_along,
    pair_vertices_along,
    swept_bound,
    swept_bound_shape,
    swept_bound_tree,
    task_offsets,
)
from planner.core.types import Array, BoolArray, IntArray
from planner.robots.geometry import CollisionModel

#: The exact minimum over the samples is found to within this [m]: every sample's exact distance is at
#: least the reported one minus it (the bounds stop the search there; the reported value itself is an
#: exact FCL distance at a real sample).
CLEARANCE_TOL_M = 1e-4
#: Distance queries (exact, and swept hulls: ~0.1-0.5 ms each near a wall) the figure may spend; what they
#: leave open is reported as the tolerance reached.
MAX_EXACT_QUERIES = 300
#: Runs of open samples at least this long are bounded by one swept hull (:mod:`.sweep`) before they are
#: halved; shorter runs sample by sample (a probe costs ~10 us, a hull ~250 us).
MIN_SWEPT_RUN = 8
#: The longest window [samples] one swept hull covers in the certificate (a hull of a long curved run is
#: loose; a failed one costs a query for nothing).
SWEPT_WINDOW_MAX = 512
#: Samples whose fine obstacle bounds the certificate evaluates at once where it needs one.
FINE_BLOCK = 64
#: Exact distances the figure spends last, at the smallest bounds left below it (within the tolerance).
POLISH_QUERIES = 8
#: Collision probes the figure may spend (~10 us each).
MAX_PROBES = 20_000
#: Spare clearances [m] beyond the clearance plus margin an FCL probe on the grown body tries to prove, the
#: largest first (a collision query costs ~10 us; an exact distance to a nearby wall ~0.5 ms).
PROBE_LEVELS = (0.016, 0.004, 0.001, 0.0)


class AlongPath:
    """The bounds of a sampled path and its certified pieces (see the module docstring).

    Tasks (the columns of :attr:`lower`): each body against the cabin (when there is one), each checked
    pair of bodies, each checked (body, obstacle) pair, then the world's allowed (body, obstacle) pairs
    (measured for their report, :meth:`allowed_clearance`, never certified nor in :meth:`clearance`).

    Args:
        qs: Joint samples (N, n), N >= 2.
        poses: Body poses (N, B, 13) of every sample.
        c: Admissibility values (N, m) of every sample.
        has_cabin: Whether there is a cabin (else only the pairs are tasks).
        model: The robot's collision model (admissibility, slope bounds).
        bodies: The world's bodies (names, checked pairs).
        probes: The world's FCL queries.
        kernels: The world's compiled entries and data, and the pair threshold of exact capsule distances.
        walk: The certified motion check of piece k (q_k -> q_{k+1}): ``walk(k, clearance, self_clearance,
            margin)``, obstacles included.
        obstacles: The world's obstacles (installed units, fixtures) and allowed pairs, or None.
    """

    def __init__(
        self,
        qs: Array,
        poses: Array,
        c: Array,
        has_cabin: bool,
        model: CollisionModel,
        bodies: BodySet,
        probes: Probes,
        kernels: tuple[Kernels, KernelData, float],
        walk: Callable[[int, float, float, float], MotionReport],
        obstacles: ObstacleSet | None = None,
    ) -> None:
        self.q = qs
        self.poses = poses
        self.c = c
        self.model = model
        self.bodies = bodies
        self.probes = probes
        self.obstacles = obstacles
        self._kernels, self._data, self._threshold = kernels
        self._walk = walk
        self.n = len(qs)
        n_b = len(bodies.names)
        self.n_cabin = n_b if has_cabin else 0
        #: Tasks the compiled kernels evaluate (the cabin's, then the pairs').
        self.n_kernel = self.n_cabin + len(bodies.pairs)
        checked: list[tuple[int, int]] = []
        allowed: list[tuple[int, int]] = []
        if obstacles is not None:
            for b in range(n_b):
                for o in range(len(obstacles)):
                    (checked if obstacles.active[b, o] else allowed).append((b, o))
        #: (body, obstacle) of the task columns from ``n_kernel`` on: the checked pairs, then the allowed.
        self.obstacle_tasks = tuple(checked + allowed)
        #: Tasks certified and in the figure (the allowed pairs' columns follow them).
        self.n_checked = self.n_kernel + len(checked)
        n_tasks = self.n_checked + len(allowed)
        #: Each task's bodies: col_a (and col_b for a pair, -1 otherwise), in the task columns' order.
        singles = list(range(n_b)) if has_cabin else []
        ob_bodies = [b for b, _ in self.obstacle_tasks]
        self._col_a = np.array(singles + [a for a, _ in bodies.pairs] + ob_bodies, dtype=np.int64)
        self._col_b = np.array(
            [-1] * len(singles) + [b for _, b in bodies.pairs] + [-1] * len(ob_bodies), dtype=np.int64
        )
        #: Lower bounds (N, T) of every task (cabin tasks first, then pairs); raised as evidence comes.
        self.lower = np.full((self.n, n_tasks), -np.inf)
        #: What each entry of ``lower`` is: ``SPREAD`` (only what other samples imply), ``BOUND``, ``EXACT``.
        self.state = np.zeros((self.n, n_tasks), dtype=np.int64)
        self.queries = 0
        #: Swept-hull queries of the figure (:mod:`.sweep`), and each task's body vertices (N, V, 3) for them.
        self.swept_queries = 0
        self._verts: dict[int, Array] = {}
        #: The certificate's swept windows: each task's window length, the sample before which a failed
        #: window is not tried again, and the (sample, task) entries a window was tried from: once each, so
        #: that a piece a window leaves uncovered (its other end short) gets probes next, not the same
        #: window again (which looped for ever on a generated cycle).
        self._window: dict[int, int] = {}
        self._no_sweep: dict[int, int] = {}
        self._swept_from: set[tuple[int, int]] = set()
        self.probes_used = 0
        # Reach along each piece: the slope bound of the whole path (every piece's ratio stays below the
        # largest sample ratio plus the largest deviation of any piece), as the motion check computes it.
        dq = np.abs(np.diff(qs, axis=0))
        rows = list(model.ratio_rows)
        ratio = 0.0
        if rows:
            ratios = c[:, rows]
            ratio = float(np.max(ratios)) if np.all(np.isfinite(ratios)) else 1.0
            dev = np.atleast_1d(model.slope_deviation(qs[:-1].T, qs[1:].T))
            ratio = min(ratio + float(np.max(dev)), 1.0) if np.all(np.isfinite(dev)) else 1.0
        rho = model.segment_reach_bounds(bodies.names, bodies.rho, ratio)
        pair_rho = pair_reach_bounds(rho, bodies.pairs, bodies.pair_rigid)
        cols = [rho, pair_rho] if has_cabin else [pair_rho]
        if self.obstacle_tasks:
            cols.append(rho[[b for b, _ in self.obstacle_tasks]])
        #: Reach (N - 1, T): how far any point of a task's bodies (pairs: relative) moves along each piece.
        rho_t = np.concatenate(cols, axis=0)  # (T, n)
        self.reach = np.ascontiguousarray(dq @ rho_t.T)
        # From sample to sample the bodies' vertices move exactly this far (a pair: both bodies' sum), often
        # far less than the reach bound, which holds between samples too.
        steps = self._task_offsets(poses[:-1], poses[1:])  # (N - 1, T)
        #: Cumulative sample-to-sample bound (N, T): |d_t(q_j) - d_t(q_k)| <= |cum[j, t] - cum[k, t]|, each
        #: step the smaller of the vertices' displacement and the piece's reach (compiled: .kernels.spread).
        self.cum = kernels[0].cumulative_bound(self.reach, steps)
        nk = self.n_kernel
        self._reach_k = np.ascontiguousarray(self.reach[:, :nk])
        self._cum_k = np.ascontiguousarray(self.cum[:, :nk])
        if obstacles is not None and self.obstacle_tasks:
            # Every sample's coarse obstacle bounds at once (bounding spheres against bounding boxes); the
            # fine sphere covers on demand (state SPREAD until then, as the kernel tasks' bounds).
            lb = obstacles.coarse_bounds_batch(poses, allowed_too=bool(allowed))
            b_idx = np.array([b for b, _ in self.obstacle_tasks])
            o_idx = np.array([o for _, o in self.obstacle_tasks])
            self.lower[:, nk:] = lb[:, b_idx, o_idx]
            #: Each body's obstacle task columns and their obstacles: (columns, obstacle indices) by body.
            self._body_tasks = {
                b: (nk + np.flatnonzero(b_idx == b), o_idx[b_idx == b]) for b in np.unique(b_idx).tolist()
            }

    def _task_offsets(self, poses_a: Array, poses_b: Array) -> Array:
        """How far each task's bodies move between two poses (M, B, 13) of them: (M, T), an upper bound.

        :func:`~planner.collision.sweep.task_offsets`: a body's own move (cabin and obstacle tasks), a
        pair's both summed.
        """
        return task_offsets(poses_a, poses_b, self.bodies.shapes, self._col_a, self._col_b)

    def seed_from(self, other: AlongPath) -> None:
        """Raise the bounds from another pass over nearby configurations of the same world.

        Sample k's bodies here are within :func:`~planner.collision.sweep.pose_offsets` of their poses in
        ``other`` (the rigid robot's pass, for the sagging robot's: the deflection moves them by a
        millimetre or less), so every bound of ``other`` less that offset bounds the distance here.
        """
        if other.lower.shape != self.lower.shape:
            raise ValueError(f"seed_from: passes of {other.lower.shape} and {self.lower.shape} tasks")
        off = self._task_offsets(other.poses, self.poses)
        np.maximum(self.lower, other.lower - off, out=self.lower)

    # ---------------------------------------------------------------- bounds
    def _propagate(self, cols: IntArray) -> None:
        """Raise columns ``cols`` to max_k (lower[k] - |C(j) - C(k)|) at every j (running maxima)."""
        self._kernels.propagate(self.lower, self.cum, np.ascontiguousarray(cols, dtype=np.int64))

    def _bounds(self, rows: IntArray) -> None:
        """Evaluate the certified bounds of every kernel task at samples ``rows`` (one kernel call)."""
        cabin, pairs = self._kernels.bounds_at(rows, self.poses, self.c, self._data, self._threshold)
        values = np.concatenate([cabin, pairs], axis=1) if self.n_cabin else pairs
        nk = self.n_kernel
        lower, state = self.lower[rows, :nk], self.state[rows, :nk]
        fresh = state == SPREAD
        self.lower[rows, :nk] = np.where(fresh, np.maximum(lower, values), lower)
        self.state[rows, :nk] = np.where(fresh, BOUND, state)

    def _obstacle_bounds(self, rows: IntArray, t: int) -> None:
        """Evaluate the fine obstacle bounds of task t's body at samples ``rows`` (all its obstacle tasks)."""
        assert self.obstacles is not None
        b = self.obstacle_tasks[t - self.n_kernel][0]
        cols, obs = self._body_tasks[b]
        fine = self.obstacles.fine_bounds_batch(self.poses, rows, b)[:, obs]  # (n, tasks of b)
        lower, state = self.lower[np.ix_(rows, cols)], self.state[np.ix_(rows, cols)]
        fresh = state == SPREAD
        self.lower[np.ix_(rows, cols)] = np.where(fresh, np.maximum(lower, fine), lower)
        self.state[np.ix_(rows, cols)] = np.where(fresh, BOUND, state)

    def task_name(self, t: int) -> tuple[str, str]:
        """(body, "cabin"), (body a, body b) or (body, obstacle) of task t."""
        names = self.bodies.names
        if t < self.n_cabin:
            return names[t], "cabin"
        if t < self.n_kernel:
            a, b = self.bodies.pairs[t - self.n_cabin]
            return names[a], names[b]
        assert self.obstacles is not None
        b, o = self.obstacle_tasks[t - self.n_kernel]
        return names[b], self.obstacles.names[o]

    def _body_state(self, k: int) -> BodyState:
        nc = self.n_cabin
        return BodyState(self.poses[k], np.zeros(nc), np.zeros(len(self.bodies.pairs)))  # poses only

    def probe_at(
        self,
        k: int,
        t: int,
        need: float,
        levels: tuple[float, ...] | None = None,
        arrays: tuple[Array, IntArray] | None = None,
    ) -> bool:
        """Raise the bound of task t at sample k by FCL collision probes on the body grown by ``need + E``.

        E in :data:`PROBE_LEVELS` (the largest first); a grown body that does not touch the cabin (an
        obstacle; a pair whose bodies, each grown by half, do not touch) proves the distance is at least its
        growth. Returns whether some level was proven. Cheaper than an exact distance by tens of times near
        a wall. ``arrays``: the (lower, state) arrays to write (default: the path's own).
        """
        lower, state = arrays if arrays is not None else (self.lower, self.state)
        state[k, t] = max(state[k, t], PROBED)
        for level in PROBE_LEVELS if levels is None else levels:
            if need + level <= lower[k, t]:
                return True
            self.probes_used += 1
            if t < self.n_kernel:
                is_cabin = t < self.n_cabin
                idx = t if is_cabin else t - self.n_cabin
                hit = self.probes.hit(self._body_state(k), is_cabin, idx, need + level)
            else:
                assert self.obstacles is not None
                b, o = self.obstacle_tasks[t - self.n_kernel]
                hit = self.obstacles.hit(self.poses[k], b, o, need + level)
            if not hit:
                lower[k, t] = need + level
                return True
        return False

    def exact_at(self, k: int, t: int, arrays: tuple[Array, IntArray] | None = None) -> float:
        """The exact distance of task t at sample k (one distance query, once); written to ``lower``.

        A body against the cabin or an obstacle: compiled on its triangle tree
        (:meth:`~.probes.Probes.distance`, :meth:`~.obstacles.ObstacleSet.distance`); a pair: FCL's.

        An exact distance replaces the bound: were it below (rounding between the distance and the bounds'
        arithmetic), the smaller value is kept, so nothing reported is above what was measured.
        """
        lower, state = arrays if arrays is not None else (self.lower, self.state)
        if state[k, t] == EXACT:
            return float(lower[k, t])
        if t < self.n_kernel:
            is_cabin = t < self.n_cabin
            idx = t if is_cabin else t - self.n_cabin
            d = float(self.probes.distance(self._body_state(k), is_cabin, idx)[0])
        else:
            assert self.obstacles is not None
            b, o = self.obstacle_tasks[t - self.n_kernel]
            d = float(self.obstacles.distance(self.poses[k], b, o)[0])
        self.queries += 1
        state[k, t] = EXACT
        lower[k, t] = d
        return d

    def swept_at(self, i: int, j: int, t: int) -> float:
        """The swept-hull bound of task t over samples i..j (:mod:`.sweep`; a pair: body a in b's frame)."""
        verts = self._verts.get(t)
        if t < self.n_cabin:
            b = t
            shape = self.bodies.shapes[b]
            if verts is None:
                verts = self._verts[t] = body_vertices_along(self.poses, b, shape)
        elif t < self.n_kernel:  # a pair: a's vertices in b's frame, against b's shape (compiled)
            a, b = self.bodies.pairs[t - self.n_cabin]
            shape = self.bodies.shapes[a]
            if verts is None:
                verts = self._verts[t] = pair_vertices_along(self.poses, a, b, shape)
            self.swept_queries += 1
            length = float(np.max(self.poses[i : j + 1, b, 12]))
            return swept_bound_shape(verts[i : j + 1], shape, self.bodies.shapes[b], length)
        else:  # an obstacle: its own bound (compiled on its triangles, see :mod:`.obstacles`)
            assert self.obstacles is not None
            b, o = self.obstacle_tasks[t - self.n_kernel]
            shape = self.bodies.shapes[b]
            if verts is None:
                verts = self._verts[t] = body_vertices_along(self.poses, b, shape)
            self.swept_queries += 1
            return self.obstacles.swept_bound(verts[i : j + 1], shape, o)
        self.swept_queries += 1
        if self.probes.tree is not None:  # the cabin: compiled, on its triangle tree
            return swept_bound_tree(verts[i : j + 1], shape, self.probes.tree)
        return swept_bound(verts[i : j + 1], shape, self.probes.cabin_obj)

    # ---------------------------------------------------------- certificate
    def certify(self, clearance: float, self_clearance: float, margin: float) -> AlongReport:
        """Certify that every piece keeps ``clearance`` (pairs ``self_clearance``) plus ``margin`` everywhere.

        Limits and margins: at every sample (the batched c(q)); a piece longer than ``LIMIT_STEP`` in any
        joint is walked (the motion check samples it every ``LIMIT_STEP``). Collision: each task's pieces
        are covered by the spare clearance proven at their ends (bounds, then probes, then exact distances;
        the cabin's and the pairs' in the compiled walk, the obstacles' alike in numpy); the rest are walked
        by the certified motion check (cabin, pairs and obstacles), which decides.
        """
        lo, hi = self.model.admissibility.c_lower, self.model.admissibility.c_upper
        bad = ~np.all((self.c >= lo[None, :]) & (self.c <= hi[None, :]), axis=1)
        if bad.any():
            k = int(np.argmax(bad))
            contacts = tuple(limit_contacts(self.model.admissibility, self.q[k]))
            return AlongReport(False, self.queries, 0, max(0, k - 1), contacts)
        left = np.max(np.abs(np.diff(self.q, axis=0)), axis=1) > LIMIT_STEP
        nk = self.n_kernel
        n_ob = self.n_checked - nk
        own = [self_clearance] * len(self.bodies.pairs)
        need = np.array([clearance] * self.n_cabin + own + [clearance] * n_ob) + margin
        # The compiled walk needs C-contiguous (N, T_kernel) arrays: the kernel columns (a view when there
        # are no other columns, else a copy written back).
        lk = np.ascontiguousarray(self.lower[:, :nk])
        sk = np.ascontiguousarray(self.state[:, :nk])
        ci = np.zeros(CW_SIZE, dtype=np.int64)
        ci[CW_PENDING] = -1
        need_k = np.ascontiguousarray(need[:nk])
        d = self._data
        args = (self._threshold, self._cum_k, self._reach_k, lk, sk, left)
        code = self._kernels.cover_walk(ci, need_k, self.n_cabin, self.poses, d, *args)  # arguments checked
        # The walk resumes on the same arrays (checked above, only written in place): straight to the entry.
        walk = self._kernels.module.cover_walk
        while code == COVER_EXACT:
            k, t = int(ci[CW_K]), int(ci[CW_TASK])
            if sk[k, t] < PROBED:
                if not self._swept_cover(k, t, float(need[t]), lk, sk):
                    self.probe_at(k, t, float(need[t]), arrays=(lk, sk))
            else:
                self.exact_at(k, t, arrays=(lk, sk))
            code = walk(ci, need_k, self.n_cabin, self.poses, d.fbuf, d.ibuf, d.grid, *args)
        if n_ob:
            self.lower[:, :nk] = lk
            self.state[:, :nk] = sk
            for t in range(nk, self.n_checked):
                self._cover_column(t, float(need[t]), left)
        walked = 0
        for k in np.flatnonzero(left).tolist():
            rep = self._walk(k, clearance, self_clearance, margin)
            walked += 1
            if not rep.valid:
                return AlongReport(False, self.queries, walked, k, rep.contacts)
        return AlongReport(True, self.queries, walked)

    def _swept_cover(self, k: int, t: int, need: float, lower: Array, state: IntArray) -> bool:
        """Cover task t's pieces from sample k on by one swept-hull bound (:mod:`.sweep`), if it can.

        Over the window k..j (its length adapts: doubled after a success, halved after a failure, from
        :data:`MIN_SWEPT_RUN` to :data:`SWEPT_WINDOW_MAX` samples), the swept bound v is a certified lower
        bound of every sample's distance: the window's entries are raised to it; when v - need >= D_i / 2 for
        every piece i of the window, each is covered (the cover's test, s_i + s_{i+1} >= D_i). A window that
        does not cover is halved at once; when even the shortest fails, no window is tried again from a
        sample inside it; and none twice from the same sample. Returns whether the window from k was covered.
        """
        w = self._window.get(t, MIN_SWEPT_RUN * 4)
        if k < self._no_sweep.get(t, 0) or (k, t) in self._swept_from:
            return False
        self._swept_from.add((k, t))
        while True:
            j = min(self.n - 1, k + w - 1)
            if j - k + 1 < MIN_SWEPT_RUN:
                return False
            v = self.swept_at(k, j, t)
            seg, st = lower[k : j + 1, t], state[k : j + 1, t]
            np.maximum(seg, v, out=seg)  # a certified bound of every sample of the window, whatever it proves
            if v - need >= 0.5 * float(np.max(self.reach[k:j, t])):
                st[st == SPREAD] = BOUND
                self._window[t] = min(2 * w, SWEPT_WINDOW_MAX)
                return True
            if w <= MIN_SWEPT_RUN:  # not even the shortest window: the probes, sample by sample, to its end
                self._window[t] = MIN_SWEPT_RUN
                self._no_sweep[t] = j + 1
                return False
            w //= 2

    def _cover_column(self, t: int, need: float, left: BoolArray) -> None:
        """:func:`~planner.collision.kernels.along.cover_walk` for one task whose bounds are all evaluated.

        Piece k is covered when s_k, s_{k+1} >= 0 and s_k + s_{k+1} >= D_k (s = lower - need); an uncovered
        piece gets probes at its start, then its end, then exact distances (each spread along the column),
        and a piece still uncovered with exact distances at both ends is marked in ``left``.
        """
        col, st, reach = self.lower[:, t], self.state[:, t], self.reach[:, t]
        k = 0
        while k < self.n - 1:
            a = col[k:-1] - need
            b = col[k + 1 :] - need
            bad = ~((a >= 0.0) & (b >= 0.0) & (a + b >= reach[k:]))
            if not bad.any():
                return
            k += int(np.argmax(bad))
            if st[k] == SPREAD or st[k + 1] == SPREAD:  # fine bounds for a block of samples at once
                block = np.arange(k, min(k + FINE_BLOCK, self.n))
                self._obstacle_bounds(block[st[block] == SPREAD].astype(np.int64), t)
                continue
            s = -1
            for level in (PROBED, EXACT):
                if st[k] < level:
                    s = k
                    break
                if st[k + 1] < level:
                    s = k + 1
                    break
            if s < 0:
                left[k] = True
                k += 1
                continue
            if st[s] < PROBED:
                if not self._swept_cover(s, t, need, self.lower, self.state):
                    self.probe_at(s, t, need)
            else:
                self.exact_at(s, t)
            self._spread(s, t, float(col[s]), need)

    # ---------------------------------------------------------------- figure
    def clearance(
        self,
        tolerance_m: float = CLEARANCE_TOL_M,
        max_exact: int = MAX_EXACT_QUERIES,
        cap_m: float = np.inf,
        allowed: bool = False,
    ) -> ClearanceAlong:
        """The exact minimum distance over the samples (branch and bound) and the bound between samples.

        It starts from the bounds the certificate proved (:meth:`certify`), spread along each column by the
        sample-to-sample bound (the samples' own certified bounds are evaluated where a run comes down to a
        few samples). An entry is *open* while its bound is below
        the best exact distance found (or ``cap_m``, a smaller figure found elsewhere) minus
        ``tolerance_m``. Each task's runs of open samples are then settled best first (smallest bound
        first): a run of at least :data:`MIN_SWEPT_RUN` samples by one swept-hull bound (:mod:`.sweep`:
        exact for a body translating on a line, a carriage along its rail), halved while it does not
        settle; a shorter run sample by sample, by an FCL probe on the body grown to the floor (a collision
        query) and, where the probe touches, the exact distance. At most ``max_exact`` distance queries
        (exact and swept) and :data:`MAX_PROBES` probes in all; what they leave open is reported as the
        tolerance reached (never a tolerance not proven). Last, up to :data:`POLISH_QUERIES` exact distances
        where the smallest bounds left are, so that the figure is most often the minimum itself.

        ``allowed``: the figure of the world's allowed pairs instead (their own report).
        """
        lower, state = self.lower, self.state
        sel = np.zeros(lower.shape[1], dtype=bool)
        if allowed:
            sel[self.n_checked :] = True
        else:
            sel[: self.n_checked] = True
        cols = np.flatnonzero(sel)
        if len(cols) == 0:
            return ClearanceAlong(np.inf, np.inf, 0, ("", ""), 0, self.queries, 0.0)
        self._propagate(cols)  # what the certificate proved, spread along each column
        exact = (state == EXACT) & sel[None, :]
        if not exact.any():
            masked = np.where(sel[None, :], lower, np.inf)
            k0, t0 = np.unravel_index(int(np.argmin(masked)), lower.shape)
            self.exact_at(int(k0), int(t0))
            exact = (state == EXACT) & sel[None, :]
        flat_best = int(np.argmin(np.where(exact, lower, np.inf)))
        best_k, best_t = flat_best // lower.shape[1], flat_best % lower.shape[1]
        best = float(lower[best_k, best_t])
        budget, probes = max_exact, MAX_PROBES
        futile = np.zeros(lower.shape[1], dtype=bool)
        tries, hits = np.zeros(lower.shape[1], dtype=np.int64), np.zeros(lower.shape[1], dtype=np.int64)

        def floor_now() -> float:
            return min(best, cap_m) - tolerance_m

        heap: list[tuple[float, int, int, int]] = []
        floor = floor_now()
        for t in cols.tolist():
            open_t = (lower[:, t] < floor) & (state[:, t] != EXACT)
            for i, j in _runs(open_t):
                heapq.heappush(heap, (float(np.min(lower[i : j + 1, t])), t, i, j))
        tried: set[tuple[int, int, int]] = set()
        while heap and (budget > 0 or probes > 0):
            _, t, i, j = heapq.heappop(heap)
            floor = floor_now()
            seg = lower[i : j + 1, t]
            opn = np.flatnonzero((seg < floor) & (state[i : j + 1, t] != EXACT))
            if len(opn) == 0:
                continue
            i, j = i + int(opn[0]), i + int(opn[-1])
            opn = opn - opn[0]  # relative to the trimmed run
            n_run = j - i + 1
            if n_run >= MIN_SWEPT_RUN:
                if (t, i, j) not in tried and budget > 0:
                    tried.add((t, i, j))
                    v = self.swept_at(i, j, t)
                    budget -= 1
                    seg = lower[i : j + 1, t]
                    seg[:] = np.where(state[i : j + 1, t] == EXACT, seg, np.maximum(seg, v))
                    opn = np.flatnonzero((seg < floor) & (state[i : j + 1, t] != EXACT))
                    if len(opn) and budget > 0:
                        # Still open: the exact distance where the bound is smallest (on a flat minimum the
                        # hull's distance is attained there, and the run then settles).
                        k = i + int(opn[np.argmin(seg[opn])])
                        d = self.exact_at(k, t)
                        budget -= 1
                        if d < best:
                            best, best_k, best_t = d, k, t
                        self._spread(k, t, d, floor_now())
                    if not np.any((seg < floor_now()) & (state[i : j + 1, t] != EXACT)):
                        continue
                m = (i + j) // 2  # what is still open, in halves (each trimmed to its open samples)
                for a, b in ((i, m), (m + 1, j)):
                    heapq.heappush(heap, (float(np.min(lower[a : b + 1, t])), t, a, b))
                continue
            rows = i + opn[state[i + opn, t] == SPREAD]
            if len(rows):  # the samples' own bounds first (one call for every kernel task / the body)
                if t < self.n_kernel:
                    self._bounds(rows.astype(np.int64))
                else:
                    self._obstacle_bounds(rows.astype(np.int64), t)
                heapq.heappush(heap, (float(np.min(lower[i : j + 1, t])), t, i, j))
                continue
            # A short run: sample by sample, smallest bound first.
            ks = i + opn[np.argsort(lower[i + opn, t], kind="stable")]
            for k in ks.tolist():
                floor = floor_now()
                if lower[k, t] >= floor or state[k, t] == EXACT:
                    continue
                if probes > 0 and not futile[t]:
                    probes -= 1
                    tries[t] += 1
                    if self.probe_at(k, t, floor, levels=(0.0,)):
                        continue
                    hits[t] += 1
                    # A body whose grown box keeps touching where its distance is not below the floor (a
                    # box's grown corners overstate the growth): its probes prove nothing.
                    futile[t] = hits[t] >= 32 and hits[t] >= 0.8 * tries[t]
                if budget <= 0:
                    continue
                d = self.exact_at(k, t)
                budget -= 1
                if d < best:
                    best, best_k, best_t = d, k, t
                self._spread(k, t, d, floor_now())
        # Polish: the exact distance where the smallest bounds left are (within the tolerance, the true
        # minimum is most likely there), so the figure is more often the minimum itself.
        # (An exact query writes its own entry only: the others' bounds stay as they are between queries.)
        remaining = np.where((state != EXACT) & sel[None, :], lower, np.inf)
        for _ in range(POLISH_QUERIES):
            flat_k = int(np.argmin(remaining))
            k, t = flat_k // lower.shape[1], flat_k % lower.shape[1]
            if not remaining[k, t] < best:
                break
            d = self.exact_at(k, t)
            remaining[k, t] = np.inf
            if d < best:
                best, best_k, best_t = d, k, t
        reached = max(tolerance_m, best - float(np.min(remaining)))
        # Between samples: on each piece the larger of (a + b - D) / 2 and max(a, b) - D (compiled).
        between, kb = self._kernels.between_bound(lower, self.reach, cols.astype(np.int64))
        bound = min(between, best)
        return ClearanceAlong(
            best, bound, int(best_k), self.task_name(int(best_t)), kb, self.queries, reached
        )

    def allowed_clearance(self, tolerance_m: float = CLEARANCE_TOL_M) -> ClearanceAlong | None:
        """The figure of the world's allowed (body, obstacle) pairs over the samples (None: there are none).

        As :meth:`clearance`, on the allowed pairs' columns only: they are left out of the certificate and
        of the path's figure, and reported on their own.
        """
        if self.n_checked == self.lower.shape[1]:
            return None
        return self.clearance(tolerance_m, allowed=True)

    def _spread(self, k: int, t: int, d: float, floor: float) -> None:
        """Raise column t around sample k to d - |C(j) - C(k)| where that is above ``floor``."""
        if d <= floor:
            return
        col, cum = self.lower[:, t], self.cum[:, t]
        ck = cum[k]
        lo = int(np.searchsorted(cum, ck - (d - floor), side="left"))
        hi = int(np.searchsorted(cum, ck + (d - floor), side="right"))
        seg = slice(lo, hi)
        np.maximum(col[seg], d - np.abs(cum[seg] - ck), out=col[seg])
        col[k] = d


def _runs(mask: BoolArray) -> list[tuple[int, int]]:
    """The maximal runs [i, j] (inclusive) of True in a boolean vector."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))
