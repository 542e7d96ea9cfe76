"""The certified motion walk of :meth:`~planner.collision.world.CollisionWorld.check_motion`, compiled.

Along the straight joint-space segment q(t) = q_a + t (q_b - q_a): limits and margins at every joint step
of at most :data:`LIMIT_STEP`; reach bounds D (how far any point of a body, or a pair's relative
position, can move over the segment); then :func:`~planner.collision.kernels.walk.motion_walk`, which
advances each body and pair with certified steps (its proven spare clearance E over D) and returns here
only when a state needs FCL probes on a grown body (:class:`~planner.collision.probes.Probes`).
The pure-Python walk with the same schedule is :mod:`planner.collision.oracle` (the tests' oracle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.collision.bodies import BodySet
from planner.collision.kernels import codes as walk
from planner.collision.kernels.buffers import KernelData
from planner.collision.kernels.entries import Kernels
from planner.collision.probes import Probes
from planner.collision.reports import BodyState, MotionReport, body_contact, limit_contacts
from planner.core.types import Array
from planner.robots.geometry import CollisionModel

#: Joint-space spacing [m or rad] at which limits and singularity margins are checked along a motion.
LIMIT_STEP = 0.005


def limit_samples(dq: Array) -> int:
    """Number of pieces n of the limit samples t_i = i / n: joint steps of at most ``LIMIT_STEP``."""
    return int(min(10_000, max(1, np.ceil(float(np.abs(dq).max()) / LIMIT_STEP))))


@dataclass(frozen=True)
class Walk:
    """What one certified walk proves and how (see ``CollisionWorld.check_motion``).

    Attributes:
        clearance: The clearance every body keeps from the cabin [m].
        margin: The margin every state proves beyond it [m] (the walk's steps).
        own: The self-clearance every checked pair keeps [m].
        ratio: A floor on the link-height ratio the reach bounds assume (None: the segment's own).
        min_margin: The smallest margin the walk adapts to near a tight state [m] (None: ``margin``).
    """

    clearance: float
    margin: float
    own: float
    ratio: float | None = None
    min_margin: float | None = None

    @property
    def floor(self) -> float:
        """The smallest margin a state must prove [m]."""
        return self.margin if self.min_margin is None else self.min_margin

    def values(self) -> tuple[float, float, float, float | None, float]:
        """(clearance, margin, own, ratio, floor)."""
        return self.clearance, self.margin, self.own, self.ratio, self.floor


class CertifiedMotion:
    """The compiled motion walk of one world, with its FCL probes.

    Args:
        model: The robot's collision model (admissibility, slope of its slope-dependent bodies).
        bodies: The world's bodies.
        data: The world's kernel data.
        probes: The world's FCL probes.
    """

    def __init__(
        self, model: CollisionModel, bodies: BodySet, data: KernelData, probes: Probes, kernels: Kernels
    ) -> None:
        self.model = model
        self.bodies = bodies
        self.data = data
        self.probes = probes
        self.kernels = kernels

    def check(self, q_a: Array, q_b: Array, spec: Walk, probe_when_proven: bool) -> MotionReport:
        """The motion report of q_a -> q_b (contiguous (8,) joints; arguments already validated).

        ``spec``: what the walk proves; ``probe_when_proven``: the probe policy (see ``check_motion``).
        """
        clearance, motion_margin, own, ratio, floor = spec.values()
        d = self.data
        dq = q_b - q_a
        adq = np.abs(dq)
        n_fine = limit_samples(dq)
        k = self.kernels
        bad = k.first_inadmissible(q_a, dq, n_fine, d)
        if bad >= 0:
            t = bad * (1.0 / n_fine) if bad < n_fine else 1.0  # numpy.linspace's samples
            contacts = limit_contacts(self.model.admissibility, q_a + t * dq)
            return MotionReport(False, n_fine + 1, 0, t, tuple(contacts))
        end = k.end_ratio(q_a, q_b, d)
        if ratio is not None:
            end = max(end, ratio)
        reach, pair_reach = k.segment_reach(
            d,
            self.model.slope_bound(end + self.model.slope_deviation(q_a, q_b)),
            self.model.slope_half_width,
            adq,
        )
        has_cabin = self.probes.has_cabin
        d_max = max([*(reach.tolist() if has_cabin else []), *pair_reach.tolist()], default=0.0)
        # One schedule step never exceeds the smallest step the walk may take (at least ``floor`` of motion).
        n = int(max(1, np.ceil(d_max / floor)))
        n_bodies = len(self.bodies.names)
        cap = min(n + 1, 32)
        slot_of = np.full(n + 1, -1, dtype=np.int64)
        poses = np.empty((cap, n_bodies, 13))
        cabin = np.empty((cap, n_bodies))
        pairs = np.empty((cap, len(d.pair_a)))
        ci = np.zeros(walk.CI_SIZE, dtype=np.int64)
        cf = np.zeros(walk.CF_SIZE)
        ci[walk.CI_N], ci[walk.CI_CABIN] = n, has_cabin
        cf[walk.CF_CLEARANCE], cf[walk.CF_OWN], cf[walk.CF_MARGIN] = clearance, own, motion_margin
        cf[walk.CF_FLOOR] = floor
        cf[walk.CF_SMALLEST] = motion_margin
        # Exact pair distances where they are small (beyond, the bounds allow long steps anyway).
        cf[walk.CF_THRESHOLD] = own + 0.06
        cf[walk.CF_PROBE_PROVEN] = probe_when_proven
        n_cabin = n_bodies if has_cabin else 0
        before = self.probes.queries
        resumed = False  # the first call checks every array; the loop's later calls resume unchecked
        while True:
            code = k.motion_walk(
                ci, cf, q_a, q_b, dq, reach, pair_reach, d, slot_of, poses, cabin, pairs, resumed=resumed
            )
            resumed = True
            task = int(ci[walk.CI_TASK])
            is_cabin = task < n_cabin
            idx = task if is_cabin else task - n_cabin
            base = clearance if is_cabin else own
            if code == walk.WALK_DONE:
                queries = self.probes.queries - before + int(ci[walk.CI_QUERIES])
                return MotionReport(
                    True, int(ci[walk.CI_COUNT]), queries, smallest_margin_m=float(cf[walk.CF_SMALLEST])
                )
            if code == walk.WALK_GROW:
                grow = poses.shape[0]
                poses = np.concatenate([poses, np.empty_like(poses[:grow])])
                cabin = np.concatenate([cabin, np.empty_like(cabin[:grow])])
                pairs = np.concatenate([pairs, np.empty_like(pairs[:grow])])
            elif code == walk.WALK_FAIL:
                contact = body_contact(
                    self.bodies.names, self.bodies.pairs, is_cabin, idx, base + float(cf[walk.CF_LOCAL])
                )
                states = int(ci[walk.CI_COUNT])
                t_fail = float(cf[walk.CF_TFAIL])
                queries = self.probes.queries - before + int(ci[walk.CI_QUERIES])
                smallest = float(cf[walk.CF_SMALLEST])
                return MotionReport(False, states, queries, t_fail, (contact,), smallest)
            else:  # WALK_PROBE: the first level at which the grown body is clear becomes the spare clearance
                slot = int(ci[walk.CI_SLOT])
                st = BodyState(poses[slot], cabin[slot], pairs[slot])
                first = walk.CF_LEVEL0
                levels = cf[first : first + int(ci[walk.CI_LEVELS])].tolist()
                for level in levels:
                    if not self.probes.hit(st, is_cabin, idx, base + level):
                        cf[walk.CF_E] = level
                        break
                else:
                    # Every grown body hit. A grown box is a larger box: near its edges and corners it
                    # overstates the clearance it tests by up to (sqrt 3 - 1) times the growth, so the exact
                    # distance (milliseconds against a mesh, asked only here) decides.
                    local = float(cf[walk.CF_LOCAL])  # the margin the state must prove
                    if levels and min(levels) <= local + 1e-12:
                        exact_spare = self.probes.distance(st, is_cabin, idx)[0] - base
                        if exact_spare >= local:
                            cf[walk.CF_E] = exact_spare
