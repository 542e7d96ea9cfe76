"""The cycle profile document (JSON contract shared by the CLI and, later, the HTTP API).

Success: the plan document's success shape (:mod:`planner.documents.output`) with ``"kind": "cycle"`` and
``"cycle": {"name", "sha256"}`` instead of ``"scenario"``, plus::

    "leg":    [int] * N     the index into "legs" of every sample
    "legs":   [{"name", "kind": "motion" | "dwell", "payload": null | "<unit id>", "t_start_s", "t_end_s",
                "sample_start", "sample_end" (exclusive)}]   pre_grasp ... park, in order
    "events": [{"kind": "attach" | "detach", "t_s", "unit", "leg", "springback_m", "rotation_rad"}]

Refusal: ``{"kind": "cycle", "robot", "cycle": {"name", "sha256"}, "status": "failed", "reason", "message",
"details", "provenance"}``. Lengths are metres (``min_clearance_m``, ``springback_m``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from planner.core.exceptions import PlannerError
from planner.core.provenance import code_version
from planner.documents.output import _jsonable, _samples, provenance

if TYPE_CHECKING:
    from planner.task.cycle import CycleResult
    from planner.task.resolve import ResolvedCycle


def cycle_provenance(cyc: ResolvedCycle) -> dict[str, Any]:
    """Hashes of the cycle, robot description, cabin mesh and code a cycle's profile depends on."""
    base = provenance(cyc.base)
    return {
        "cycle_sha256": cyc.sha256,
        "robot_description_sha256": base["robot_description_sha256"],
        "cabin_mesh_sha256": base["cabin_mesh_sha256"],
        "cabin_source": base["cabin_source"],
        "stiffness": base["stiffness"],
        "code": code_version(),
    }


def _head(cyc: ResolvedCycle, status: str) -> dict[str, Any]:
    return {
        "kind": "cycle",
        "robot": cyc.robot.name,
        "cycle": {"name": cyc.spec.name, "sha256": cyc.sha256},
        "status": status,
    }


def cycle_document(cyc: ResolvedCycle, result: CycleResult, *, arrays: bool = False) -> dict[str, Any]:
    """The success document of a certified cycle (see the module docstring).

    Args:
        cyc: The resolved cycle.
        result: The certified cycle.
        arrays: Keep the sample arrays as numpy arrays (for ``document_bytes``); lists otherwise.
    """
    samples = result.profile.to_dict(arrays=True) if arrays else _samples(result.profile)
    leg = result.leg_of if arrays else result.leg_of.tolist()
    tail = {
        "min_clearance_m": result.gate.min_clearance_m,
        "legs": [x.to_dict() for x in result.legs],
        "events": [e.to_dict() for e in result.events],
        "report": result.report,
        "provenance": cycle_provenance(cyc),
    }
    return {**_head(cyc, "succeeded"), **samples, "leg": leg, **_jsonable(tail)}


def cycle_refusal_document(
    exc: PlannerError, cyc: ResolvedCycle | None, name: str | None = None
) -> dict[str, Any]:
    """The refusal document of a cycle: status ``failed``, the reason and its evidence (the leg named).

    Args:
        exc: The refusal.
        cyc: The resolved cycle; None when its input was refused before it resolved (no robot, hash or
            provenance then).
        name: The cycle's name as submitted, for an unresolved cycle.
    """
    if cyc is None:
        head = {"kind": "cycle", "robot": None, "cycle": {"name": name}, "status": "failed"}
        return _jsonable({**head, **exc.to_dict()})
    return _jsonable({**_head(cyc, "failed"), **exc.to_dict(), "provenance": cycle_provenance(cyc)})


def cycle_png(cyc: ResolvedCycle, result: CycleResult) -> bytes:
    """PNG bytes of a cycle's drive profile against its limits, the legs and events in the title.

    The plot is :func:`~planner.documents.plot.profile_png`'s.
    """
    from planner.documents.plot import profile_png

    legs = " | ".join(f"{x.name} {x.t_start_s:.1f}" for x in result.legs)
    events = ", ".join(f"{e.kind} {e.t_s:.2f} s ({1e3 * e.springback_m:.2f} mm)" for e in result.events)
    title = f"{cyc.spec.name}: {result.profile.duration_s:.2f} s\nlegs from [s]: {legs}\n{events}"
    return profile_png(result.profile, cyc.robot, title=title)
