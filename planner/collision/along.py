"""A sampled path in one batched pass: certified clearance along the whole polyline, and its true minimum.

The path is the polyline through N joint samples q_0..q_{N-1} (straight joint-space pieces between
consecutive samples, as :meth:`~planner.collision.world.CollisionWorld.check_path` certifies it). A *task*
is one body against the cabin or one checked pair of bodies; for task t, d_t(q) is its exact distance.

One compiled call (:func:`~planner.collision.kernels.along.bounds_along`) gives, at every sample, the body
poses, the admissibility values and a certified lower bound L[k, t] <= d_t(q_k) of every task (sphere
covers on the cabin's clearance grid; pairs by their covers, exact for capsules). Along piece k no point of
a body moves more than D[k, t] = rho_t . |q_{k+1} - q_k| (the reach bounds of
:mod:`planner.collision.bodies` with the slope bound of the whole path, pairs by their relative reach), so
d_t is 1-Lipschitz in the cumulative reach C_t (C_t(q_0) = 0, growing by D[k, t] along piece k). Hence:

* an exact distance d at sample k bounds every other sample: L[j, t] >= d - |C_t(j) - C_t(k)| (the bounds
  are propagated both ways by running maxima, :meth:`AlongPath.refine`);
* on piece k, d_t >= max((L_k + L_{k+1} - D) / 2, max(L_k, L_{k+1}) - D) (two cones meeting), the lower
  bound *between* samples;
* piece k keeps ``need`` (the clearance plus the walk's margin) everywhere when L_k, L_{k+1} >= need and
  (L_k - need) + (L_{k+1} - need) >= D[k, t]: the spare clearance proven at its two ends covers it.

:meth:`AlongPath.certify` proves every piece so in one compiled walk
(:func:`~planner.collision.kernels.along.cover_walk`): bounds on demand where the spare clearance proven
so far runs out (a body far from the cabin keeps its spare over many samples), and FCL exact distances
(tens of microseconds for a box against the cabin) only where the bounds fall short, as the motion walk
does; a piece whose two exact end distances still cannot cover it is walked by the world's
certified motion check (:meth:`~planner.collision.world.CollisionWorld.check_motion`), which decides.
It is never weaker than ``check_path``: what it certifies keeps ``clearance + margin`` everywhere.
:meth:`AlongPath.clearance` then finds the exact minimum of the sample distances by branch and bound on
the same bounds, and the certified lower bound between samples.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
from planner.collision.probes import Probes
from planner.collision.reports import BodyState, Contact, MotionReport, limit_contacts
from planner.core.types import Array, IntArray
from planner.robots.geometry import CollisionModel

#: The exact minimum over the samples is found to within this [m]: every sample's exact distance is at
#: least the reported one minus it (the bounds stop the search there; the reported value itself is an
#: exact FCL distance at a real sample).
CLEARANCE_TOL_M = 1e-4
#: Exact distance queries the figure may spend (~0.5 ms each near a wall); where the distance is flat over
#: more samples than this (a carriage along a straight rail) the tolerance reached is reported instead.
MAX_EXACT_QUERIES = 300
#: The exact distances of the figure go to every this-many-th open sample first.
EXACT_STRIDE = 8
#: Collision probes the figure may spend (~10 us each).
MAX_PROBES = 20_000
#: The figure's bounds are evaluated at every this-many-th sample up front (the rest on demand).
BOUND_STRIDE = 4
#: Spare clearances [m] beyond the clearance plus margin an FCL probe on the grown body tries to prove, the
#: largest first (a collision query costs ~10 us; an exact distance to a nearby wall ~0.5 ms).
PROBE_LEVELS = (0.016, 0.004, 0.001, 0.0)


@dataclass(frozen=True)
class AlongReport:
    """Result of :meth:`AlongPath.certify`: the polyline keeps the clearance everywhere, or where not.

    Attributes:
        valid: Every piece certified (limits at every sample and every ``LIMIT_STEP`` within pieces).
        exact_queries: FCL distance queries the certificate needed.
        walked: Pieces the bounds could not cover, handed to the certified motion walk.
        first_bad: The sample starting the first piece that failed (None if valid).
        contacts: Why it failed.
    """

    valid: bool
    exact_queries: int
    walked: int
    first_bad: int | None = None
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class ClearanceAlong:
    """The smallest distance of a path: exact over every sample, certified between samples.

    Attributes:
        distance_m: Exact FCL distance at ``sample`` for ``bodies``: no sample's exact distance of any
            body to the cabin, or between two checked bodies, is below it by more than ``tolerance_m``.
        bound_m: Certified lower bound of every distance along the polyline through the samples (between
            samples included), <= ``distance_m``.
        sample: The sample of ``distance_m``.
        bodies: The body and ``"cabin"``, or the two bodies, of ``distance_m``.
        bound_sample: The sample starting the piece where ``bound_m`` is smallest.
        exact_queries: FCL distance queries the search needed.
        tolerance_m: No sample's exact distance is below ``distance_m`` by more than this (the requested
            tolerance, or what the query budget reached where the distances are flat over many samples).
    """

    distance_m: float
    bound_m: float
    sample: int
    bodies: tuple[str, str]
    bound_sample: int
    exact_queries: int
    tolerance_m: float


class AlongPath:
    """The bounds of a sampled path and its certified pieces (see the module docstring).

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
            margin)``.
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
    ) -> None:
        self.q = qs
        self.poses = poses
        self.c = c
        self.model = model
        self.bodies = bodies
        self.probes = probes
        self._kernels, self._data, self._threshold = kernels
        self._walk = walk
        self.n = len(qs)
        self.n_cabin = len(bodies.names) if has_cabin else 0
        n_tasks = self.n_cabin + len(bodies.pairs)
        #: Lower bounds (N, T) of every task (cabin tasks first, then pairs); raised as evidence comes.
        self.lower = np.full((self.n, n_tasks), -np.inf)
        #: What each entry of ``lower`` is: ``SPREAD`` (only what other samples imply), ``BOUND``, ``EXACT``.
        self.state = np.zeros((self.n, n_tasks), dtype=np.int64)
        self.queries = 0
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
        #: Reach (N - 1, T): how far any point of a task's bodies (pairs: relative) moves along each piece.
        self.reach = np.ascontiguousarray(dq @ np.concatenate(cols, axis=0).T)
        #: Cumulative reach (N, T).
        self.cum = np.ascontiguousarray(np.vstack([np.zeros((1, n_tasks)), np.cumsum(self.reach, axis=0)]))

    # ---------------------------------------------------------------- bounds
    def _propagate(self, cols: IntArray) -> None:
        """Raise columns ``cols`` to max_k (lower[k] - |C(j) - C(k)|) at every j (running maxima)."""
        v, cum = self.lower[:, cols], self.cum[:, cols]
        fwd = np.maximum.accumulate(v + cum, axis=0) - cum
        bwd = np.flip(np.maximum.accumulate(np.flip(v - cum, axis=0), axis=0), axis=0) + cum
        self.lower[:, cols] = np.maximum(v, np.maximum(fwd, bwd))

    def _bounds(self, rows: IntArray) -> None:
        """Evaluate the certified bounds of every task at samples ``rows`` (one kernel call)."""
        cabin, pairs = self._kernels.bounds_at(rows, self.poses, self.c, self._data, self._threshold)
        values = np.concatenate([cabin, pairs], axis=1) if self.n_cabin else pairs
        fresh = self.state[rows] == SPREAD
        self.lower[rows] = np.where(fresh, np.maximum(self.lower[rows], values), self.lower[rows])
        self.state[rows] = np.where(fresh, BOUND, self.state[rows])

    def task_name(self, t: int) -> tuple[str, str]:
        """(body, "cabin") or (body a, body b) of task t."""
        names = self.bodies.names
        if t < self.n_cabin:
            return names[t], "cabin"
        a, b = self.bodies.pairs[t - self.n_cabin]
        return names[a], names[b]

    def probe_at(self, k: int, t: int, need: float, levels: tuple[float, ...] | None = None) -> bool:
        """Raise the bound of task t at sample k by FCL collision probes on the body grown by ``need + E``.

        E in :data:`PROBE_LEVELS` (the largest first); a grown body that does not touch the cabin (a pair
        whose bodies, each grown by half, do not touch) proves the distance is at least its growth. Returns
        whether some level was proven. Cheaper than an exact distance by tens of times near a wall.
        """
        self.state[k, t] = max(self.state[k, t], PROBED)
        is_cabin = t < self.n_cabin
        idx = t if is_cabin else t - self.n_cabin
        nc = self.n_cabin
        st = BodyState(self.poses[k], self.lower[k, :nc], self.lower[k, nc:])  # only the poses are read
        for level in PROBE_LEVELS if levels is None else levels:
            if need + level <= self.lower[k, t]:
                return True
            self.probes_used += 1
            if not self.probes.hit(st, is_cabin, idx, need + level):
                self.lower[k, t] = need + level
                return True
        return False

    def exact_at(self, k: int, t: int) -> float:
        """The exact distance of task t at sample k (one FCL distance query, once); written to ``lower``.

        An exact distance replaces the bound: were it below (rounding between FCL and the bounds'
        arithmetic), the smaller value is kept, so nothing reported is above what FCL measured.
        """
        if self.state[k, t] == EXACT:
            return float(self.lower[k, t])
        is_cabin = t < self.n_cabin
        idx = t if is_cabin else t - self.n_cabin
        nc = self.n_cabin
        st = BodyState(self.poses[k], self.lower[k, :nc], self.lower[k, nc:])  # only the poses are read
        d = float(self.probes.distance(st, is_cabin, idx)[0])
        self.queries += 1
        self.state[k, t] = EXACT
        self.lower[k, t] = d
        return d

    # ---------------------------------------------------------- certificate
    def certify(self, clearance: float, self_clearance: float, margin: float) -> AlongReport:
        """Certify that every piece keeps ``clearance`` (pairs ``self_clearance``) plus ``margin`` everywhere.

        Limits and margins: at every sample (the batched c(q)); a piece longer than ``LIMIT_STEP`` in any
        joint is walked (the motion check samples it every ``LIMIT_STEP``). Collision: each task's pieces
        are covered by the spare clearance proven at their ends (bounds, then exact distances); the rest are
        walked by the certified motion check, which decides.
        """
        lo, hi = self.model.admissibility.c_lower, self.model.admissibility.c_upper
        bad = ~np.all((self.c >= lo[None, :]) & (self.c <= hi[None, :]), axis=1)
        if bad.any():
            k = int(np.argmax(bad))
            contacts = tuple(limit_contacts(self.model.admissibility, self.q[k]))
            return AlongReport(False, self.queries, 0, max(0, k - 1), contacts)
        left = np.max(np.abs(np.diff(self.q, axis=0)), axis=1) > LIMIT_STEP
        need = np.array([clearance] * self.n_cabin + [self_clearance] * len(self.bodies.pairs)) + margin
        ci = np.zeros(CW_SIZE, dtype=np.int64)
        ci[CW_PENDING] = -1
        k_ = self._kernels
        args = (self._data, self._threshold, self.cum, self.reach, self.lower, self.state, left)
        while k_.cover_walk(ci, need, self.n_cabin, self.poses, *args) == COVER_EXACT:
            k, t = int(ci[CW_K]), int(ci[CW_TASK])
            if self.state[k, t] < PROBED:
                self.probe_at(k, t, float(need[t]))
            else:
                self.exact_at(k, t)
        walked = 0
        for k in np.flatnonzero(left).tolist():
            rep = self._walk(k, clearance, self_clearance, margin)
            walked += 1
            if not rep.valid:
                return AlongReport(False, self.queries, walked, k, rep.contacts)
        return AlongReport(True, self.queries, walked)

    # ---------------------------------------------------------------- figure
    def clearance(
        self, tolerance_m: float = CLEARANCE_TOL_M, max_exact: int = MAX_EXACT_QUERIES
    ) -> ClearanceAlong:
        """The exact minimum distance over the samples (branch and bound) and the bound between samples.

        The certified bounds at every :data:`BOUND_STRIDE`-th sample (one kernel call), spread to the
        others along the cumulative reach. Then, in rounds, every entry whose bound is below the best exact
        distance found minus ``tolerance_m`` gets its sample's bounds (one kernel call for all), an FCL
        probe on the body grown by that much (a collision query, which clears most), and, smallest bound
        first, the exact distance where the probe touches -- at most ``max_exact`` of them in all, after
        which the tolerance reached is reported instead (likewise after :data:`MAX_PROBES` probes).
        """
        lower, state = self.lower, self.state
        strided = np.unique(np.r_[np.arange(0, self.n, BOUND_STRIDE), self.n - 1]).astype(np.int64)
        self._bounds(strided[(state[strided] == SPREAD).any(axis=1)])
        self._propagate(np.arange(lower.shape[1]))
        exact = state == EXACT
        if not exact.any():
            k, t = np.unravel_index(int(np.argmin(lower)), lower.shape)
            self.exact_at(int(k), int(t))
            exact = state == EXACT
        best_k, best_t = np.unravel_index(int(np.argmin(np.where(exact, lower, np.inf))), lower.shape)
        best = float(lower[best_k, best_t])
        budget, probes = max_exact, MAX_PROBES
        n_tasks = lower.shape[1]
        tries, hits = np.zeros(n_tasks, dtype=np.int64), np.zeros(n_tasks, dtype=np.int64)
        futile = np.zeros(n_tasks, dtype=bool)
        while True:
            floor = best - tolerance_m
            open_ = (lower < floor) & (state != EXACT)
            if not open_.any():
                break
            rows = np.flatnonzero((open_ & (state == SPREAD)).any(axis=1))
            if len(rows):  # the samples' own bounds, all in one call
                self._bounds(rows.astype(np.int64))
                continue
            probing = open_ & (state == BOUND) & ~futile[None, :]
            ks, ts = np.nonzero(probing)
            if len(ks) and probes > 0:  # one collision query each on the body grown to the floor
                order = np.argsort(lower[ks, ts])[:probes]
                probes -= len(order)
                for k, t in zip(ks[order].tolist(), ts[order].tolist(), strict=True):
                    if futile[t] or lower[k, t] >= floor:
                        continue
                    tries[t] += 1
                    if self.probe_at(k, t, floor, levels=(0.0,)):
                        self._spread(k, t, float(lower[k, t]), floor)
                    else:
                        hits[t] += 1
                        # A body whose grown box keeps touching where its distance is not below the floor
                        # (a box's grown corners overstate the growth): its probes prove nothing.
                        futile[t] = hits[t] >= 32 and hits[t] >= 0.8 * tries[t]
                continue
            if budget <= 0:
                break
            ks, ts = np.nonzero(open_)
            # Coarse to fine: every EXACT_STRIDE-th open sample first (the distance is smooth, so the best
            # found soon comes near the minimum), smallest bound first within each pass.
            coarse = (ks % EXACT_STRIDE) != 0
            order = np.lexsort((lower[ks, ts], coarse))[:budget]
            for k, t in zip(ks[order].tolist(), ts[order].tolist(), strict=True):
                if lower[k, t] >= best - tolerance_m:
                    continue
                d = self.exact_at(k, t)
                budget -= 1
                if d < best:
                    best, best_k, best_t = d, k, t
                self._spread(k, t, d, best - tolerance_m)
        remaining = np.where(state != EXACT, lower, np.inf)
        reached = max(tolerance_m, best - float(np.min(remaining)))
        a, b = lower[:-1], lower[1:]
        between = np.maximum(0.5 * (a + b - self.reach), np.maximum(a, b) - self.reach)
        kb = int(np.argmin(np.min(between, axis=1)))
        bound = min(float(np.min(between)), best)
        return ClearanceAlong(
            best, bound, int(best_k), self.task_name(int(best_t)), kb, self.queries, reached
        )

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
