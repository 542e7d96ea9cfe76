"""The plan's output documents (JSON contract shared by the CLI and the HTTP API).

Success::

    {"robot", "scenario": {"name", "sha256"}, "status": "succeeded", "drives", "units", "sample_period_s",
     "t", "position", "velocity", "acceleration", "effort", "joints": {"names", "position"}, "duration_s",
     "min_clearance_m", "report": {...}, "provenance": {...}}

Refusal::

    {"robot", "scenario", "status": "failed", "reason", "message", "details", "provenance"}

Arrays are (N samples, 8 drives) in drive order, SI units.
"""

from __future__ import annotations

import math

from typing import TYPE_CHECKING, Any

import numpy as np

from planner.core.exceptions import PlannerError
from planner.core.provenance import code_version

if TYPE_CHECKING:
    from planner.plan.pipeline import PlanResult
    from planner.scenario.resolve import ResolvedScenario


def provenance(sc: ResolvedScenario) -> dict[str, Any]:
    """Hashes of the scenario, robot description, cabin mesh and code that a plan depends on."""
    return {
        "scenario_sha256": sc.scenario_sha256,
        "robot_description_sha256": sc.robot.description_sha256,
        "cabin_mesh_sha256": sc.cabin.sha256 if sc.cabin is not None else None,
        "cabin_source": sc.cabin_source,
        "stiffness": _stiffness(sc),
        "code": code_version(),
    }


def _stiffness(sc: ResolvedScenario) -> dict[str, Any]:
    from planner.gate.requirements import stiffness_provenance

    try:
        return stiffness_provenance(sc)
    except PlannerError as exc:  # an invalid compensation option: the refusal says why
        return {"model": None, "source": None, "compensated": False, "note": exc.message}


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        if all(type(v) is float for v in value):  # a row of samples: one pass, no call per element
            return [v if math.isfinite(v) else None for v in value]
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            return _jsonable(value.tolist())  # element by element: non-finite values become null
        if value.dtype.kind in "fiub":
            return value.tolist()  # Python floats, ints and bools throughout: no walk over the elements
        return _jsonable(value.tolist())
    if isinstance(value, np.floating | float):
        f = float(value)
        return f if np.isfinite(f) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def result_document(sc: ResolvedScenario, result: PlanResult) -> dict[str, Any]:
    """The success document of a validated plan."""
    doc: dict[str, Any] = {
        "robot": sc.robot.name,
        "scenario": {"name": sc.spec.name, "sha256": sc.scenario_sha256},
        "status": "succeeded",
    }
    doc.update(result.profile.to_dict())
    doc["min_clearance_m"] = result.gate.min_clearance_m
    doc["report"] = {**result.report, "gate": result.gate.to_dict()}
    doc["provenance"] = provenance(sc)
    return _jsonable(doc)


def refusal_document(
    exc: PlannerError, sc: ResolvedScenario | None = None, name: str | None = None
) -> dict[str, Any]:
    """The refusal document: status ``failed`` with the machine-readable reason and its evidence."""
    doc: dict[str, Any] = {
        "robot": sc.robot.name if sc is not None else None,
        "scenario": {"name": sc.spec.name, "sha256": sc.scenario_sha256}
        if sc is not None
        else {"name": name},
        "status": "failed",
        **exc.to_dict(),
    }
    if sc is not None:
        doc["provenance"] = provenance(sc)
    return _jsonable(doc)
