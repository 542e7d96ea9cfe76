"""Certified straight motions for the planners: a cheap sampled rejection first, an adaptive margin after.

A planner's shortcut attempts and long tree extensions mostly fail, and a certified walk
(:meth:`CollisionWorld.check_motion`) pays for every state it proves clear before it meets the obstacle:
about 10 ms for a failing 0.5-1.4 rad/m move against 2 ms for a typical accepted edge (measured on the
reference bay insertions). A single state check costs some 50 us, so a few states at bisection points
(1/2, 1/4, 3/4, ...) are checked first: a state that fails proves the motion fails (the certified check
would fail there too), so the answer is the same and only failing motions get cheaper.

**Adaptive margin.** The walk proves, at every state it checks, a spare clearance of at least its margin
beyond ``clearance``, and steps by that margin over the bodies' displacement bound. Near a tight state (an
insertion into a bay with millimetres to spare) a fixed margin refuses a motion that is clear, only because
its states lack the margin. So the walk adapts its margin where it must (``CollisionWorld.check_motion``
with ``min_margin``): a state that cannot prove the margin is asked again nearer the last proven state with
half of it, down to :data:`MIN_MARGIN_M`, and the margin grows back where there is room. A motion whose
true clearance is at least ``clearance + MIN_MARGIN_M`` everywhere is certified by one walk with short
steps only where it is tight; one that comes closer is refused with the state and the bodies that come
closest. (Before, a failed walk was run again from the start with a smaller margin, up to eight times:
on 35 generated plans those repeated walks took a third of all the walking, and corner cuts were refused
after one retry to bound that cost; measured in ``bench.generalization``, one adaptive walk plans those
cases 11% faster with every motion held to the same ``MIN_MARGIN_M``.)

**Either way along.** The walk needs its margin at the state it leaves from; the state it arrives at is
reached by the last step's bound and needs only the clearance. A segment that no walk can leave (less than
:data:`MIN_MARGIN_M` of spare clearance at its start) is walked the other way before it is refused: the
segment is the same set of configurations, so a certificate of the reversed walk is a certificate of it.
A generated cycle's retract was refused that way (slide 11.98 mm from the cabin at the release an
insertion had arrived at, 12 mm needed to leave it), which the reversed walk certifies with the full 5 mm
margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.collision.world import CollisionWorld, MotionReport
from planner.core.types import Array

#: One probe state per this much of the largest joint step [m or rad], at most MAX_PROBES.
PROBE_SPACING = 0.05
MAX_PROBES = 7
#: Bisection order of the probes along the segment.
_PROBE_T = np.array([0.5, 0.25, 0.75, 0.125, 0.375, 0.625, 0.875])
#: The smallest margin the adaptive walk goes down to [m]: a motion whose states keep at least this
#: spare clearance beyond the planner's clearance is certified; closer ones are refused. 0.5 mm keeps the
#: planner's total slack over the requested clearance at 2 mm (with the 1.5 mm planner slack).
MIN_MARGIN_M = 0.0005
#: The next margin :func:`path_clear` tries is this fraction of the spare clearance where its walk failed.
SPARE_FRACTION = 0.8


@dataclass(frozen=True)
class AdaptiveMotion:
    """The outcome of an adaptive certified motion check.

    Attributes:
        report: The last walk's report.
        margin_m: The smallest margin the walk stepped with when it passed; the margin it could not prove
            where it failed (the smallest it adapts to, :data:`MIN_MARGIN_M`, or the scenario's margin if
            that is smaller) [m].
    """

    report: MotionReport
    margin_m: float

    @property
    def valid(self) -> bool:
        """True when the motion is certified."""
        return self.report.valid


def spare_clearance(world: CollisionWorld, q: Array, clearance: float) -> float:
    """Exact spare clearance at q [m] (exact FCL distance queries).

    The smallest body-cabin distance beyond ``clearance``, or the smallest distance of a checked body pair
    beyond the world's self-clearance, whichever is smaller.
    """
    spare = np.inf
    if world.cabin is not None or world.obstacles is not None:
        spare = world.min_distance(q, include_self=False).distance_m - clearance
    pair = world.min_distance(q, include_self=True)
    if not world.is_environment(pair.bodies[1]):
        spare = min(spare, pair.distance_m - world.self_clearance)
    return float(spare)


def certify_motion(
    world: CollisionWorld,
    q_a: Array,
    q_b: Array,
    clearance: float,
    motion_margin: float,
) -> AdaptiveMotion:
    """The certified walk q_a -> q_b with ``motion_margin``, adapted down to MIN_MARGIN_M near tight states.

    See the module docstring (a motion that no walk can leave ``q_a`` for, with less than MIN_MARGIN_M of
    spare clearance there, is walked from ``q_b`` back to ``q_a`` before it is refused).
    Limits and margins of the parallel stage are never adapted: a limit failure is final.
    """
    margin = float(motion_margin)
    floor = min(margin, MIN_MARGIN_M)
    rep = world.check_motion(q_a, q_b, clearance, margin, min_margin=floor)
    if rep.valid or rep.t_fail is None or any(c.kind == "limit" for c in rep.contacts):
        return AdaptiveMotion(rep, margin if rep.smallest_margin_m is None else rep.smallest_margin_m)
    # No walk can leave q_a, which is itself clear (exact distances, asked only here): walk towards it.
    if rep.t_fail == 0.0 and spare_clearance(world, np.asarray(q_a, dtype=float), clearance) >= 0.0:
        back = world.check_motion(q_b, q_a, clearance, margin, min_margin=floor)
        if back.valid:
            return AdaptiveMotion(back, margin if back.smallest_margin_m is None else back.smallest_margin_m)
    return AdaptiveMotion(rep, floor)


def motion_clear(
    world: CollisionWorld,
    q_a: Array,
    q_b: Array,
    clearance: float,
    motion_margin: float,
) -> bool:
    """True when the straight joint motion q_a -> q_b is certified to keep ``clearance`` (and limits).

    The answer of :func:`certify_motion`, faster when the motion fails at one of the probe states.
    """
    q_a, q_b = np.asarray(q_a, dtype=float), np.asarray(q_b, dtype=float)
    dq = q_b - q_a
    probes = min(MAX_PROBES, int(float(np.abs(dq).max()) / PROBE_SPACING))
    for t in _PROBE_T[:probes]:
        if not world.is_valid(q_a + t * dq, clearance):
            return False
    return certify_motion(world, q_a, q_b, clearance, motion_margin).valid


def path_clear(
    world: CollisionWorld,
    qs: Array,
    clearance: float,
    motion_margin: float,
    max_extra_m: float = 0.002,
) -> bool:
    """True when the polyline through (N, n) configurations is certified to keep ``clearance``.

    :meth:`CollisionWorld.check_path` with ``motion_margin``, retried with the margin halved (down to
    :data:`MIN_MARGIN_M`) while the piece that failed has that much spare clearance where it starts.
    """
    margin = float(motion_margin)
    while True:
        rep = world.check_path(qs, clearance, margin, max_extra_m=max_extra_m)
        if rep.valid:
            return True
        if rep.first_bad is None or any(c.kind == "limit" for c in rep.contacts) or margin <= MIN_MARGIN_M:
            return False
        spare = spare_clearance(world, np.atleast_2d(qs)[rep.first_bad], clearance)
        if spare <= MIN_MARGIN_M:
            return False
        margin = max(MIN_MARGIN_M, min(0.5 * margin, SPARE_FRACTION * spare))
