"""The load change at a grasp or a release: the tool springs by the change of its static deflection.

The drives hold their positions while the gripper takes or lets go of a unit, but the structure's static
deflection under gravity (:mod:`planner.dynamics.stiffness`: links, tool and payload weights) changes with
the load: at a release the tool springs back (up, mostly) by the deflection the unit's weight caused, at
a grasp it sinks by as much. With x(q, load) the deflection twist (translation [m], rotation [rad], base
frame) of a frame fixed to the tool, the jump is

    dx = x(q, after) - x(q, before),

and the frame's real pose moves from ``deflected_pose(T(q), x_before)`` to ``deflected_pose(T(q), x_after)``
(:func:`~planner.dynamics.stiffness.deflected_pose`). This module is the one place a cycle calls the
stiffness model for a load change (the stiffness model's public functions only), so a port of that model
changes only :func:`load_change`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.dynamics.stiffness import deflected_pose, stiffness_model
from planner.robots.cabin8 import Cabin8


@dataclass(frozen=True)
class LoadChange:
    """The static deflection of a tool-fixed frame before and after a load change at one configuration.

    Attributes:
        q: The configuration (8,) the drives hold.
        T_tool_frame: The frame the deflection is measured at, in the tool frame (4x4).
        before: Deflection twist (6,) [m, rad] with the load before the change (base frame).
        after: Deflection twist (6,) with the load after it.
    """

    q: Array = field(repr=False)
    T_tool_frame: Array = field(repr=False)
    before: Array = field(repr=False)
    after: Array = field(repr=False)

    @property
    def jump(self) -> Array:
        """The frame's jump (6,): ``after - before`` (translation [m], rotation [rad], base frame)."""
        return self.after - self.before

    @property
    def springback_m(self) -> float:
        """Size of the frame origin's jump [m]."""
        return float(np.linalg.norm(self.jump[:3]))

    @property
    def rotation_rad(self) -> float:
        """Size of the frame's rotation jump [rad]."""
        return float(np.linalg.norm(self.jump[3:]))

    def poses(self, T_base_frame: Array) -> tuple[Array, Array]:
        """The frame's real poses (4x4, 4x4) before and after, given its rigid pose ``T_base_frame``."""
        return deflected_pose(T_base_frame, self.before), deflected_pose(T_base_frame, self.after)


def load_change(
    robot: Cabin8,
    q: Array,
    before: RigidPayload | None,
    after: RigidPayload | None,
    T_tool_frame: Array | None = None,
) -> LoadChange:
    """The static deflection of a tool-fixed frame before and after the tool's load changes at q.

    Args:
        robot: The robot (it must have stiffness data).
        q: The configuration the drives hold (8,).
        before: The payload carried before the change (None: the empty tool).
        after: The payload carried after it.
        T_tool_frame: The frame, in the tool frame (default: the tool frame).

    Returns:
        The :class:`LoadChange`; its :attr:`~LoadChange.jump` is the frame's spring-back (release) or sink
        (grasp).
    """
    model = stiffness_model(robot)
    T = np.eye(4) if T_tool_frame is None else np.asarray(T_tool_frame, dtype=float)
    q = np.asarray(q, dtype=float)
    x_before = model.deflection(q, before, T).twist
    x_after = model.deflection(q, after, T).twist
    return LoadChange(q.copy(), T.copy(), x_before, x_after)
