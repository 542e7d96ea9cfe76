"""Which robot has a dynamics model: the force model the timing stage and the gate use, if any.

The force models are held by the robot registry (:mod:`planner.robots.registry`); this module registers
cabin8's (the Lagrange model of :mod:`planner.dynamics.lagrange`) and looks them up. A mechanism without one
(pprs6: the paper gives no masses) is timed and gated under its drive velocity and acceleration limits
only, and its profiles carry no forces.
"""

from __future__ import annotations

from typing import cast

from planner.dynamics.payload import RigidPayload
from planner.robots import base
from planner.robots.base import RobotModel
from planner.robots.registry import force_model_of, register_forces

#: A force model taking the planner's payload (:class:`~planner.robots.base.DriveDynamics` bound to
#: :class:`~planner.dynamics.payload.RigidPayload`).
DriveDynamics = base.DriveDynamics[RigidPayload]


def _cabin8_forces(robot: RobotModel) -> DriveDynamics:
    """cabin8's inverse dynamics (:class:`~planner.dynamics.lagrange.Cabin8Dynamics`, once per model)."""
    from planner.dynamics.lagrange import Cabin8Dynamics
    from planner.robots.cabin8 import Cabin8

    if not isinstance(robot, Cabin8):
        raise TypeError(f"cabin8's force model needs a Cabin8 model, got {type(robot).__name__}")
    return Cabin8Dynamics.of(robot)


register_forces("cabin8", _cabin8_forces)


def drive_dynamics(robot: RobotModel) -> DriveDynamics | None:
    """The robot's dynamics model (built once per model), or None where it has none."""
    return cast(DriveDynamics | None, force_model_of(robot))


__all__ = ["DriveDynamics", "drive_dynamics"]
