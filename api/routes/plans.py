"""Planning jobs: submit a scenario (202 + id), poll, fetch profile / plot, cancel, delete, list; the gate.

``POST /plans`` takes the scenario as JSON or YAML (``Content-Type: application/yaml``: the scenario
files of the CLI as they are), validates and resolves it (same schema as the CLI; ``cabin.mesh`` is a
reference cabin name or the id of one of the tenant's uploaded cabins), checks the planning time limit
ceiling and the tenant's quota, and commits the job (``queued``) *before* answering 202 with its id and
``Location``. An ``Idempotency-Key`` header makes a retry return the same job instead of planning twice.

Results are stored packed (:mod:`api.compact`, about 7x smaller than the JSON text); the JSON document
(``GET /plans/{id}``) and the CSV (``GET /plans/{id}/profile.csv``) are made from it on request.
``DELETE /plans/{id}`` cancels a queued or running plan and deletes a finished one.
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
import uuid
from collections import OrderedDict
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Header, Query, Request, Response
from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import IntegrityError
from starlette.concurrency import run_in_threadpool

from api.auth import CurrentPrincipal
from api.bodies import parse_body
from api.compact import unpack_document, unpack_text
from api.context import AppContext
from api.db import ACTIVE_STATES, TERMINAL_STATES, Job, now_s
from api.examples import docked
from api.jobs import rows_matched
from api.openapi import scenario_request_body
from api.problems import Problem, problem_responses
from api.routes.deps import Ctx
from api.store import scenario_mesh_resolver
from planner.meshes import reference_cabin_path, reference_cabins
from planner.robots import load_robot
from planner.robots.cabin8 import Cabin8
from planner.scenario import ResolvedScenario, Scenario, resolve_scenario, scenario_from_dict
from planner.timing.profile import DriveProfile

router = APIRouter(tags=["plans"])

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]

_SCENARIO_DESCRIPTION = (
    "A scenario (the CLI's schema, see the README), as JSON or YAML: robot, cabin (reference name or "
    "uploaded cabin id), payload, start, goal, options."
)

#: Example of a scenario body (a free rail move).
_SCENARIO_EXAMPLE: dict[str, Any] = {
    "name": "transfer",
    "robot": "cabin8",
    "start": docked(d1=1.0),
    "goal": docked(d1=2.0),
}


def _canonical_sha256(data: Any) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def job_document(row: Job, warming: str | None = None) -> dict[str, Any]:
    """The public job document (without the result: :func:`get_plan` adds it).

    Args:
        row: The job.
        warming: The runner's warm-up stage, shown as the stage of a queued job while it lasts.
    """
    base = f"/api/v1/plans/{row.id}"
    stage = warming if row.status == "queued" and warming is not None else row.stage
    doc: dict[str, Any] = {
        "id": row.id,
        "status": row.status,
        "stage": stage,
        "progress": row.progress,
        "scenario": {"name": row.scenario_name, "sha256": row.provenance.get("scenario_sha256")},
        "time_limit_s": row.time_limit_s,
        "attempts": row.attempts,
        "created_at": row.created_at,
        "started_at": row.started_at,
        "finished_at": row.finished_at,
        "reason": row.reason,
        "message": row.message,
        "provenance": row.provenance,
        "links": {"self": base},
    }
    if row.status == "succeeded":
        doc["links"].update(profile_csv=f"{base}/profile.csv", plot_png=f"{base}/plot.png")
    return doc


def _tenant_job(ctx: AppContext, tenant: str, job_id: str, *columns: Any) -> Job:
    with ctx.db.session() as s:
        row = s.scalar(select(Job).options(*columns).where(Job.id == job_id, Job.tenant == tenant))
    if row is None:
        raise Problem(404, "not_found", f"no plan {job_id!r}")
    return row


def _mesh_map(ctx: AppContext, tenant: str, spec: Scenario) -> dict[str, str]:
    """Stored files of the tenant's meshes the scenario names; 422 for any other mesh name."""
    meshes: dict[str, str] = {}
    names: list[tuple[str, str, str, bool]] = []
    if spec.cabin is not None:
        names.append(("cabin.mesh", spec.cabin.mesh, spec.cabin.units, True))
    if spec.payload is not None and spec.payload.mesh is not None:
        names.append(("payload.mesh", spec.payload.mesh, spec.payload.units, False))
    for field, name, units, cabin in names:
        if cabin and reference_cabin_path(name) is not None:
            continue
        row = ctx.store.get(tenant, name)
        if row is None:
            hint = f" nor a reference cabin ({', '.join(reference_cabins())})" if cabin else ""
            raise Problem(
                422,
                "invalid_input",
                f"{field}: {name!r} is neither the id of an uploaded cabin{hint}",
                errors=[{"field": field, "reason": "unknown mesh"}],
            )
        if row.units != units:
            units_field = field.replace(".mesh", ".units")
            raise Problem(
                422,
                "invalid_input",
                f"{units_field}: the mesh {name[:12]}... was uploaded in {row.units!r}, "
                f"the scenario says {units!r}",
                errors=[{"field": units_field, "reason": f"must be {row.units!r} for this mesh"}],
            )
        meshes[name] = str(ctx.store.local_path(row))
    return meshes


