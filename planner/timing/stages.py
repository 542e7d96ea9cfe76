"""The registry of timing stages: a stage's name -> how to build it and whether it binds the jerk limits.

A decision lives here once: which :class:`~planner.timing.stage.TimingStage` a name builds, whether the
gate holds the profile to the drive jerk limits, and which stage a scenario that names none gets (the rule
of :func:`planner.core.timing_names.default_timing`: jerk-limited when the robot description has jerk
limits, else acceleration-limited). The scenario schema (``options.timing``), the planner (the plan
context's factory), the gate (:func:`planner.gate.requirements.requirements_for`), pprs6's pose paths and
both robot models all read it from here or from the names beside the rule. A new stage is one module and
one entry of :data:`STAGES` (plus its name in :data:`~planner.core.timing_names.TimingName`; this module
refuses to load when the two disagree).

- ``jerk_limited``: :class:`~planner.timing.jerk.JerkLimitedStage`, checked at the controller period;
  binds the jerk limits and needs them in the robot description.
- ``acceleration_limited``: :class:`~planner.timing.toppra.ToppraStage` (TOPP-RA alone); the jerk check
  reports the peak and passes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, get_args

from planner.core.exceptions import InvalidInput
from planner.core.timing_names import ACCELERATION_LIMITED, JERK_LIMITED, TimingName, default_timing
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel
from planner.timing.jerk import JerkLimitedStage
from planner.timing.stage import Safety, TimingFactory, TimingStage
from planner.timing.toppra import ToppraStage


@dataclass(frozen=True)
class StageEntry:
    """One registered timing stage.

    Attributes:
        name: Its name (``options.timing``).
        stage: The stage's class (a :class:`~planner.timing.stage.TimingStage` built from the robot, the
            payload and keyword settings: ``safety``, ``min_points`` / ``max_points``, ``sample_period_s``).
        binds_jerk: Whether the gate holds its profiles to the drive jerk limits (else the jerk check
            reports the peak and passes).
        needs_jerk_limits: Whether the robot description must give jerk limits for it.
        checked_at_period: Whether the stage checks its law at the controller period (it is then given
            ``sample_period_s``; the jerk-limited stage's jerk is the change of the sampled acceleration).
    """

    name: TimingName
    stage: Callable[..., TimingStage]
    binds_jerk: bool
    needs_jerk_limits: bool
    checked_at_period: bool

    def build(
        self,
        robot: RobotModel,
        payload: RigidPayload | None,
        safety: Safety | None = None,
        *,
        sample_period_s: float,
        grid_points: int | None = None,
    ) -> TimingStage:
        """The stage for a robot and payload.

        Args:
            robot: The robot model.
            payload: The carried payload (None: empty gripper).
            safety: Fractions of the (velocity, acceleration, force) limits the stage may use (None: the
                stage's own default, :data:`~planner.timing.stage.DEFAULT_SAFETY` for both stages).
            sample_period_s: The controller period the profile is sampled at [s].
            grid_points: A fixed number of grid intervals per leg (None: the stage's spacing rule).
        """
        kw: dict[str, Any] = {}
        if safety is not None:
            kw["safety"] = safety
        if grid_points is not None:
            kw.update(min_points=grid_points, max_points=grid_points)
        if self.checked_at_period:
            kw["sample_period_s"] = sample_period_s
        return self.stage(robot, payload, **kw)

    def factory(self, sample_period_s: float) -> TimingFactory:
        """The plan's factory ``(robot, payload, safety) -> TimingStage`` at the controller period."""

        def build(robot: Any, payload: Any, safety: Safety) -> TimingStage:
            return self.build(robot, payload, safety, sample_period_s=sample_period_s)

        return build


#: Every timing stage, by name.
STAGES: dict[str, StageEntry] = {
    JERK_LIMITED: StageEntry(
        JERK_LIMITED, JerkLimitedStage, binds_jerk=True, needs_jerk_limits=True, checked_at_period=True
    ),
    ACCELERATION_LIMITED: StageEntry(
        ACCELERATION_LIMITED, ToppraStage, binds_jerk=False, needs_jerk_limits=False, checked_at_period=False
    ),
}
if set(STAGES) != set(get_args(TimingName)):  # pragma: no cover - a registry edited without its names
    raise ImportError(f"timing stages {sorted(STAGES)} != the names {sorted(get_args(TimingName))}")


def default_stage(robot: RobotModel) -> StageEntry:
    """The stage of a scenario that names none (:func:`~planner.core.timing_names.default_timing`)."""
    return STAGES[default_timing(robot.limits.j_max is not None)]


def select(option: str | None, robot: RobotModel) -> StageEntry:
    """The timing stage of a scenario: ``options.timing`` (``option``), else the robot's default.

    Raises:
        InvalidInput: an unknown name, or a stage that needs jerk limits asked for a robot whose
            description has none (``field`` ``options.timing``).
    """
    if option is None:
        return default_stage(robot)
    entry = STAGES.get(option)
    if entry is None:
        raise InvalidInput(
            f"options.timing: unknown timing stage {option!r}; expected one of {sorted(STAGES)}",
            field="options.timing",
        )
    if entry.needs_jerk_limits and robot.limits.j_max is None:
        raise InvalidInput(
            f"options.timing: robot {robot.name!r} has no jerk limits in its description",
            field="options.timing",
        )
    return entry
