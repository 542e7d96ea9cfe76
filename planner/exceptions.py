"""One exception tree for the whole planner; every error carries the evidence that explains it.

Callers catch :class:`PlannerError` for "the planner refused", and the subclasses when they need to tell
the reasons apart. Each exception has a stable machine-readable ``reason`` (used by the CLI exit codes and
the HTTP problem bodies) and a ``details`` mapping with the numbers behind the refusal.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class PlannerError(Exception):
    """Root of every error the planner raises on purpose.

    Attributes:
        reason: Stable, machine-readable reason code (snake_case).
        details: JSON-serialisable evidence (values, limits, indices) behind the error.
    """

    reason: str = "planner_error"

    def __init__(self, message: str, **details: Any) -> None:
        super().__init__(message)
        self.message = message
        self.details: Mapping[str, Any] = details

    def to_dict(self) -> dict[str, Any]:
        """Machine-readable form: ``{"reason", "message", "details"}``."""
        return {"reason": self.reason, "message": self.message, "details": dict(self.details)}


class InvalidInput(PlannerError):
    """A user-supplied value is malformed or names something that does not exist."""

    reason = "invalid_input"


class InvalidRobotDescription(InvalidInput):
    """A robot description file failed validation."""

    reason = "invalid_robot_description"


class UnknownRobot(InvalidInput):
    """No robot model of that name is registered."""

    reason = "unknown_robot"


class OutsideWorkspace(PlannerError):
    """A configuration or pose lies outside the mechanism's workspace or violates its assembly mode.

    ``details`` names the violated condition (``condition``) and, for batches, the first failing ``index``.
    """

    reason = "outside_workspace"


class LimitViolation(PlannerError):
    """A configuration violates a joint/drive limit or a singularity margin (``details['violations']``)."""

    reason = "limit_violation"


class GoalUnreachable(PlannerError):
    """Inverse kinematics found no admissible configuration for the requested pose."""

    reason = "goal_unreachable"


class QPSolveFailed(PlannerError):
    """The quadratic program of a redundancy-resolution step had no solution."""

    reason = "qp_failed"


class InvalidMesh(InvalidInput):
    """A mesh file cannot be used: unreadable, empty, non-finite, too large, wrong units or format.

    ``details`` carries the file name, the check that failed and the measured values.
    """

    reason = "invalid_mesh"
