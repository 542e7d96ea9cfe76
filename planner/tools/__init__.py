"""Kinematics tools of each robot (the CLI's ``fk`` / ``ik``, the API's ``/kinematics``) and their registry.

Each robot's tools module is a :class:`~planner.robots.base.KinematicsTools`; front ends dispatch through
:func:`kinematics_tools`, never by robot name.
"""

from __future__ import annotations

from typing import cast

from planner.core.exceptions import InvalidInput
from planner.robots.base import KinematicsTools
from planner.robots.registry import available_robots, unknown_robot

#: The kinematics tools module of each robot (imported on first use).
_TOOLS: dict[str, str] = {"cabin8": "planner.tools.cabin8", "pprs6": "planner.tools.pprs6"}


def kinematics_tools(name: str) -> KinematicsTools:
    """The FK / IK document functions of the robot registered under ``name``.

    Raises:
        UnknownRobot: no model of that name.
        InvalidInput: the model has no kinematics tools (``details['field'] = 'robot'``).
    """
    if name not in available_robots():
        raise unknown_robot(name, field="robot")
    if name not in _TOOLS:
        raise InvalidInput(f"robot: {name!r} has no kinematics tools", field="robot", robot=name)
    import importlib

    return cast(KinematicsTools, importlib.import_module(_TOOLS[name]))


__all__ = ["kinematics_tools"]
