"""Scenarios: the schema, the files, and their resolution into robot, geometry and vectors.

:mod:`~planner.scenario.schema` (pydantic models), :mod:`~planner.scenario.files` (YAML / JSON reading),
:mod:`~planner.scenario.resolve` (robot model, meshes, start and goal vectors and transforms).
"""

from planner.scenario.files import MAX_SCENARIO_BYTES, SCENARIO_EXTENSIONS, load_scenario_file
from planner.scenario.resolve import MeshResolver, ResolvedScenario, load_scenario, resolve_scenario
from planner.scenario.schema import MAX_SEED, PlanOptions, Scenario, scenario_from_dict, scenario_hash

__all__ = [
    "MAX_SCENARIO_BYTES",
    "MAX_SEED",
    "SCENARIO_EXTENSIONS",
    "MeshResolver",
    "PlanOptions",
    "ResolvedScenario",
    "Scenario",
    "load_scenario",
    "load_scenario_file",
    "resolve_scenario",
    "scenario_from_dict",
    "scenario_hash",
]
