"""The reference route of the collision world: the tests' oracle and the benchmark's baseline.

:class:`ReferenceWorld` answers every question of :class:`~planner.collision.world.CollisionWorld` by the
original, independent routes -- poses from the robot model's CasADi function
(``CollisionModel.pose_functions``), the certified motion walk in plain Python with the original always-probe
policy, the lower bounds also vectorised in numpy (:meth:`ReferenceWorld.cabin_lower_bounds`,
:meth:`ReferenceWorld.pair_lower_bounds`, the obstacles' by :class:`ReferenceObstacles`) -- and must give
the compiled route's verdicts and reports exactly (tests/collision/test_kernels.py,
tests/collision/test_obstacles.py). It is not used by the planner.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from planner.collision.bodies import BodySet, segment_reach_bounds
from planner.collision.kernels.bounds import state_bounds
from planner.collision.kernels.codes import MAX_LEVELS
from planner.collision.motion import Walk, limit_samples
from planner.collision.obstacles import Obstacle, ObstacleSet
from planner.collision.reports import BodyState, MotionReport, StateReport, body_contact, limit_contacts
from planner.collision.world import DEFAULT_CLEARANCE_M, CollisionWorld
from planner.core.types import Array, IntArray
from planner.kinematics import chain


def _rows_times(local: Array, M: Array) -> Array:
    """Local (S, 3) times each M (n, 3, 3): (n, S, 3), written out (no threaded BLAS call for 3 x 3)."""
    return (
        local[None, :, 0, None] * M[:, None, 0, :]
        + local[None, :, 1, None] * M[:, None, 1, :]
        + local[None, :, 2, None] * M[:, None, 2, :]
    )


class ReferenceObstacles(ObstacleSet):
    """:class:`ObstacleSet` with its lower bounds vectorised in numpy (the compiled kernels' reference).

    The bounds of :mod:`planner.collision.kernels.obstacles` by whole-array operations, summed in the same
    order; probes, exact distances and swept hulls by FCL (the obstacle set's reference route).
    """

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        bodies: BodySet,
        allowed: frozenset[tuple[str, str]] = frozenset(),
    ) -> None:
        super().__init__(obstacles, bodies, allowed, compiled=False)  # FCL's probes and distances
        n_o = len(obstacles)
        bounds = [o.bound for o in obstacles]
        self._R_bound = np.array([T[:3, :3] for T, _ in bounds]).reshape(n_o, 3, 3)
        self._p_bound = np.array([T[:3, 3] for T, _ in bounds]).reshape(n_o, 3)
        self._half = np.array([h for _, h in bounds]).reshape(n_o, 3)
        self._origin_local = np.einsum("oi,oij->oj", self._p_bound, self._R_bound)  # p_o R_o (O, 3)
        self._sphere_body, self._local, self._frac = self._cover.table
        self._radii = self._cover.radii
        self._capsule = np.array([s.kind == "capsule" for s in bodies.shapes])
        self._capsule_r = np.array([s.radius for s in bodies.shapes])
        self._box_r = np.array([0.5 * float(np.linalg.norm(s.size)) for s in bodies.shapes])

    def _box_distance(self, points: Array) -> Array:
        """Distances (P, O) of points (P, 3) to every obstacle's bounding box (0 inside)."""
        # In each box's axes: (x - p_o) R_o = x R_o - p_o R_o, one batched product for all boxes.
        R = self._R_bound  # written out, not matmul: a threaded BLAS call costs more than these sums
        local = (
            points[None, :, 0, None] * R[:, None, 0, :]
            + points[None, :, 1, None] * R[:, None, 1, :]
            + points[None, :, 2, None] * R[:, None, 2, :]
            - self._origin_local[:, None, :]
        )  # (O, P, 3)
        outside = np.maximum(np.abs(local) - self._half[:, None, :], 0.0)
        return np.sqrt(np.sum(outside * outside, axis=2)).T

    def lower_bounds(self, flat: Array, threshold: float | Array = np.inf) -> Array:
        """:meth:`ObstacleSet.lower_bounds` in numpy."""
        out = self.coarse_bounds_batch(flat[None])[0]
        th = np.asarray(threshold, dtype=float)
        th = th.reshape(-1, 1) if th.ndim else th
        near = np.flatnonzero(np.any(out <= th, axis=1))
        for b in near.tolist():  # both bound the distance from below: keep the larger
            fine = self.fine_bounds_batch(flat[None], np.zeros(1, dtype=np.int64), b)[0]
            out[b] = np.where(self.active[b], np.maximum(out[b], fine), np.inf)
        return out

    def coarse_bounds_batch(self, poses: Array, allowed_too: bool = False) -> Array:
        """:meth:`ObstacleSet.coarse_bounds_batch` in numpy."""
        n, n_b = poses.shape[0], poses.shape[1]
        n_o = len(self.obstacles)
        length = poses[:, :, 12]
        capsule_r = self._capsule_r[None, :] + 0.5 * length
        radius = np.where(self._capsule[None, :], capsule_r, self._box_r[None, :])
        out = self._box_distance(poses[:, :, 9:12].reshape(-1, 3)).reshape(n, n_b, n_o) - radius[:, :, None]
        active = np.ones_like(self.active) if allowed_too else self.active
        return np.where(active[None], out, np.inf)

    def fine_bounds_batch(self, poses: Array, rows: IntArray, b: int) -> Array:
        """:meth:`ObstacleSet.fine_bounds_batch` in numpy."""
        poses_b = poses[rows, b]
        sel = np.flatnonzero(self._sphere_body == b)
        Rt = poses_b[:, :9].reshape(-1, 3, 3)  # R^T (column-major storage), (n, 3, 3)
        centres = (
            poses_b[:, None, 9:12]
            + _rows_times(self._local[sel], Rt)  # (R local)^T = local^T R^T
            + Rt[:, None, 2, :] * (self._frac[sel][None, :] * poses_b[:, 12][:, None])[..., None]
        )  # (n, S_b, 3)
        d = self._box_distance(centres.reshape(-1, 3)).reshape(len(poses_b), len(sel), len(self.obstacles))
        return np.min(d - self._radii[sel][None, :, None], axis=1)


class ReferenceWorld(CollisionWorld):
    """:class:`CollisionWorld` by the reference routes: same verdicts and reports, slower (same arguments)."""

    #: The original always-probe policy of the motion walk.
    probe_when_proven = True
    #: Every probe and distance through FCL: bodies against the cabin and the obstacles, pairs of bodies.
    compiled_tests = False

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.obstacles is not None:  # the obstacles' bounds in numpy
            obs = self.obstacles
            self.obstacles = ReferenceObstacles(obs.obstacles, self.bodies, obs.allowed)

    @cached_property
    def _pair_spheres(self) -> tuple[IntArray, IntArray, Array, list[IntArray]]:
        """Every sphere pair of every checked body pair, grouped by body pair: (ia, ib, rsum, groups)."""
        coarse = self._kernel.coarse
        counts = np.diff(coarse.bounds)
        ia, ib = [], []
        for a, b in self.bodies.pairs:
            ga, gb = np.meshgrid(
                np.arange(coarse.start[a], coarse.start[a] + counts[a]),
                np.arange(coarse.start[b], coarse.start[b] + counts[b]),
                indexing="ij",
            )
            ia.append(ga.ravel())
            ib.append(gb.ravel())
        bounds = np.concatenate([[0], np.cumsum([len(x) for x in ia])]).astype(int)
        pair_ia = np.concatenate(ia) if ia else np.zeros(0, dtype=int)
        pair_ib = np.concatenate(ib) if ib else np.zeros(0, dtype=int)
        groups = [np.arange(bounds[k], bounds[k + 1]) for k in range(len(self.bodies.pairs))]
        return pair_ia, pair_ib, coarse.radii[pair_ia] + coarse.radii[pair_ib], groups

    # ------------------------------------------------------------------ poses
    def _evaluate(self, q: Array) -> tuple[Array, Array]:
        """Poses by the CasADi function, which evaluates column-wise when given N stacked columns."""
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        if q2.shape[0] == 1:
            return super()._evaluate(q2)
        outs = self._pose_fn(ca.DM(q2.T), ca.DM(self._T_tool_box))
        flat, c = (np.asarray(o.full(), dtype=float).T for o in outs)
        return np.ascontiguousarray(flat.reshape(q2.shape[0], self._n_bodies, 13)), c

    def flat_poses(self, q: Array) -> Array:
        """Poses by the CasADi function."""
        return self._evaluate(q)[0][0]

    def _state(self, q: Array, threshold: float = DEFAULT_CLEARANCE_M) -> BodyState:
        """Poses by the CasADi function, then the bound kernel."""
        slot = self._pose_fast._slot()  # shared by every world of this model: the payload box each time
        slot.args[1][:] = self._T_tool_box.ravel(order="F")
        slot.args[0][:] = q
        slot.trigger()
        flat = slot.res[0].reshape(self._n_bodies, 13).copy()
        d = self._kernel
        cabin, pairs, ok = state_bounds(flat, slot.res[1].copy(), d.fbuf, d.ibuf, d.grid, threshold)
        return BodyState(flat, cabin, pairs, ok)

    def cabin_lower_bounds(self, fine_centres: Array, d1: Array) -> Array:
        """(N, B) certified lower bound of each body's distance to the cabin (inf without a cabin).

        From the fine sphere cover and the clearance grid; for the rail body (cabin8: the carriage), which
        moves with d1 only, also from its exact clearance table along the rail (whichever bound is larger).
        """
        n = fine_centres.shape[0]
        if self._grid is None:
            return np.full((n, self._n_bodies), np.inf)
        fine = self._kernel.fine
        lb = self._grid.query(fine_centres) - fine.radii[None, :]
        out = np.minimum.reduceat(lb, np.minimum(fine.start, lb.shape[1] - 1), axis=1)
        out[:, np.diff(fine.bounds) == 0] = np.inf  # reduceat returns an element for an empty group
        if self._carriage_table is not None:
            z0, dz, table = self._carriage_table
            k = np.clip(np.rint((d1 - z0) / dz).astype(int), 0, len(table) - 1)
            exact = table[k] - np.abs(d1 - (z0 + k * dz))
            carriage = self.names.index(self.model.rail_body)  # the table exists only for a rail body
            current = out[:, carriage]
            out[:, carriage] = np.where(np.isinf(current), exact, np.maximum(current, exact))
        return out

    def pair_lower_bounds(self, centres: Array, threshold: float) -> Array:
        """(N, P) certified lower bound of the distance between the bodies of each checked pair.

        First the separation of the bodies' boxes (from their coarse sphere covers) along the axes; where
        that is not above ``threshold`` for some state, also the sphere-cover gap (the larger bound counts).
        """
        n = centres.shape[0]
        pair_a, pair_b = self._kernel.pair_a, self._kernel.pair_b
        if len(pair_a) == 0:
            return np.full((n, 0), np.inf)
        coarse = self._kernel.coarse
        r = coarse.radii[None, :, None]
        lo = np.minimum.reduceat(centres - r, coarse.start, axis=1)
        hi = np.maximum.reduceat(centres + r, coarse.start, axis=1)
        sep = np.maximum(lo[:, pair_b] - hi[:, pair_a], lo[:, pair_a] - hi[:, pair_b])
        out = np.max(sep, axis=2)
        close = np.flatnonzero(np.any(out <= threshold, axis=0))
        if close.size:
            pair_ia, pair_ib, rsum, groups = self._pair_spheres
            idx = np.concatenate([groups[k] for k in close])
            starts = np.concatenate([[0], np.cumsum([len(groups[k]) for k in close])[:-1]])
            ia, ib = pair_ia[idx], pair_ib[idx]
            gap = np.linalg.norm(centres[:, ia] - centres[:, ib], axis=2) - rsum[idx][None, :]
            out[:, close] = np.maximum(out[:, close], np.minimum.reduceat(gap, starts, axis=1))
        return out

    # --------------------------------------------------------------- checks
    def _screen(self, q: Array, clearance: float) -> StateReport | BodyState:
        if not np.all(np.isfinite(q)):
            return StateReport(False, tuple(limit_contacts(self.model.admissibility, q)))
        return self._state(q, self.self_clearance)

    def is_valid(self, q: Array, clearance: float = DEFAULT_CLEARANCE_M) -> bool:
        """The verdict of :meth:`check_state`."""
        return self.check_state(q, clearance).valid

    def _carriage_clearance(self, d1_a: float, d1_b: float) -> float:
        """Certified carriage-to-cabin clearance for every d1 between d1_a and d1_b (table minimum)."""
        assert self._carriage_table is not None
        z0, dz, table = self._carriage_table
        lo, hi = sorted((d1_a, d1_b))
        k0 = int(np.clip(np.floor((lo - z0) / dz), 0, len(table) - 1))
        k1 = int(np.clip(np.ceil((hi - z0) / dz), 0, len(table) - 1))
        if lo < z0 or hi > z0 + dz * (len(table) - 1):
            return -np.inf
        # Every d1 in [lo, hi] is within dz/2 of a sample in k0..k1; the distance is 1-Lipschitz in d1.
        return float(table[k0 : k1 + 1].min()) - 0.5 * dz

    def _segment_reach(self, q_a: Array, q_b: Array, ratio: float | None = None) -> tuple[Array, Array]:
        """Reach bounds valid along the straight segment q_a -> q_b (``CollisionModel.slope_deviation``)."""
        model = self.model
        rows = list(model.ratio_rows)
        c = model.admissibility.constraint_values_batch(np.stack([q_a, q_b]))[:, rows]
        end = (float(np.nanmax(c)) if np.all(np.isfinite(c)) else 1.0) if rows else -np.inf
        if ratio is not None:
            end = max(end, ratio)
        return segment_reach_bounds(model, self.bodies, end + model.slope_deviation(q_a, q_b))

    def _walk(self, q_a: Array, q_b: Array, spec: Walk) -> MotionReport:
        """The motion walk of ``check_motion``: the cabin's and the pairs' in Python, then the obstacles'."""
        rep = self._cabin_walk(q_a, q_b, spec)
        if not rep.valid or self.obstacles is None:
            return rep
        return self._obstacle_walk(q_a, q_b, spec.clearance, spec.floor, rep)

    def _cabin_walk(self, q_a: Array, q_b: Array, spec: Walk) -> MotionReport:
        """The cabin's and the pairs' walk in Python: the schedule the compiled walk follows."""
        clearance, motion_margin, own, ratio, floor = spec.values()
        dq = q_b - q_a
        rho, pair_rho = self._segment_reach(q_a, q_b, ratio)
        reach = rho @ np.abs(dq)
        n_fine = limit_samples(dq)
        t_fine = np.linspace(0.0, 1.0, n_fine + 1)
        qs = q_a[None, :] + t_fine[:, None] * dq[None, :]
        bad = ~self.model.admissibility.admissible_batch(qs)
        if bad.any():
            i = int(np.argmax(bad))
            contacts = tuple(limit_contacts(self.model.admissibility, qs[i]))
            return MotionReport(False, n_fine + 1, 0, float(t_fine[i]), contacts)
        probes = self._probes
        before = probes.queries
        tasks: list[tuple[bool, int, float]] = []
        if probes.has_cabin:
            tasks += [(True, b, float(reach[b])) for b in range(self._n_bodies)]
        pair_reach = pair_rho @ np.abs(dq)
        tasks += [(False, k, float(pair_reach[k])) for k in range(len(self.bodies.pairs))]
        # One schedule for all: spacing such that no body or pair moves more than motion_margin between
        # neighbouring states; each task's next check is snapped down onto it (a shorter step stays
        # certified).
        d_max = max((d for _, _, d in tasks), default=0.0)
        # Not capped: one schedule step must never exceed a proven step (at least ``floor`` of motion).
        n = int(max(1, np.ceil(d_max / floor)))

        def t_of(i: int) -> float:
            return i / n

        cache: dict[int, BodyState] = {}

        def state(i: int) -> BodyState:  # evaluated lazily: the walks visit few of the n + 1 states
            st = cache.get(i)
            if st is None:
                # Exact pair distances where they are small (beyond, the bounds allow long steps anyway).
                st = cache[i] = self._state(q_a + t_of(i) * dq, own + 0.06)
            return st

        def spare(st: BodyState, is_cabin: bool, idx: int, base: float) -> float:
            return float((st.cabin_lb[idx] if is_cabin else st.pair_lb[idx]) - base)

        rail = self.model.rail_body
        carriage = self.names.index(rail) if rail is not None else -1
        # Both end states: a task whose spare clearance at the two ends covers the segment from both sides
        # (free_0 / D + free_1 / D >= 1) needs nothing in between.
        s0, s1 = state(0), state(n)
        smallest = motion_margin  # the smallest margin any task stepped with
        for is_cabin, idx, D in tasks:
            base = clearance if is_cabin else own
            f0, f1 = spare(s0, is_cabin, idx, base), spare(s1, is_cabin, idx, base)
            if f0 >= motion_margin and f1 >= motion_margin and f0 + f1 >= D:
                continue
            if is_cabin and idx == carriage and self._carriage_table is not None:
                # The carriage moves with d1 only: its exact clearance table covers the whole segment.
                if self._carriage_clearance(q_a[chain.D1], q_b[chain.D1]) > clearance:
                    continue
            t_stop = 1.0 - f1 / D if f1 >= motion_margin and D > 0.0 else 1.0
            # ``local``: the margin the state must prove; ``prev``, ``e_prev``: the last state proven, its E.
            i, last, local, prev, e_prev = 0, motion_margin, motion_margin, -1, 0.0
            while True:
                st = state(i)
                free = spare(st, is_cabin, idx, base)
                E = free if free >= local else 0.0
                # Probe for more spare clearance than the bound proves (twice what held last time), then fall
                # back level by level; where the bound proves a margin, only with ``probe_when_proven``.
                exact = not is_cabin and bool(self._kernel.exact_pair[idx])  # E is the exact spare clearance
                optimistic = D > 0.0 and not exact and (E == 0.0 or self.probe_when_proven)
                first = min(0.3, max(2.0 * last, 2.0 * E, 4.0 * local))
                trials = [first] if optimistic and first > E else []
                if E == 0.0 and not exact:
                    # Then the level proven last time halved down to the margin, strictly decreasing (a
                    # level at or above one that hit would hit too), at most MAX_LEVELS in all.
                    level = max(last, 2.0 * local)
                    while level > local and len(trials) < MAX_LEVELS - 1:
                        if level < (trials[-1] if trials else np.inf):
                            trials.append(level)
                        level *= 0.5
                    if local < (trials[-1] if trials else np.inf):
                        trials.append(local)
                for level in trials:
                    if not probes.hit(st, is_cabin, idx, base + level):
                        E = level
                        break
                if E == 0.0 and not exact:  # every grown body hit: the exact distance decides
                    exact_spare = probes.distance(st, is_cabin, idx)[0] - base
                    E = exact_spare if exact_spare >= local else 0.0
                last = max(E, local)
                if E == 0.0:
                    if local <= floor:
                        contact = body_contact(self.names, self.bodies.pairs, is_cabin, idx, base + local)
                        queries = probes.queries - before
                        return MotionReport(False, len(cache), queries, t_of(i), (contact,), smallest)
                    # Halve the margin and step again from the last proven state (or ask the first again).
                    local = max(floor, 0.5 * local)
                    smallest = min(smallest, local)
                    if prev >= 0:
                        back = int(np.floor((t_of(prev) + (e_prev + local) / D) * n + 1e-9))
                        i = min(i, max(prev + 1, back))
                    continue
                prev, e_prev = i, E
                if E >= 2.0 * local:  # room again: back towards the walk's margin
                    local = min(motion_margin, 2.0 * local)
                # Done when the proven interval reaches the end state's own certified interval.
                if i == n or D <= 0.0 or t_of(i) + E / D >= t_stop:
                    break
                i = min(n, max(i + 1, int(np.floor((t_of(i) + (E + local) / D) * n + 1e-9))))
        return MotionReport(True, len(cache), probes.queries - before, smallest_margin_m=smallest)