def _resolve(ctx: AppContext, tenant: str, body: Any) -> tuple[Scenario, ResolvedScenario, dict[str, str]]:
    spec = scenario_from_dict(body, source="request")
    ceiling = ctx.settings.time_limit_ceiling_s
    if spec.options.time_limit_s > ceiling:
        raise Problem(
            422,
            "invalid_input",
            f"options.time_limit_s: {spec.options.time_limit_s} s exceeds the service's ceiling of "
            f"{ceiling} s",
            errors=[{"field": "options.time_limit_s", "reason": f"must be at most {ceiling}"}],
        )
    meshes = _mesh_map(ctx, tenant, spec)
    empty = ctx.settings.data_dir / "empty"
    empty.mkdir(parents=True, exist_ok=True)
    resolved = resolve_scenario(spec, base_dir=empty, mesh_resolver=scenario_mesh_resolver(meshes))
    return spec, resolved, meshes


def _replay(
    ctx: AppContext, tenant: str, key: str, request_sha256: str, response: Response
) -> dict[str, Any] | None:
    with ctx.db.session() as s:
        row = s.scalar(select(Job).where(Job.tenant == tenant, Job.idempotency_key == key))
    if row is None:
        return None
    if row.request_sha256 != request_sha256:
        raise Problem(
            422,
            "idempotency_key_reused",
            "this Idempotency-Key was already used with a different request body",
            errors=[{"field": "Idempotency-Key", "reason": "reused with a different body"}],
            plan_id=row.id,
        )
    response.status_code = 200
    response.headers["Location"] = f"/api/v1/plans/{row.id}"
    response.headers["Idempotent-Replayed"] = "true"
    return job_document(row)


@router.post(
    "/plans",
    status_code=202,
    summary="Submit a scenario (JSON or YAML) for planning",
    responses={200: {"description": "Idempotent replay: the job of an earlier request with this key"}},
    openapi_extra={"requestBody": scenario_request_body(_SCENARIO_DESCRIPTION, _SCENARIO_EXAMPLE)},
)
async def submit(
    request: Request,
    ctx: Ctx,
    principal: CurrentPrincipal,
    response: Response,
    idempotency_key: Annotated[
        str | None,
        Header(alias="Idempotency-Key", max_length=200, description="Same key + same body = same job."),
    ] = None,
) -> dict[str, Any]:
    """Queue a planning job: 202 with the job document and ``Location``.

    The body is a scenario as ``application/json`` or ``application/yaml``. A body that cannot be parsed
    gives 400; invalid scenarios give 422 naming the field; a ``time_limit_s`` above the ceiling gives 422
    naming ``options.time_limit_s``; a tenant with too many queued + running jobs gets 429 with
    ``Retry-After``.
    """
    body = parse_body(await request.body(), request.headers.get("content-type"))
    return await run_in_threadpool(_submit, ctx, principal.tenant, response, body, idempotency_key)


