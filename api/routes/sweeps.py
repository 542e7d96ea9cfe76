"""Feasibility sweeps: submit a sweep description (202 + id), poll its progress and summary, download results.

``POST /sweeps`` takes the description of ``cabinplan sweep`` (see the README) with the base scenario
inline (``cabin.mesh`` a reference cabin or one of the tenant's uploaded cabins; bays come from the
reference manifest). It expands and validates every plan (the service's time limit ceiling included)
before answering 202; the plans then run as ordinary planning jobs, fed into the queue by
:class:`api.sweeps.SweepFeeder` under the tenant's quota. ``GET /sweeps/{id}`` gives the counts and the
summary; ``results.csv`` and ``results.parquet`` the table (one row a plan, as the CLI writes it; the
``profile_file`` column links each plan's job). ``DELETE /sweeps/{id}`` cancels a running sweep (its plans
without a job are never fed, its queued jobs are cancelled and its running ones killed) and deletes an
ended one with its jobs, as ``DELETE /plans/{id}`` does for one plan.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from typing import Annotated, Any

from fastapi import APIRouter, Body, Response

from api.auth import CurrentPrincipal
from api.context import AppContext
from api.examples import aisle_bay_goal, docked
from api.openapi import BODY_SCHEMA_KEY
from api.problems import Problem, problem_responses
from api.routes.deps import Ctx
from api.routes.inputs import empty_dir
from api.routes.jobroutes import forget_result, result_text
from api.routes.plans import mesh_map
from api.store import scenario_mesh_resolver
from api.sweeps import Sweep, SweepStore, new_sweep
from planner.core.exceptions import InvalidInput
from planner.documents.output import provenance
from planner.scenario import resolve_scenario, scenario_from_dict
from planner.sweep.expand import SweepPlan, expand_sweep
from planner.sweep.results import csv_text, make_row, outcome_from_document, parquet_bytes
from planner.sweep.spec import sweep_from_dict

router = APIRouter(tags=["sweeps"])

_SWEEP_BODY = Body(
    description="A sweep description (the CLI's schema, see the README) with the base scenario inline.",
    examples=[
        {
            "name": "aisle-bays",
            "base": {
                "name": "bay",
                "cabin": {"mesh": "cabin-aisle"},
                "payload": {"box": [0.45, 0.35, 0.3], "mass": 60, "grasp": {"position": [0, 0, 0.2]}},
                "start": docked(),
                "goal": aisle_bay_goal(),
            },
            "axes": {"goal": {"bays": "all"}, "payload_mass_kg": [60, 90]},
        }
    ],
)


def _sweep_document(ctx: AppContext, row: Sweep) -> dict[str, Any]:
    base = f"/api/v1/sweeps/{row.id}"
    states = SweepStore(ctx.db).job_states(row.id)
    counts = Counter(status for status, _ in states)
    reasons = Counter(reason for status, reason in states if status in ("failed", "cancelled"))
    return {
        "id": row.id,
        "name": row.name,
        "status": row.status,
        "total": row.total,
        "progress": {
            "waiting": row.total - len(states),
            "queued": counts.get("queued", 0),
            "running": counts.get("running", 0),
            "succeeded": counts.get("succeeded", 0),
            "failed": counts.get("failed", 0),
            "cancelled": counts.get("cancelled", 0),
            "done": sum(counts.get(k, 0) for k in ("succeeded", "failed", "cancelled")),
        },
        "summary": {"succeeded": counts.get("succeeded", 0), "reasons": dict(sorted(reasons.items()))},
        "created_at": row.created_at,
        "finished_at": row.finished_at,
        "links": {
            "self": base,
            "results_csv": f"{base}/results.csv",
            "results_parquet": f"{base}/results.parquet",
        },
    }


def _tenant_sweep(ctx: AppContext, tenant: str, sweep_id: str) -> Sweep:
    row = SweepStore(ctx.db).get(tenant, sweep_id)
    if row is None:
        raise Problem(404, "not_found", f"no sweep {sweep_id!r}")
    return row


@router.post(
    "/sweeps",
    status_code=202,
    summary="Submit a feasibility sweep",
    openapi_extra={BODY_SCHEMA_KEY: "Sweep"},
)
def submit_sweep(
    ctx: Ctx,
    principal: CurrentPrincipal,
    response: Response,
    body: Annotated[dict[str, Any], _SWEEP_BODY],
) -> dict[str, Any]:
    """Expand and validate the sweep, store it ``running`` and answer 202 with its document.

    422 names the field: an invalid description, a base given as a file path, a bay manifest file, a
    plan over the time limit ceiling or naming an unknown mesh.
    """
    spec = sweep_from_dict(body, source="request")
    if isinstance(spec.base, str):
        raise InvalidInput("base: give the base scenario inline (the service reads no files)", field="base")
    if spec.bays.manifest is not None:
        raise InvalidInput(
            "bays.manifest: the service reads no files; bays come from the reference cabins' manifest",
            field="bays.manifest",
        )
    plans = expand_sweep(spec, None, absolute_meshes=False, max_plans=ctx.settings.sweep_max_plans)
    ceiling = ctx.settings.time_limit_ceiling_s
    for plan in plans:
        if plan.scenario.options.time_limit_s > ceiling:
            raise InvalidInput(
                f"plan {plan.index}: options.time_limit_s: {plan.scenario.options.time_limit_s} s exceeds "
                f"the service's ceiling of {ceiling} s",
                field="options.time_limit_s",
            )
    tenant = principal.tenant
    meshes = mesh_map(ctx, tenant, plans[0].scenario)  # the axes vary neither the cabin nor a mesh payload
    empty = empty_dir(ctx)
    resolved = resolve_scenario(
        plans[0].scenario, base_dir=empty, mesh_resolver=scenario_mesh_resolver(meshes)
    )
    stored = [
        {
            "index": p.index,
            "sha256": p.sha256,
            "scenario": p.scenario.model_dump(mode="json"),
            "labels": p.labels,
        }
        for p in plans
    ]
    row = new_sweep(
        tenant,
        spec.name,
        spec.model_dump(mode="json"),
        stored,
        {"meshes": meshes, "provenance": provenance(resolved)},
    )
    SweepStore(ctx.db).add(row)
    ctx.sweep_submitted()
    response.headers["Location"] = f"/api/v1/sweeps/{row.id}"
    return _sweep_document(ctx, row)


@router.get("/sweeps/{sweep_id}", summary="A sweep's progress and summary")
def get_sweep(sweep_id: str, ctx: Ctx, principal: CurrentPrincipal) -> dict[str, Any]:
    """Counts of the plans waiting for a job, queued, running and ended, and the outcome summary."""
    return _sweep_document(ctx, _tenant_sweep(ctx, principal.tenant, sweep_id))


@router.delete(
    "/sweeps/{sweep_id}",
    summary="Cancel a running sweep; delete an ended one",
    responses={
        202: {"description": "Cancelled, the kill of some running plans still pending"},
        204: {"description": "Deleted"},
        **problem_responses(404),
    },
)
def delete_sweep(sweep_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """Running -> cancelled: plans without a job are never fed, queued jobs cancelled, running ones killed.

    200 with the cancelled sweep's document; 202 when a kill is still pending after 10 s (DELETE again
    later). An ended sweep (finished or cancelled, every job ended) is deleted with its plans' jobs and
    results: 204.
    """
    row = _tenant_sweep(ctx, principal.tenant, sweep_id)
    store = SweepStore(ctx.db)
    job_ids = store.job_ids(row.id)
    if row.status != "running" and not ctx.jobs.active_of(job_ids):
        store.delete(row, job_ids)
        for job_id in job_ids:
            forget_result(job_id)
        return Response(status_code=204)
    running = store.cancel(row, "cancelled by the client (its sweep was cancelled)")
    for job_id in running:  # their owner (this instance or another) kills them at its next heartbeat
        ctx.runner.cancel(job_id)
    deadline = time.monotonic() + 10.0
    while running and ctx.jobs.active_of(running) and time.monotonic() < deadline:
        time.sleep(0.05)
    status = 202 if ctx.jobs.active_of(store.job_ids(row.id)) else 200
    doc = _sweep_document(ctx, _tenant_sweep(ctx, principal.tenant, sweep_id))
    body = json.dumps(doc, allow_nan=False, separators=(",", ":"))
    return Response(body, status_code=status, media_type="application/json")


def _rows(ctx: AppContext, row: Sweep) -> list[dict[str, Any]]:
    """Result rows of the plans whose job ended, in plan order."""
    links = SweepStore(ctx.db).links(row.id)
    by_id = {job.id: job for job in ctx.jobs.rows(list(links.values()))}
    jobs = {index: by_id[job_id] for index, job_id in links.items() if job_id in by_id}
    out = []
    for stored in row.plans["plans"]:
        job = jobs.get(int(stored["index"]))
        if job is None or job.status in ("queued", "running"):
            continue
        plan = SweepPlan(
            int(stored["index"]), scenario_from_dict(stored["scenario"]), stored["sha256"], stored["labels"]
        )
        outcome = outcome_from_document(job.status, job.reason, job.message, result_text(ctx, job))
        wall = (job.finished_at - job.started_at) if job.finished_at and job.started_at else None
        result = make_row(plan, outcome, wall if wall is not None else float("nan"), job.attempts)
        if wall is None:
            result["wall_time_s"] = None
        result["scenario_file"] = None
        result["profile_file"] = f"/api/v1/plans/{job.id}"
        out.append(result)
    return out


@router.get(
    "/sweeps/{sweep_id}/results.csv",
    summary="The sweep's result table as CSV",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}},
)
def get_results_csv(sweep_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """One row per plan whose job ended (the columns of the CLI's results.csv)."""
    row = _tenant_sweep(ctx, principal.tenant, sweep_id)
    return Response(csv_text(_rows(ctx, row)), media_type="text/csv; charset=utf-8")


@router.get(
    "/sweeps/{sweep_id}/results.parquet",
    summary="The sweep's result table as Parquet",
    response_class=Response,
    responses={200: {"content": {"application/vnd.apache.parquet": {}}}},
)
def get_results_parquet(sweep_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """The same table as Parquet (typed columns)."""
    row = _tenant_sweep(ctx, principal.tenant, sweep_id)
    return Response(parquet_bytes(_rows(ctx, row)), media_type="application/vnd.apache.parquet")


__all__ = ["router"]
