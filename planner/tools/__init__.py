"""Kinematics tools of each robot (the CLI's ``fk`` / ``ik``, the API's ``/kinematics``).

Each robot's tools module is a :class:`~planner.robots.base.KinematicsTools`, held by the one robot
registry (:mod:`planner.robots.registry`): this module registers the built-in robots' tools (each imported
on first use) and front ends dispatch through :func:`kinematics_tools`, never by robot name.
"""

from __future__ import annotations

from planner.robots.base import KinematicsTools
from planner.robots.registry import kinematics_tools_of, register_tools


def _cabin8_tools() -> KinematicsTools:
    from planner.tools import cabin8

    return cabin8


def _pprs6_tools() -> KinematicsTools:
    from planner.tools import pprs6

    return pprs6


register_tools("cabin8", _cabin8_tools)
register_tools("pprs6", _pprs6_tools)


def kinematics_tools(name: str) -> KinematicsTools:
    """The FK / IK document functions of the robot registered under ``name``.

    Raises:
        UnknownRobot: no model of that name (``details['field'] = 'robot'``).
        InvalidInput: the model has no kinematics tools (``details['field'] = 'robot'``).
    """
    return kinematics_tools_of(name)


__all__ = ["kinematics_tools"]
