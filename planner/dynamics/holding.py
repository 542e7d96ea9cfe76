"""The static-hold check: can the drives hold the robot and its payload at rest at a configuration?

Every state the planner passes through must be holdable within a fraction of the drive force limits
(:class:`StaticForceCheck`); the static drive forces come from the robot's inverse dynamics at rest
(:meth:`planner.dynamics.lagrange.Cabin8Dynamics.static_forces_batch`: gravity on the links, the tool and
the payload), the margin left for the dynamic forces that the timing stage keeps within the limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.core.types import Array
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload

#: Spacing of :meth:`StaticForceCheck.segment_ok`'s points: m or rad of the largest joint change.
SEGMENT_STEP = 0.02


@dataclass(frozen=True)
class StaticForceCheck:
    """Static drive forces (holding the payload at rest) within ``fraction`` of the force limits.

    A state the drives cannot hold is useless to plan through; the margin (1 - fraction) is left for the
    dynamic forces, which the timing stage keeps within the limits along the path.
    """

    dynamics: Cabin8Dynamics
    payload: RigidPayload | None
    fraction: float = 0.95

    def ratios(self, qs: Array) -> Array:
        """Largest |static force| / limit of each configuration (N,) for (N, 8) joints."""
        return self._ratios(self.dynamics.static_forces_batch(qs, self.payload))

    def _ratios(self, tau: Array) -> Array:
        """Largest |force| / limit of forces tau (..., 8), over the last axis."""
        return np.max(np.abs(tau) / self.dynamics.robot.limits.effort_max, axis=-1)

    def ok(self, q: Array) -> bool:
        """True when the drives can hold the payload at q (8,): :meth:`ratios`' figure, one configuration.

        The same inverse dynamics at rest and the same arithmetic as :meth:`ratios` on one row (the same
        verdict, bit for bit), without its batch's stacking: a sampling planner asks it of every state.
        """
        return bool(self._ratios(self.dynamics.static_forces(q, self.payload)) <= self.fraction)

    def segment_ok(self, q_a: Array, q_b: Array, step: float = SEGMENT_STEP) -> bool:
        """Checked at every ``step`` (m or rad, largest joint change) along the straight segment."""
        n = int(max(1, np.ceil(float(np.max(np.abs(q_b - q_a))) / step)))
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        return bool(np.all(self.ratios(q_a + t * (q_b - q_a)) <= self.fraction))
