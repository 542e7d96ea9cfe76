"""The registry of timing stages: a stage's name -> how to build it and whether it binds the jerk limits.

A decision lives here once: which :class:`~planner.timing.stage.TimingStage` a name builds, whether the
gate holds the profile to the drive jerk limits, and which stage a scenario that names none gets (the rule
of :func:`planner.core.timing_names.default_timing`: jerk-limited when the robot description has jerk
limits, else acceleration-limited). The scenario schema (``options.timing``), the planner (the plan
context's factory), the gate (:func:`planner.gate.requirements.requirements_for`), pprs6's pose paths and
both robot models all read it from here or from the names beside the rule. A new stage is one module and
one entry of :data:`STAGES` (plus its name in :data:`~planner.core.timing_names.TimingName`; this module
refuses to load when the two disagree).

========================  ==========================================  ===========  ====================
name                      stage                                        binds jerk   needs jerk limits
========================  ==========================================  ===========  ====================
``jerk_limited``          :class:`~planner.timing.jerk.JerkLimitedStage`  yes          yes
``acceleration_limited``  :class:`~planner.timing.toppra.ToppraStage`     no           no
========================  ==========================================  ===========  ====================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, get_args

from planner.core.exceptions import InvalidInput
from planner.core.timing_names import ACCELERATION_LIMITED, JERK_LIMITED, TimingName, default_timing
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel
from planner.timing.jerk import JerkLimitedStage
from planner.timing.stage import TimingFactory, TimingStage
from planner.timing.toppra import ToppraStage

Safety = tuple[float, float, float]


class StageBuilder(Protocol):
    """Builds one stage for a robot and payload.

    Args:
        robot: The robot model.
        payload: The carried payload (None: empty gripper).
        safety: Fractions of the (velocity, acceleration, force) limits the stage may use (None: the
            stage's own default, (0.995, 0.97, 0.97) for both stages).
        sample_period_s: The controller period the profile is sampled at [s].
        grid_points: A fixed number of grid intervals per leg (None: the stage's spacing rule).
    """

    def __call__(
        self,
        robot: RobotModel,
        payload: RigidPayload | None,
        safety: Safety | None,
        *,
        sample_period_s: float,
        grid_points: int | None,
    ) -> TimingStage:
        """The stage (see the class docstring for the arguments)."""
        ...


def _grid(grid_points: int | None) -> dict[str, int]:
    return {} if grid_points is None else {"min_points": grid_points, "max_points": grid_points}


def _jerk_limited(
    robot: RobotModel,
    payload: RigidPayload | None,
    safety: Safety | None,
    *,
    sample_period_s: float,
    grid_points: int | None,
) -> TimingStage:
    """The jerk-limited LP, its jerk checked at the controller period."""
    kw: dict[str, Any] = {"sample_period_s": sample_period_s, **_grid(grid_points)}
    if safety is not None:
        kw["safety"] = safety
    return JerkLimitedStage(robot, payload, **kw)


def _acceleration_limited(
    robot: RobotModel,
    payload: RigidPayload | None,
    safety: Safety | None,
    *,
    sample_period_s: float,
    grid_points: int | None,
) -> TimingStage:
    """TOPP-RA alone (the controller period only matters to the sampler)."""
    kw: dict[str, Any] = dict(_grid(grid_points))
    if safety is not None:
        kw["safety"] = safety
    return ToppraStage(robot, payload, **kw)


@dataclass(frozen=True)
class StageEntry:
    """One registered timing stage.

    Attributes:
        name: Its name (``options.timing``).
        build: Builds the stage (:class:`StageBuilder`).
        binds_jerk: Whether the gate holds its profiles to the drive jerk limits (else the jerk check
            reports the peak and passes).
        needs_jerk_limits: Whether the robot description must give jerk limits for it.
    """

    name: TimingName
    build: StageBuilder
    binds_jerk: bool
    needs_jerk_limits: bool

    def factory(self, sample_period_s: float) -> TimingFactory:
        """The plan's factory ``(robot, payload, safety) -> TimingStage`` at the controller period."""

        def build(robot: Any, payload: Any, safety: Safety) -> TimingStage:
            return self.build(robot, payload, safety, sample_period_s=sample_period_s, grid_points=None)

        return build


#: Every timing stage, by name.
STAGES: dict[str, StageEntry] = {
    JERK_LIMITED: StageEntry(JERK_LIMITED, _jerk_limited, binds_jerk=True, needs_jerk_limits=True),
    ACCELERATION_LIMITED: StageEntry(
        ACCELERATION_LIMITED, _acceleration_limited, binds_jerk=False, needs_jerk_limits=False
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
