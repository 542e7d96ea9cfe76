"""The timing protocol: a :class:`TimingStage` turns a geometric path into a :class:`TimedPath`.

The geometric path (the joint path after smoothing: exactly the path the collision layer certified) is kept;
a stage only chooses the time law s(t). Adding a stage is one module implementing :class:`TimingStage`
plus one entry in the registry :mod:`planner.timing.stages` (and its name in
:data:`planner.core.timing_names.TimingName`); the sampler (:func:`planner.timing.profile.sample_legs`) and
the gate take any :class:`TimedPath`. The stages are :class:`planner.timing.jerk.JerkLimitedStage` (the
default with jerk limits) and the TOPP-RA adapter :class:`planner.timing.toppra.ToppraStage`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from planner.core.types import Array
from planner.timing.path import JointPath


class TimedPath(Protocol):
    """A geometric path with its time law s(t), at rest at both ends."""

    @property
    def path(self) -> JointPath:
        """The geometric path, unchanged by timing."""
        ...

    @property
    def duration(self) -> float:
        """Duration of the time law [s]."""
        ...

    def state(self, times: Array, order: int = 2) -> tuple[Array, ...]:
        """The path parameter and its time derivatives up to ``order`` at ``times`` (N,) in [0, duration].

        Returns:
            ``order + 1`` arrays (N,): s, sd, sdd (and sddd for ``order`` 3).
        """
        ...


class TimingStage(Protocol):
    """Turns a geometric joint path into a time law within the robot's drive limits."""

    name: str

    def time_path(self, path: JointPath) -> TimedPath:
        """The time law, rest to rest; raises :class:`~planner.core.exceptions.RetimingFailed` if none."""
        ...


#: Fractions of the (velocity, acceleration, force) limits a stage's time law may use.
Safety = tuple[float, float, float]
#: The fractions of a first timing, every stage's default (a re-timing after a limit failure tightens
#: them: :data:`planner.plan.retime.SAFETY_LEVELS`).
DEFAULT_SAFETY: Safety = (0.995, 0.97, 0.97)

#: Builds the timing stage of a plan: ``(robot, payload, safety) -> TimingStage``, ``safety`` the fractions
#: of the (velocity, acceleration, force) limits the stage may use.
TimingFactory = Callable[[Any, Any, Safety], TimingStage]