def _submit(
    ctx: AppContext, tenant: str, response: Response, body: Any, idempotency_key: str | None
) -> dict[str, Any]:
    request_sha256 = _canonical_sha256(body)
    if idempotency_key is not None:
        replay = _replay(ctx, tenant, idempotency_key, request_sha256, response)
        if replay is not None:
            return replay
    spec, resolved, meshes = _resolve(ctx, tenant, body)
    from planner.documents.output import provenance

    # Count and insert in one transaction under the tenant's quota lock (every instance sharing the
    # database takes it), so concurrent submissions cannot pass the quota together.
    row = Job(
        id=uuid.uuid4().hex,
        tenant=tenant,
        status="queued",
        progress=0.0,
        scenario=spec.model_dump(mode="json"),
        scenario_name=spec.name,
        request_sha256=request_sha256,
        idempotency_key=idempotency_key,
        meshes=meshes,
        provenance=provenance(resolved),
        time_limit_s=float(spec.options.time_limit_s),
        attempts=0,
        created_at=now_s(),
    )
    limit = ctx.settings.tenant_max_active_jobs
    try:
        with ctx.db.tenant_quota_session(tenant) as s:
            active = int(
                s.scalar(
                    select(func.count())
                    .select_from(Job)
                    .where(Job.tenant == tenant, Job.status.in_(ACTIVE_STATES))
                )
                or 0
            )
            if active >= limit:
                raise Problem(
                    429,
                    "quota_exceeded",
                    f"{active} jobs queued or running; this tenant may have at most {limit} at a time",
                    headers={"Retry-After": str(ctx.settings.retry_after_s)},
                    active_jobs=active,
                    limit=limit,
                )
            s.add(row)
    except IntegrityError:  # a concurrent request with the same Idempotency-Key won the race
        if idempotency_key is None:
            raise
        replay = _replay(ctx, tenant, idempotency_key, request_sha256, response)
        if replay is None:
            raise
        return replay
    ctx.runner.wake()
    response.headers["Location"] = f"/api/v1/plans/{row.id}"
    return job_document(row)


