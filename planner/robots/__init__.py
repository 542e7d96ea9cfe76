"""Robot models and their registry.

A robot is named in scenarios, the CLI and the API by its registry name. Adding a mechanism means adding
its description file, its model module, and one entry in :data:`_FACTORIES`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

from planner.exceptions import InvalidInput, UnknownRobot
from planner.robots.base import DriveLimits, RobotModel


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


__all__ = ["DriveLimits", "RobotModel", "available_robots", "load_robot"]
