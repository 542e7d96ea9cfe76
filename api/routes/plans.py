"""Planning jobs: submit a scenario (202 + id), poll, fetch profile / plot, cancel, delete, list; the gate.

``POST /plans`` takes the scenario as JSON or YAML (``Content-Type: application/yaml``: the scenario
files of the CLI as they are), validates and resolves it (same schema as the CLI; ``cabin.mesh`` is a
reference cabin name or the id of one of the tenant's uploaded cabins), checks the planning time limit
ceiling and the tenant's quota, and commits the job (``queued``) *before* answering 202 with its id and
``Location``. An ``Idempotency-Key`` header makes a retry return the same job instead of planning twice.

Plans are jobs of kind :data:`api.jobkinds.PLAN`: these routes check the scenario and call the helpers
every job kind shares (:mod:`api.routes.jobroutes`), which call the job store (:mod:`api.jobstore`).
Results are stored packed (:mod:`api.compact`, about 5x smaller than the JSON text); the JSON document
(``GET /plans/{id}``), the CSV (``GET /plans/{id}/profile.csv``) and the plot (``plot.png``, kept once
made) are made from it on request. ``DELETE /plans/{id}`` cancels a queued or running plan and deletes
a finished one.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Query, Response
from starlette.concurrency import run_in_threadpool

from api.auth import CurrentPrincipal
from api.context import AppContext
from api.db import Job
from api.examples import docked
from api.jobkinds import PLAN
from api.jobstore import new_job
from api.openapi import scenario_request_body
from api.problems import problem_responses
from api.routes import jobroutes
from api.routes.deps import Ctx
from api.routes.inputs import MeshField, check_time_limit, empty_dir, stored_meshes
from api.store import scenario_mesh_resolver
from planner.scenario import ResolvedScenario, Scenario, resolve_scenario, scenario_from_dict

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


def job_document(row: Job, warming: str | None = None) -> dict[str, Any]:
    """The public document of a planning job (see :func:`api.routes.jobroutes.job_document`)."""
    return jobroutes.job_document(PLAN, row, warming)


def mesh_map(ctx: AppContext, tenant: str, spec: Scenario) -> dict[str, str]:
    """Stored files of the tenant's meshes the scenario names; 422 for any other mesh name."""
    fields: list[MeshField] = []
    if spec.cabin is not None:
        fields.append(("cabin.mesh", spec.cabin.mesh, spec.cabin.units, True))
    if spec.payload is not None and spec.payload.mesh is not None:
        fields.append(("payload.mesh", spec.payload.mesh, spec.payload.units, False))
    return stored_meshes(ctx, tenant, fields)


def _resolve(ctx: AppContext, tenant: str, body: Any) -> tuple[Scenario, ResolvedScenario, dict[str, str]]:
    spec = scenario_from_dict(body, source="request")
    check_time_limit(ctx, spec.options.time_limit_s)
    meshes = mesh_map(ctx, tenant, spec)
    resolved = resolve_scenario(spec, base_dir=empty_dir(ctx), mesh_resolver=scenario_mesh_resolver(meshes))
    return spec, resolved, meshes


@router.post(
    "/plans",
    status_code=202,
    summary="Submit a scenario (JSON or YAML) for planning",
    responses=jobroutes.REPLAY_RESPONSE,
    openapi_extra={"requestBody": scenario_request_body(_SCENARIO_DESCRIPTION, _SCENARIO_EXAMPLE)},
)
async def submit(
    ctx: Ctx, principal: CurrentPrincipal, submission: jobroutes.SubmissionDep
) -> dict[str, Any]:
    """Queue a planning job: 202 with the job document and ``Location``.

    The body is a scenario as ``application/json`` or ``application/yaml``. A body that cannot be parsed
    gives 400; invalid scenarios give 422 naming the field; a ``time_limit_s`` above the ceiling gives 422
    naming ``options.time_limit_s``; a tenant with too many queued + running jobs gets 429 with
    ``Retry-After``.
    """
    return await run_in_threadpool(
        jobroutes.submit_request, ctx, PLAN, principal.tenant, submission, _plan_job
    )


def _plan_job(ctx: AppContext, tenant: str, body: Any, key: str | None, request_sha256: str) -> Job:
    from planner.documents.output import provenance

    spec, resolved, meshes = _resolve(ctx, tenant, body)
    return new_job(
        PLAN,
        tenant,
        spec.model_dump(mode="json"),
        spec.name,
        request_sha256,
        meshes,
        provenance(resolved),
        spec.options.time_limit_s,
        key,
    )


@router.get("/plans", summary="List the tenant's plans (paged, newest first)")
def list_plans(
    ctx: Ctx,
    principal: CurrentPrincipal,
    status: Annotated[JobStatus | None, Query(description="Only plans in this state.")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 20,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> dict[str, Any]:
    """``{"items": [job, ...], "total", "limit", "offset"}`` without results."""
    return jobroutes.page(ctx, PLAN, principal.tenant, status, limit, offset)


@router.get(
    "/plans/{plan_id}",
    summary="A plan's status, progress, provenance and result",
    response_class=Response,
    responses={200: {"content": {"application/json": {}}}},
)
async def get_plan(
    plan_id: str, ctx: Ctx, principal: CurrentPrincipal, wait_s: jobroutes.WaitQuery = 0.0
) -> Response:
    """The job document; once finished, ``result`` is the drive profile or the refusal document.

    With ``wait_s`` the request waits for the plan to end (long poll: answered as soon as it does, or
    after ``wait_s`` with the plan still queued or running), so a client needs no polling loop. The
    result's JSON text is kept for recent plans (:mod:`api.results`), so reading it is cheap.
    """
    return await jobroutes.waited_answer(ctx, PLAN, principal.tenant, plan_id, wait_s)


@router.get(
    "/plans/{plan_id}/profile.csv",
    summary="The drive profile as CSV",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}, **problem_responses(409)},
)
def get_profile_csv(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """One row per sample: ``t_s``, then position, velocity, acceleration, effort of each drive."""
    return jobroutes.file_answer(ctx, PLAN, principal.tenant, plan_id, "profile.csv", "profile")


@router.get(
    "/plans/{plan_id}/plot.png",
    summary="Plot of the profile against the limits and of the clearance",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **problem_responses(409)},
)
def get_plot_png(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """Made from the stored profile on the first request (exact clearances: about a second), then kept."""
    return jobroutes.file_answer(ctx, PLAN, principal.tenant, plan_id, "plot.png", "plot")


@router.delete(
    "/plans/{plan_id}",
    summary="Cancel a queued or running plan; delete a finished one",
    responses={
        202: {"description": "Cancellation requested, the kill still pending"},
        204: {"description": "Deleted"},
        **problem_responses(409),
    },
)
def cancel_plan(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """Queued -> cancelled; running -> its worker is killed (on whichever instance runs it), cancelled.

    200 with the cancelled job; 202 when the kill of a running job is still pending after 10 s. A
    finished plan (succeeded, failed or cancelled) is deleted with its result and plot: 204.
    """
    return jobroutes.cancel_or_delete(ctx, PLAN, principal.tenant, plan_id)


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