@router.get("/plans", summary="List the tenant's plans (paged, newest first)")
def list_plans(
    ctx: Ctx,
    principal: CurrentPrincipal,
    status: Annotated[JobStatus | None, Query(description="Only plans in this state.")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 20,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> dict[str, Any]:
    """``{"items": [job, ...], "total", "limit", "offset"}`` without results."""
    limit = min(limit, ctx.settings.page_size_max)
    where = [Job.tenant == principal.tenant]
    if status is not None:
        where.append(Job.status == status)
    with ctx.db.session() as s:
        rows = s.scalars(
            select(Job).where(*where).order_by(Job.created_at.desc(), Job.id).limit(limit).offset(offset)
        ).all()
        total = s.scalar(select(func.count()).select_from(Job).where(*where)) or 0
    warming = ctx.runner.warming()
    items = [job_document(r, warming) for r in rows]
    return {"items": items, "total": int(total), "limit": limit, "offset": offset}


#: Decoded result texts of the last few plans read (finished results never change).
_RESULTS: OrderedDict[str, str] = OrderedDict()
_RESULTS_MAX = 8
_RESULTS_LOCK = threading.Lock()


def result_text(ctx: AppContext, row: Job) -> str | None:
    """The result document's JSON text (unpacked from storage, or a legacy text row), or ``None``."""
    if row.status in ACTIVE_STATES:
        return None
    with _RESULTS_LOCK:
        if row.id in _RESULTS:
            _RESULTS.move_to_end(row.id)
            return _RESULTS[row.id]
    with ctx.db.session() as s:
        packed, legacy = s.execute(
            select(Job.result_packed, Job.result_json).where(Job.id == row.id)
        ).one_or_none() or (None, None)
    text = unpack_text(packed) if packed is not None else legacy
    if text is not None:
        with _RESULTS_LOCK:
            _RESULTS[row.id] = text
            while len(_RESULTS) > _RESULTS_MAX:
                _RESULTS.popitem(last=False)
    return text


def _forget_result(job_id: str) -> None:
    with _RESULTS_LOCK:
        _RESULTS.pop(job_id, None)


@router.get(
    "/plans/{plan_id}",
    summary="A plan's status, progress, provenance and result",
    response_class=Response,
    responses={200: {"content": {"application/json": {}}}},
)
def get_plan(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """The job document; once finished, ``result`` is the drive profile or the refusal document.

    The stored result is unpacked into its JSON text once and spliced into the answer (a few recent
    results are kept decoded), so that polling stays cheap for the server.
    """
    row = _tenant_job(ctx, principal.tenant, plan_id)
    head = json.dumps(job_document(row, ctx.runner.warming()), allow_nan=False, separators=(",", ":"))
    body = f'{head[:-1]},"result":{result_text(ctx, row) or "null"}}}'
    return Response(body, media_type="application/json")


def _succeeded(ctx: AppContext, tenant: str, plan_id: str, what: str) -> Job:
    row = _tenant_job(ctx, tenant, plan_id)
    if row.status in ACTIVE_STATES:
        raise Problem(
            409, "not_finished", f"plan {plan_id} is {row.status}; the {what} exists once it succeeds"
        )
    if row.status != "succeeded":
        raise Problem(404, "not_found", f"plan {plan_id} {row.status}: it has no {what}")
    return row


def profile_csv(ctx: AppContext, row: Job) -> str | None:
    """The drive profile of a succeeded plan as CSV, made from its stored document (or a legacy CSV)."""
    with ctx.db.session() as s:
        packed, legacy = s.execute(
            select(Job.result_packed, Job.profile_csv).where(Job.id == row.id)
        ).one_or_none() or (None, None)
    if packed is None:
        return legacy
    doc = unpack_document(packed)
    robot = load_robot(str(doc["robot"]))
    if not isinstance(robot, Cabin8):  # planning jobs are cabin8 plans
        return None
    return DriveProfile.from_dict(doc, robot).to_csv()


@router.get(
    "/plans/{plan_id}/profile.csv",
    summary="The drive profile as CSV",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}, **problem_responses(409)},
)
def get_profile_csv(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """One row per sample: ``t_s``, then position, velocity, acceleration, effort of each drive."""
    row = _succeeded(ctx, principal.tenant, plan_id, "profile")
    csv = profile_csv(ctx, row)
    if csv is None:
        raise Problem(404, "not_found", f"plan {plan_id}: it has no profile")
    return Response(csv, media_type="text/csv; charset=utf-8")


@router.get(
    "/plans/{plan_id}/plot.png",
    summary="Plot of the profile against the limits and of the clearance",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **problem_responses(409)},
)
def get_plot_png(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """The plot made by the worker when the job finished."""
    row = _succeeded(ctx, principal.tenant, plan_id, "plot")
    with ctx.db.session() as s:
        png = s.scalar(select(Job.plot_png).where(Job.id == row.id))
    if png is None:
        raise Problem(404, "not_found", f"plan {plan_id}: it has no plot")
    return Response(png, media_type="image/png")


@router.delete(
    "/plans/{plan_id}",
    summary="Cancel a queued or running plan; delete a finished one",
    responses={
        202: {"description": "Cancellation requested, the kill still pending"},
        204: {"description": "Deleted"},
        **problem_responses(409),
    },
)
def cancel_plan(plan_id: str, ctx: Ctx, principal: CurrentPrincipal, response: Response) -> Response:
    """Queued -> cancelled; running -> its worker is killed (on whichever instance runs it), cancelled.

    200 with the cancelled job; 202 when the kill of a running job is still pending after 10 s. A
    finished plan (succeeded, failed or cancelled) is deleted with its result and plot: 204.
    """
    row = _tenant_job(ctx, principal.tenant, plan_id)
    if row.status in TERMINAL_STATES:
        with ctx.db.session() as s:
            s.execute(delete(Job).where(Job.id == plan_id, Job.status.in_(TERMINAL_STATES)))
        _forget_result(plan_id)
        return Response(status_code=204)
    with ctx.db.session() as s:
        cancelled = rows_matched(
            s.execute(
                update(Job)
                .where(Job.id == plan_id, Job.status == "queued")
                .values(
                    status="cancelled",
                    reason="cancelled",
                    message="cancelled by the client",
                    finished_at=now_s(),
                )
            )
        )
        if not cancelled:  # running: its owner (this instance or another) kills it at its next heartbeat
            s.execute(
                update(Job).where(Job.id == plan_id, Job.status == "running").values(cancel_requested=True)
            )
    if not cancelled:
        ctx.runner.cancel(plan_id)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            row = _tenant_job(ctx, principal.tenant, plan_id)
            if row.status in TERMINAL_STATES:
                break
            time.sleep(0.05)
    row = _tenant_job(ctx, principal.tenant, plan_id)
    status = 200
    if row.status in ACTIVE_STATES:  # the kill is still pending (e.g. the process is being started)
        status = 202
    elif row.status != "cancelled":
        raise Problem(409, "already_finished", f"plan {plan_id} {row.status} before it could be cancelled")
    body = json.dumps(job_document(row), allow_nan=False, separators=(",", ":"))
    return Response(body, status_code=status, media_type="application/json")


@router.post("/plans:validate", summary="Run the validation gate on a caller's drive profile")
def validate(
    ctx: Ctx,
    principal: CurrentPrincipal,
    scenario: Annotated[dict[str, Any], Body(description="The scenario the profile claims to solve.")],
    profile: Annotated[dict[str, Any], Body(description="A drive profile document (as GET /plans/{id}).")],
) -> dict[str, Any]:
    """The gate's report (``passed`` and every check); a profile that fails the gate is a 200 answer."""
    from planner.gate.check_profile import check_profile

    _, sc, _ = _resolve(ctx, principal.tenant, scenario)
    report = check_profile(sc, profile)
    out: dict[str, Any] = report.to_dict()
    return out
