"""The one registry of robots: each robot's model factory, kinematics tools and force model, by name.

A mechanism is named in scenarios, the CLI and the API by its registry name. Each :class:`RobotEntry`
holds the three things the planner needs of a robot:

- ``model``: builds its :class:`~planner.robots.base.RobotModel` (the entries of :data:`_ENTRIES` below);
- ``tools``: its single-shot kinematics documents (:class:`~planner.robots.base.KinematicsTools`, the CLI's
  ``fk`` / ``ik``, the API's ``/kinematics``);
- ``forces``: its inverse dynamics in drive space (:class:`~planner.robots.base.DriveDynamics`, the force
  model of the timing stages and the gate; None for a mechanism without masses, pprs6).

The tools and the force models are built by rooms above this one (``planner.tools`` builds documents with
the planner's stages; ``planner.dynamics`` compiles the Lagrange model), and an import never runs up a floor
(``tests/test_layering.py``): those rooms register typed callables here when they are imported
(:func:`register_tools` in :mod:`planner.tools`, :func:`register_forces` in :mod:`planner.dynamics.models`),
and the functions that look them up (:func:`planner.tools.kinematics_tools`,
:func:`planner.dynamics.models.drive_dynamics`) live in those same modules, so the registration has always
run before a lookup. Adding a mechanism: its description file, its model module, one entry in
:data:`_ENTRIES`, and its tools and force model registered beside the others.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from planner.core.exceptions import InvalidInput, UnknownRobot
from planner.robots.base import DriveDynamics, KinematicsTools, RobotModel

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8

#: Builds a robot's model for a rail length (None: the description's; refused by a robot without a rail).
ModelFactory = Callable[[float | None], RobotModel]
#: Returns a robot's kinematics tools (imported on first use).
ToolsFactory = Callable[[], KinematicsTools]
#: Returns the force model of one model object (built once per model).
ForceModelFactory = Callable[[RobotModel], DriveDynamics[Any]]


@dataclass(frozen=True)
class RobotEntry:
    """One registered robot.

    Attributes:
        name: Its registry name (scenarios' ``robot``, the CLI's and the API's robot argument).
        kind: The mechanism kind its model reports (:attr:`RobotModel.kind`): a model object finds its force
            model by it, whatever the name of its description.
        model: Builds the model.
        tools: Its kinematics tools (None: none registered).
        forces: Its force model (None: the mechanism has none; timed and gated without forces).
    """

    name: str
    kind: str
    model: ModelFactory
    tools: ToolsFactory | None = None
    forces: ForceModelFactory | None = None


def _cabin8(rail_length: float | None) -> RobotModel:
    from planner.robots.cabin8 import Cabin8

    return Cabin8(rail_length=rail_length)


def _pprs6(rail_length: float | None) -> RobotModel:
    from planner.robots.pprs6 import Pprs6

    if rail_length is not None:
        raise InvalidInput("rail_length: the pprs6 platform has no rail", field="rail_length")
    return Pprs6()


#: Every robot, by registry name (tools and force models are added by :func:`register_tools` and
#: :func:`register_forces`).
_ENTRIES: dict[str, RobotEntry] = {
    "cabin8": RobotEntry("cabin8", "hybrid8", _cabin8),
    "pprs6": RobotEntry("pprs6", "pprs6", _pprs6),
}


def available_robots() -> tuple[str, ...]:
    """Registry names of every robot model."""
    return tuple(sorted(_ENTRIES))


def unknown_robot(name: str, **details: object) -> UnknownRobot:
    """The refusal for a robot name that is not registered (``details`` are added to its evidence)."""
    known = ", ".join(available_robots())
    return UnknownRobot(f"robot: unknown robot {name!r}; available: {known}", robot=name, **details)


def entry(name: str, **details: object) -> RobotEntry:
    """The registry entry of ``name``.

    Raises:
        UnknownRobot: no robot of that name (``details`` added to its evidence).
    """
    try:
        return _ENTRIES[name]
    except KeyError:
        raise unknown_robot(name, **details) from None


def register_tools(name: str, tools: ToolsFactory) -> None:
    """Register the kinematics tools of the robot ``name`` (called by :mod:`planner.tools` on import)."""
    _ENTRIES[name] = replace(entry(name), tools=tools)


def register_forces(name: str, forces: ForceModelFactory) -> None:
    """Register the force model of the robot ``name`` (called by :mod:`planner.dynamics.models` on import)."""
    _ENTRIES[name] = replace(entry(name), forces=forces)


@lru_cache(maxsize=32)
def load_robot(name: str, rail_length: float | None = None) -> RobotModel:
    """The robot model registered under ``name`` (cached; models are immutable after construction).

    Raises:
        UnknownRobot: no model of that name.
    """
    return entry(name).model(rail_length)


def kinematics_tools_of(name: str) -> KinematicsTools:
    """The kinematics tools registered for the robot ``name``.

    Raises:
        UnknownRobot: no robot of that name (``details['field'] = 'robot'``).
        InvalidInput: the robot has no kinematics tools (``details['field'] = 'robot'``).
    """
    tools = entry(name, field="robot").tools
    if tools is None:
        raise InvalidInput(f"robot: {name!r} has no kinematics tools", field="robot", robot=name)
    return tools()


def force_model_of(robot: RobotModel) -> DriveDynamics[Any] | None:
    """The force model of a model object (the first entry of its mechanism kind that has one), or None."""
    for e in _ENTRIES.values():
        if e.kind == robot.kind and e.forces is not None:
            return e.forces(robot)
    return None


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
