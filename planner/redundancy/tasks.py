"""Tasks of the redundancy QP: each gives an error e(q) and a Jacobian J(q) with J dq ~ e.

Sign convention: the error points from the current value to the target, so the least-squares step
solves ``J dq = e``. A task contributes ``|| W (J dq - e) ||^2`` to the QP cost, plus Levenberg-Marquardt
damping ``lm_damping * |e|^2 * |dq|^2`` that keeps steps short while the error is large (the mink/pink
formulation).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np

from planner.core.so3 import pose_error
from planner.core.types import Array
from planner.redundancy.configuration import Configuration


class Objective(NamedTuple):
    """Quadratic objective 1/2 dq^T H dq + c^T dq."""

    H: Array
    c: Array


class Task(ABC):
    """A weighted least-squares objective on the joint step."""

    def __init__(self, cost: Array | float, lm_damping: float = 0.0) -> None:
        self.cost = cost
        self.lm_damping = lm_damping

    @abstractmethod
    def compute_error(self, configuration: Configuration) -> Array:
        """Task error e(q), shape (k,)."""

    @abstractmethod
    def compute_jacobian(self, configuration: Configuration) -> Array:
        """Task Jacobian, shape (k, 8)."""

    def compute_qp_objective(self, configuration: Configuration) -> Objective:
        """H = J^T W^2 J + mu I and c = -J^T W^2 e with mu = lm_damping |W e|^2."""
        e = self.compute_error(configuration)
        J = self.compute_jacobian(configuration)
        w = np.asarray(self.cost, dtype=float)
        We = w * e
        WJ = J * (w[:, None] if w.ndim else w)
        H = WJ.T @ WJ
        if self.lm_damping:
            H.flat[:: H.shape[0] + 1] += self.lm_damping * float(We @ We)
        return Objective(H, -WJ.T @ We)


class FrameTask(Task):
    """Bring the tool frame to ``T_target`` (4x4, base frame).

    Args:
        T_target: Target pose of the tool frame.
        position_cost: Weight of the position error [1/m].
        orientation_cost: Weight of the orientation error [1/rad].
        lm_damping: Levenberg-Marquardt damping.
    """

    def __init__(
        self,
        T_target: Array,
        position_cost: float = 1.0,
        orientation_cost: float = 1.0,
        lm_damping: float = 0.0,
    ) -> None:
        super().__init__(np.array([position_cost] * 3 + [orientation_cost] * 3), lm_damping)
        self.T_target = np.asarray(T_target, dtype=float)

    def compute_error(self, configuration: Configuration) -> Array:
        """(p_target - p; log(R_target R^T)), base frame."""
        return pose_error(self.T_target, configuration.T_base_tool)

    def compute_jacobian(self, configuration: Configuration) -> Array:
        """The geometric Jacobian."""
        return configuration.jacobian


class PostureTask(Task):
    """Stay near a preferred joint vector ``q_ref`` (the redundancy's default use).

    ``cost`` may be per joint (8,), e.g. to weigh metres and radians sensibly.
    """

    def __init__(self, q_ref: Array, cost: Array | float = 1e-2) -> None:
        super().__init__(cost)
        self.q_ref = np.asarray(q_ref, dtype=float)

    def compute_qp_objective(self, configuration: Configuration) -> Objective:
        """Diagonal objective: H = W^2, c = -W^2 (q_ref - q) (no Jacobian product needed)."""
        w2 = np.broadcast_to(np.square(np.asarray(self.cost, dtype=float)), configuration.q.shape)
        return Objective(np.diag(w2), -w2 * (self.q_ref - configuration.q))

    def compute_error(self, configuration: Configuration) -> Array:
        """q_ref - q."""
        return self.q_ref - configuration.q

    def compute_jacobian(self, configuration: Configuration) -> Array:
        """Identity."""
        return np.eye(configuration.q.shape[0])


class MarginTask(Task):
    """Push admissibility margins up to a comfortable level (limit and singularity clearance).

    For every constraint whose distance to a bound is below ``comfort`` (per constraint, in its unit),
    the error asks the step to restore ``comfort``; constraints already comfortable contribute nothing.
    """

    def __init__(self, comfort: Array, cost: float = 1e-1) -> None:
        super().__init__(cost)
        self.comfort = np.asarray(comfort, dtype=float)

    def _rows(self, configuration: Configuration) -> tuple[Array, Array]:
        robot = configuration.robot
        c, dc = configuration.c, configuration.dc_dq
        d_up = robot.c_upper - c
        d_lo = c - robot.c_lower
        near_up = d_up < d_lo
        margin = np.where(near_up, d_up, d_lo)
        sign = np.where(near_up, -1.0, 1.0)  # direction in which the margin grows
        deficit = np.clip(self.comfort - margin, 0.0, None) / self.comfort
        J = sign[:, None] * dc / self.comfort[:, None]
        return deficit, J

    def compute_error(self, configuration: Configuration) -> Array:
        """Normalised margin deficits (0 when comfortable)."""
        return self._rows(configuration)[0]

    def compute_jacobian(self, configuration: Configuration) -> Array:
        """Normalised margin gradients, rows zeroed where there is no deficit."""
        deficit, J = self._rows(configuration)
        return np.where(deficit[:, None] > 0, J, 0.0)
