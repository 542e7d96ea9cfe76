"""Robot models and their registry.

A robot is named in scenarios, the CLI and the API by its registry name. Adding a mechanism means adding
its description file, its model module, one entry in :data:`_FACTORIES` and, for the CLI's ``fk`` / ``ik``
and the API's ``/kinematics``, its tools module (a :class:`~planner.robots.base.KinematicsTools`) in
:data:`_TOOLS`; the front ends dispatch through :func:`kinematics_tools`, never by robot name.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from functools import lru_cache
from typing import cast

from planner.exceptions import InvalidInput, UnknownRobot
from planner.robots.base import DriveLimits, KinematicsTools, RobotModel


def _cabin8(rail_length: float | None) -> RobotModel:
    from planner.robots.cabin8 import Cabin8

    return Cabin8(rail_length=rail_length)


def _pprs6(rail_length: float | None) -> RobotModel:
    from planner.robots.pprs6 import Pprs6

    if rail_length is not None:
        raise InvalidInput("rail_length: the pprs6 platform has no rail", field="rail_length")
    return Pprs6()


_FACTORIES: dict[str, Callable[[float | None], RobotModel]] = {"cabin8": _cabin8, "pprs6": _pprs6}


#: The kinematics tools module of each robot (imported on first use).
_TOOLS: dict[str, str] = {"cabin8": "planner.tools", "pprs6": "planner.robots.pprs6_tools"}


def kinematics_tools(name: str) -> KinematicsTools:
    """The FK / IK document functions of the robot registered under ``name``.

    Raises:
        UnknownRobot: no model of that name.
        InvalidInput: the model has no kinematics tools (``details['field'] = 'robot'``).
    """
    if name not in _FACTORIES:
        raise UnknownRobot(
            f"robot: unknown robot {name!r}; available: {', '.join(available_robots())}",
            robot=name,
            field="robot",
        )
    if name not in _TOOLS:
        raise InvalidInput(f"robot: {name!r} has no kinematics tools", field="robot", robot=name)
    return cast(KinematicsTools, importlib.import_module(_TOOLS[name]))


def available_robots() -> tuple[str, ...]:
    """Registry names of every robot model."""
    return tuple(sorted(_FACTORIES))


@lru_cache(maxsize=32)
def load_robot(name: str, rail_length: float | None = None) -> RobotModel:
    """The robot model registered under ``name`` (cached; models are immutable after construction).

    Raises:
        UnknownRobot: no model of that name.
    """
    try:
        factory = _FACTORIES[name]
    except KeyError:
        raise UnknownRobot(
            f"robot: unknown robot {name!r}; available: {', '.join(available_robots())}", robot=name
        ) from None
    return factory(rail_length)


__all__ = [
    "DriveLimits",
    "KinematicsTools",
    "RobotModel",
    "available_robots",
    "kinematics_tools",
    "load_robot",
]
