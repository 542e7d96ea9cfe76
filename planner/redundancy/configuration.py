"""A robot configuration with its kinematic quantities computed once and cached."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from planner.core.types import Array
from planner.robots.cabin8 import Cabin8


class Configuration:
    """Joint vector q of a :class:`Cabin8` with lazily cached FK, Jacobians and admissibility values.

    A Configuration is immutable: stepping creates a new one (:meth:`integrate`).

    Args:
        robot: The robot model.
        q: Joint vector (8,) [m, rad].
    """

    def __init__(self, robot: Cabin8, q: Array) -> None:
        self.robot = robot
        self.q = np.array(q, dtype=float)
        self.q.setflags(write=False)

    @cached_property
    def _all(self) -> tuple[Array, ...]:
        # One compiled call gives FK, both Jacobians and the admissibility vector with its Jacobian.
        return self.robot.kin.step(self.q)

    @property
    def T_base_tool(self) -> Array:
        """Tool pose in the base frame (4x4)."""
        return self._all[0]

    @property
    def jacobian(self) -> Array:
        """Geometric joint-space Jacobian (6x8), twist (v; omega) in the base frame."""
        return self._all[1]

    @property
    def drive_jacobian(self) -> Array:
        """Drive-space Jacobian (6x8)."""
        return self._all[2]

    @property
    def c(self) -> Array:
        """The admissibility vector, in ``Cabin8.constraint_specs`` order."""
        return self._all[3]

    @property
    def dc_dq(self) -> Array:
        """Jacobian of the admissibility vector, (m, 8)."""
        return self._all[4]

    @cached_property
    def u(self) -> Array:
        """Drive positions (8,)."""
        return self.c[:8].copy()

    def integrate(self, dq: Array) -> Configuration:
        """Step to the configuration q + dq."""
        return Configuration(self.robot, self.q + dq)
