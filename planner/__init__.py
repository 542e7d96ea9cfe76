"""cabinplan: trajectory planning and redundancy control for cabin assembly robots.

The public API, what a library user imports (loaded on first use, so ``import planner`` stays cheap)::

    import planner

    sc = planner.load_scenario("tests/scenarios/aisle-bay-insert.yaml")
    result = planner.plan_scenario(sc)            # a validated PlanResult, or a PlannerError refusal
    result.profile.position                       # (N samples, 8 drives) [m, rad]
    report = planner.check_profile(sc, document)  # the validation gate on a profile document

Everything else is reachable through its room (``planner.kinematics``, ``planner.collision``, ...; see the
README's layout) but may change between versions.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

#: Public name -> the module that defines it.
_PUBLIC: dict[str, str] = {
    "__version__": "planner.core.provenance",
    # scenarios
    "Scenario": "planner.scenario.schema",
    "ResolvedScenario": "planner.scenario.resolve",
    "load_scenario": "planner.scenario.resolve",
    "resolve_scenario": "planner.scenario.resolve",
    "scenario_from_dict": "planner.scenario.schema",
    # planning
    "plan_scenario": "planner.plan.pipeline",
    "Planner": "planner.plan.pipeline",
    "PlanResult": "planner.plan.pipeline",
    "Clearances": "planner.plan.context",
    "SearchPreset": "planner.plan.context",
    # assembly cycles
    "Cycle": "planner.task.schema",
    "ResolvedCycle": "planner.task.resolve",
    "CycleResult": "planner.task.cycle",
    "load_cycle": "planner.task.resolve",
    "resolve_cycle": "planner.task.resolve",
    "cycle_from_dict": "planner.task.schema",
    "plan_cycle": "planner.task.cycle",
    "check_cycle": "planner.task.check",
    "cycle_document": "planner.documents.cycle",
    # gate
    "check_profile": "planner.gate.check_profile",
    "validate_profile": "planner.gate.checks",
    "GateReport": "planner.gate.checks",
    "GateRequirements": "planner.gate.requirements",
    # profiles and documents
    "DriveProfile": "planner.timing.profile",
    "result_document": "planner.documents.output",
    "refusal_document": "planner.documents.output",
    # robots and geometry
    "load_robot": "planner.robots.registry",
    "available_robots": "planner.robots.registry",
    "kinematics_tools": "planner.tools",
    "CollisionWorld": "planner.collision.world",
    "load_mesh": "planner.meshio",
    "Pose": "planner.core.schemas",
    # errors
    "PlannerError": "planner.core.exceptions",
    "PlanRefused": "planner.core.exceptions",
    "InvalidInput": "planner.core.exceptions",
    "ValidationFailed": "planner.core.exceptions",
}

if TYPE_CHECKING:
    from planner.collision.world import CollisionWorld
    from planner.core.exceptions import InvalidInput, PlannerError, PlanRefused, ValidationFailed
    from planner.core.schemas import Pose
    from planner.documents.cycle import cycle_document
    from planner.documents.output import refusal_document, result_document
    from planner.gate.check_profile import check_profile
    from planner.gate.checks import GateReport, validate_profile
    from planner.gate.requirements import GateRequirements
    from planner.meshio import load_mesh
    from planner.plan.context import Clearances, SearchPreset
    from planner.plan.pipeline import Planner, PlanResult, plan_scenario
    from planner.robots.registry import available_robots, load_robot
    from planner.scenario.resolve import ResolvedScenario, load_scenario, resolve_scenario
    from planner.scenario.schema import Scenario, scenario_from_dict
    from planner.task.check import check_cycle
    from planner.task.cycle import CycleResult, plan_cycle
    from planner.task.resolve import ResolvedCycle, load_cycle, resolve_cycle
    from planner.task.schema import Cycle, cycle_from_dict
    from planner.timing.profile import DriveProfile
    from planner.tools import kinematics_tools


def __getattr__(name: str) -> Any:
    """Import a public name on first use (PEP 562)."""
    try:
        module = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module 'planner' has no attribute {name!r}") from None
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return list(__all__)


__all__ = [
    "Clearances",
    "CollisionWorld",
    "Cycle",
    "CycleResult",
    "DriveProfile",
    "GateReport",
    "GateRequirements",
    "InvalidInput",
    "PlanRefused",
    "PlanResult",
    "Planner",
    "PlannerError",
    "Pose",
    "ResolvedCycle",
    "ResolvedScenario",
    "Scenario",
    "SearchPreset",
    "ValidationFailed",
    "__version__",
    "available_robots",
    "check_cycle",
    "check_profile",
    "cycle_document",
    "cycle_from_dict",
    "kinematics_tools",
    "load_cycle",
    "load_mesh",
    "load_robot",
    "load_scenario",
    "plan_cycle",
    "plan_scenario",
    "refusal_document",
    "resolve_cycle",
    "resolve_scenario",
    "result_document",
    "scenario_from_dict",
    "validate_profile",
]
