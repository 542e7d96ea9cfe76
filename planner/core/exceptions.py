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


class ForwardKinematicsFailed(OutsideWorkspace):
    """Numerical forward kinematics did not converge to the working assembly mode (no such assembly).

    ``details`` carries the failing sample ``index``, its closure ``residual_m`` and the ``drives``.
    """

    reason = "fk_not_converged"


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


class PlanRefused(PlannerError):
    """The scenario is well-formed but the planner returns no trajectory; ``reason`` says why.

    Subclasses fix the reason; every refusal is a plain "no" to the caller (CLI exit 3, HTTP result with
    status ``failed``), never a partial trajectory.
    """

    reason = "plan_refused"


class StartInvalid(PlanRefused):
    """The start configuration violates a limit or margin, or touches the cabin or itself.

    ``details['contacts']`` lists what is wrong. ``reason`` is ``start_in_collision`` for contacts and
    ``start_outside_limits`` for limit or margin violations.
    """

    reason = "start_in_collision"

    def __init__(self, message: str, *, limits: bool = False, **details: Any) -> None:
        super().__init__(message, **details)
        if limits:
            self.reason = "start_outside_limits"


class GoalInCollision(PlanRefused):
    """Every configuration reaching the goal touches the cabin or itself (or violates a margin)."""

    reason = "goal_in_collision"


class ApproachInfeasible(PlanRefused):
    """The straight-line approach cannot be tracked within limits, margins and clearance."""

    reason = "approach_infeasible"


class NoPathFound(PlanRefused):
    """The wall-clock time limit stopped the search before it found a path or spent its work budget.

    The outcome depends on the machine's speed and load (``details['ended_by'] == 'time_limit'``).
    """

    reason = "no_path_within_time_limit"


class NoPathWithinBudget(NoPathFound):
    """The search spent its work budget (motion checks) without a certified path.

    Reproducible: the same scenario and seed end the same way on any machine
    (``details['ended_by'] == 'work_budget'``).
    """

    reason = "no_path_within_budget"


class RetimingFailed(PlanRefused):
    """Time-parameterisation found no profile within the drive limits (e.g. a force limit at rest)."""

    reason = "retiming_failed"


class ValidationFailed(PlanRefused):
    """The validation gate rejected the trajectory; ``details['report']`` is the gate's full report."""

    reason = "validation_failed"


class DeflectionNotCompensated(PlanRefused):
    """Goal compensation did not bring the predicted deflected pose within tolerance of the request.

    ``details['iterations']`` is the residual log (m, rad); ``details['violations']`` lists the limits the
    commanded configuration would violate, when that is why.
    """

    reason = "compensation_failed"


class CalibrationIllPosed(InvalidInput):
    """Measured deflections cannot determine the stiffness parameters asked for (issue 15).

    Too few measurements or configurations, configurations or loads too similar to separate the parameters
    (``details['condition']``, ``details['combination']``), or a parameter left undetermined
    (``details['relative_std']``).
    """

    reason = "calibration_ill_posed"


class UnitNotHoldable(PlanRefused):
    """An assembly cycle's unit cannot be held at its dock: ``details`` name the drive and its force ratio."""

    reason = "unit_not_holdable"


class ReleaseInCollision(PlanRefused):
    """At a cycle's release the tool's spring-back (the load change) brings a body within the clearance.

    ``details`` name the bodies and their distance.
    """

    reason = "release_in_collision"
