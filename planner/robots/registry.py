"""The registry of robot models: a mechanism is named in scenarios, the CLI and the API by this name.

Adding a mechanism means adding its description file, its model module (a
:class:`~planner.robots.base.RobotModel`) and one entry in :data:`_FACTORIES`; its kinematics tools (the
CLI's ``fk`` / ``ik``, the API's ``/kinematics``) are registered in :mod:`planner.tools`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import TYPE_CHECKING

from planner.core.exceptions import InvalidInput, UnknownRobot
from planner.robots.base import RobotModel

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8


def _cabin8(rail_length: float | None) -> RobotModel:
    from planner.robots.cabin8 import Cabin8

    return Cabin8(rail_length=rail_length)


def _pprs6(rail_length: float | None) -> RobotModel:
    from planner.robots.pprs6 import Pprs6

    if rail_length is not None:
        raise InvalidInput("rail_length: the pprs6 platform has no rail", field="rail_length")
    return Pprs6()


_FACTORIES: dict[str, Callable[[float | None], RobotModel]] = {"cabin8": _cabin8, "pprs6": _pprs6}


def available_robots() -> tuple[str, ...]:
    """Registry names of every robot model."""
    return tuple(sorted(_FACTORIES))


def unknown_robot(name: str, **details: object) -> UnknownRobot:
    """The refusal for a robot name that is not registered (``details`` are added to its evidence)."""
    known = ", ".join(available_robots())
    return UnknownRobot(f"robot: unknown robot {name!r}; available: {known}", robot=name, **details)


@lru_cache(maxsize=32)
def load_robot(name: str, rail_length: float | None = None) -> RobotModel:
    """The robot model registered under ``name`` (cached; models are immutable after construction).

    Raises:
        UnknownRobot: no model of that name.
    """
    try:
        factory = _FACTORIES[name]
    except KeyError:
        raise unknown_robot(name) from None
    return factory(rail_length)


def tool_pose_robot(robot_name: str) -> Cabin8:
    """The model of ``robot_name`` if it has tool-pose kinematics (cabin8-type).

    Raises:
        UnknownRobot: no model of that name.
        InvalidInput: the model has no tool-pose kinematics in these tools (``details['field'] = 'robot'``).
    """
    from planner.robots.cabin8 import Cabin8

    model = load_robot(robot_name)
    if not isinstance(model, Cabin8):
        raise InvalidInput(
            f"robot {robot_name!r} has no tool-pose kinematics in this command",
            field="robot",
            robot=robot_name,
        )
    return model
