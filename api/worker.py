"""The child side of a planning job: runs in its own process, talks to the parent through a pipe.

The parent (:mod:`api.jobs`) sends nothing after start: the job description (scenario as submitted and
the tenant's mesh files it names) is the process argument. The child sends ``("progress", stage,
fraction)`` messages while planning and one ``("done", outcome)`` at the end; the parent writes
everything to the database. The plot and the packed result document (:mod:`api.compact`) are made
here, never in the server's event loop. The process arms its parent-death signal first, so it ends
with the service (:mod:`api.lifeline`).

Importing this module imports the planner, so the forkserver can preload it once and every job forks
warm.
"""

from __future__ import annotations

import json
import logging
import os
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from api.compact import pack_document
from api.lifeline import die_with_parent
from api.store import scenario_mesh_resolver
from planner.core.exceptions import PlannerError
from planner.documents.output import refusal_document, result_document
from planner.documents.plot import plan_png
from planner.plan.pipeline import Planner
from planner.scenario.resolve import ResolvedScenario, resolve_scenario
from planner.scenario.schema import scenario_from_dict

_LOG = logging.getLogger(__name__)


def plan_job(job: dict[str, Any], send: Any) -> dict[str, Any]:
    """Plan one job; the outcome ``{"status", "reason", "message", "document", "provenance", "csv", "png"}``.

    Args:
        job: ``{"id", "scenario" (dict as submitted), "meshes" ({id: path}), "empty_dir"}`` (and ``nice``,
            the niceness :func:`run_job` adds to the process).
        send: Called with ``(stage, fraction)`` as the planner's stages start.
    """
    sc: ResolvedScenario | None = None
    try:
        spec = scenario_from_dict(job["scenario"], source="scenario")
        sc = resolve_scenario(
            spec, base_dir=Path(job["empty_dir"]), mesh_resolver=scenario_mesh_resolver(job["meshes"])
        )
        planner = Planner(sc, send)
        result = planner.plan()
    except PlannerError as exc:
        name = job["scenario"].get("name") if isinstance(job["scenario"], dict) else None
        doc = refusal_document(exc, sc, name=name)
        return {
            "status": "failed",
            "reason": exc.reason,
            "message": exc.message,
            "document": json.dumps(doc),
            "provenance": doc.get("provenance"),
        }
    doc = result_document(sc, result)
    return {
        "status": "succeeded",
        "reason": None,
        "message": f"{sc.spec.name}: {result.profile.duration_s:.3f} s, {len(result.profile.t)} samples",
        "document": json.dumps(doc),
        "provenance": doc["provenance"],
        "csv": result.profile.to_csv(),
        "png": plan_png(sc, result, planner.world),
    }


def run_job(job: dict[str, Any], conn: Connection) -> None:
    """Process entry point: plan ``job`` and send progress and the outcome through ``conn``.

    The outcome carries the result document packed (``packed``), not its text, and no CSV (made on
    request from the document).
    """
    die_with_parent(job.get("server_pid"))

    def send(message: tuple[Any, ...]) -> None:
        try:
            conn.send(message)
        except OSError:  # the server is gone (its end of the pipe closed): its lease re-queues the job
            os._exit(0)  # quietly, before the parent-death signal: no traceback in the server's log

    def progress(stage: str, fraction: float) -> None:
        send(("progress", str(stage), float(fraction)))

    if job.get("nice"):
        os.nice(int(job["nice"]))  # planning yields the CPU to the service's event loop

    try:
        outcome = plan_job(job, progress)
    except Exception as exc:  # a bug in the planner: report it as a failed job, never hang
        _LOG.exception("job %s crashed", job.get("id"))
        outcome = {
            "status": "failed",
            "reason": "internal_error",
            "message": f"internal error: {type(exc).__name__}: {exc}",
            "document": None,
        }
    document = outcome.pop("document", None)
    outcome.pop("csv", None)
    outcome["packed"] = pack_document(document) if document is not None else None
    send(("done", outcome))
    conn.close()


__all__ = ["plan_job", "run_job"]
