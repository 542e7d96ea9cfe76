"""Certified straight motions for the planners, with a cheap sampled rejection first.

A planner's shortcut attempts and long tree extensions mostly fail, and a certified walk
(:meth:`CollisionWorld.check_motion`) pays for every state it proves clear before it meets the obstacle:
about 10 ms for a failing 0.5-1.4 rad/m move against 2 ms for a typical accepted edge (measured on the
reference bay insertions). A single state check costs some 50 us, so a few states at bisection points
(1/2, 1/4, 3/4, ...) are checked first: a state that fails proves the motion fails (the certified check
would fail there too), so the answer is the same and only failing motions get cheaper. Accepting a motion
always takes the certified walk.
"""

from __future__ import annotations

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.types import Array

#: One probe state per this much of the largest joint step [m or rad], at most MAX_PROBES.
PROBE_SPACING = 0.05
MAX_PROBES = 7
#: Bisection order of the probes along the segment.
_PROBE_T = np.array([0.5, 0.25, 0.75, 0.125, 0.375, 0.625, 0.875])


def motion_clear(
    world: CollisionWorld, q_a: Array, q_b: Array, clearance: float, motion_margin: float
) -> bool:
    """True when the straight joint motion q_a -> q_b is certified to keep ``clearance`` (and limits).

    The same answer as ``world.check_motion(q_a, q_b, clearance, motion_margin).valid``, faster when the
    motion fails at one of the probe states.
    """
    q_a, q_b = np.asarray(q_a, dtype=float), np.asarray(q_b, dtype=float)
    dq = q_b - q_a
    probes = min(MAX_PROBES, int(float(np.abs(dq).max()) / PROBE_SPACING))
    for t in _PROBE_T[:probes]:
        if not world.is_valid(q_a + t * dq, clearance):
            return False
    return world.check_motion(q_a, q_b, clearance, motion_margin).valid
