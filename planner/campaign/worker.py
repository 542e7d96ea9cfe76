"""What one cycle process of a campaign runs: a cycle document in, an outcome out (plain data, JSON-able).

The runner the sweep executors call for a campaign's cycles (:data:`planner.campaign.run.CYCLE_RUNNER`,
through :func:`planner.sweep.task.run_task`), in an embedded warm worker or a Ray task alike. It is the
cycle's own planning (:func:`planner.task.cycle.plan_cycle`) with the outcome shape of a sweep's plan
(:func:`planner.sweep.task.task_outcome`), so the driver records both the same way.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from planner.sweep.task import mesh_resolver, task_outcome

__all__ = ["cycle_outcome"]


def cycle_outcome(task: dict[str, Any], meshes: dict[str, Any] | None = None) -> dict[str, Any]:
    """Resolve and plan one cycle; the outcome, success or refusal (never an exception).

    Args:
        task: ``{"cycle": dict (a cycle document), "base_dir": str | None, "profile_path": str | None}``;
            with ``profile_path`` the document is written there by this process (atomic) instead of
            being returned.
        meshes: Mesh name -> file path or bytes, looked up before the default resolution (Ray).

    Returns:
        ``{"status", "reason", "message", "evidence" (JSON text of the refusal's details, cut at
        :data:`~planner.sweep.results.MAX_EVIDENCE_CHARS`), "duration_s", "min_clearance_m",
        "planning_time_s", "task_time_s", "document", "profile_written", "pid"}``.
    """
    from planner.documents.cycle import cycle_document, cycle_refusal_document
    from planner.documents.output import document_bytes
    from planner.task.cycle import plan_cycle
    from planner.task.resolve import ResolvedCycle, resolve_cycle
    from planner.task.schema import cycle_from_dict

    t0 = time.perf_counter()

    def resolve() -> ResolvedCycle:
        spec = cycle_from_dict(task["cycle"], source="campaign cycle")
        base_dir = Path(task["base_dir"]) if task.get("base_dir") else None
        return resolve_cycle(spec, base_dir=base_dir, mesh_resolver=mesh_resolver(meshes))

    def plan(cyc: ResolvedCycle) -> tuple[dict[str, Any], str]:
        result = plan_cycle(cyc)
        fields = {
            "message": f"{result.profile.duration_s:.3f} s, {len(result.profile.t)} samples",
            "duration_s": float(result.profile.duration_s),
            "min_clearance_m": float(result.gate.min_clearance_m),
            "planning_time_s": float(result.report.get("planning_time_s", time.perf_counter() - t0)),
        }
        return fields, document_bytes(cycle_document(cyc, result, arrays=True)).decode("utf-8")

    name = task["cycle"].get("name")
    return task_outcome(
        task,
        f"campaign cycle {name}",
        resolve,
        plan,
        lambda exc, cyc: cycle_refusal_document(exc, cyc, name=name),
        ("duration_s", "min_clearance_m"),
    )
