"""Which robot has a dynamics model: the force model the timing stage and the gate use, if any.

A mechanism without one (pprs6: the paper gives no masses) is timed and gated under its drive velocity and
acceleration limits only, and its profiles carry no forces.
"""

from __future__ import annotations

from typing import Protocol

from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel


class DriveDynamics(Protocol):
    """Inverse dynamics in drive space, batched over (N, n) arrays, SI units."""

    def drive_forces_batch(
        self, q: Array, qd: Array, qdd: Array, payload: RigidPayload | None = None
    ) -> Array:
        """Drive forces / torques (N, n_drives) of the joint motion (q, q', q'')."""
        ...

    def static_forces_batch(self, q: Array, payload: RigidPayload | None = None) -> Array:
        """Drive forces (N, n_drives) that hold the configurations at rest."""
        ...

    def joint_rates_batch(self, q: Array, ud: Array, udd: Array) -> tuple[Array, Array]:
        """Joint velocities and accelerations (N, n) of drive velocities and accelerations at q."""
        ...


def drive_dynamics(robot: RobotModel) -> DriveDynamics | None:
    """The robot's dynamics model (built once per model), or None where it has none."""
    from planner.robots.cabin8 import Cabin8

    if isinstance(robot, Cabin8):
        from planner.dynamics.lagrange import Cabin8Dynamics

        return Cabin8Dynamics.of(robot)
    return None
