"""Assembly cycles and campaigns as jobs: submit (202 + id), poll, files, scene, cancel, delete, list.

``POST /cycles`` takes a cycle document (:class:`planner.task.schema.Cycle`, JSON or YAML, the CLI's file as
it is); ``POST /campaigns`` a campaign (:class:`planner.task.campaign_schema.Campaign`). Mesh names resolve
through the service's mesh store like a scenario's: ``cabin.mesh`` is a reference cabin name or the id of
one of the tenant's uploaded meshes, every other mesh (an installed unit's, the unit's, a fixture's) an
uploaded id; no file of the server is ever named by a request. The document is validated and resolved
before it is queued, so bad input is a 422 naming the field (overlapping installed units name both, a bay
already occupied names the unit there, a unit on its dock overlapping its fixture names ``dock.pose``);
for a campaign :func:`planner.task.campaign.check_campaign` refuses what no order can install (two units
overlapping at their installed poses: ``units``, both named; a unit's own bad cycle: ``units[k].<field>``).

Both are jobs of the one job machinery (:mod:`api.jobkinds` ``CYCLE`` and ``CAMPAIGN``; the helpers of
:mod:`api.routes.jobroutes`): the same tenants, quota (429), ``Idempotency-Key`` replay, cancellation
(``DELETE``), retention, progress and listing as plans. A cycle's job time limit is three times its
``options.time_limit_s`` (its three searched legs: pre-grasp, transit with insertion, park); a campaign's
is that times the most cycles it may plan (its units for ``order: given``; for ``order: find`` its
``search.max_cycles``, at most every (unit, installed set) state).

A campaign job's document carries ``units`` (each unit's status as it changes: waiting, planning, planned,
refused, not_planned); its finished cycles survive a server kill (:mod:`api.cycles`). Results: the JSON
document (``GET /<collection>/{id}``), ``profile.csv``, ``plot.png`` (and ``units.csv`` for a campaign),
and the operator page's ``scene`` and ``cabin.glb``.
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Response
from starlette.concurrency import run_in_threadpool

from api.auth import CurrentPrincipal
from api.context import AppContext
from api.db import ACTIVE_STATES, Job
from api.examples import aisle_campaign, aisle_cycle
from api.jobkinds import CAMPAIGN, CYCLE, JobKind
from api.jobstore import new_job
from api.openapi import SCENARIO_MEDIA_TYPES
from api.problems import Problem, problem_responses
from api.routes import jobroutes
from api.routes.deps import Ctx
from api.routes.inputs import MeshField, check_time_limit, empty_dir, stored_meshes
from api.routes.scene import rebuilding_scene
from api.store import scenario_mesh_resolver
from planner.core.lru import BoundedLRU

router = APIRouter(tags=["cycles"])

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
#: The list routes' query parameters (module level: the routes are made per kind, their annotations
#: resolve here).
StatusQuery = Annotated[JobStatus | None, Query(description="Only jobs in this state.")]
LimitQuery = Annotated[int, Query(ge=1, le=1000)]
OffsetQuery = Annotated[int, Query(ge=0, le=10**9)]
#: The searched legs of a cycle, each with the full ``options.time_limit_s`` (pre-grasp, transit, park).
SEARCHED_LEGS = 3


def _request_body(schema: str, description: str, example: dict[str, Any]) -> dict[str, Any]:
    content = {
        m: {"schema": {"$ref": f"#/components/schemas/{schema}"}, "example": example}
        for m in SCENARIO_MEDIA_TYPES
    }
    return {"required": True, "description": description, "content": content}


# ------------------------------------------------------------------------------------------ mesh names
def _mesh_fields(body: Any, prefix: str, cabin: bool) -> list[MeshField]:
    """``(field, name, units, may be a reference cabin)`` of every mesh a cycle-shaped mapping names."""
    out: list[MeshField] = []

    def add(where: str, node: Any, is_cabin: bool = False) -> None:
        if isinstance(node, dict) and isinstance(node.get("mesh"), str):
            out.append((f"{where}.mesh", node["mesh"], str(node.get("units", "m")), is_cabin))

    if cabin:
        add(f"{prefix}cabin", body.get("cabin"), True)
        for k, e in enumerate(body.get("installed") or []):
            add(f"{prefix}installed[{k}]", e)
    add(f"{prefix}unit", body.get("unit"))
    dock = body.get("dock")
    if isinstance(dock, dict):
        add(f"{prefix}dock.fixture", dock.get("fixture"))
    return out


# ---------------------------------------------------------------------------------------- submission
def _cycle_job(ctx: AppContext, tenant: str, body: Any, key: str | None, sha: str) -> Job:
    from planner.documents.cycle import cycle_provenance
    from planner.task.resolve import resolve_cycle
    from planner.task.schema import cycle_from_dict

    spec = cycle_from_dict(body, source="request")
    check_time_limit(ctx, float(spec.options.time_limit_s))
    meshes = stored_meshes(ctx, tenant, _mesh_fields(body, "", cabin=True))
    cyc = resolve_cycle(spec, base_dir=empty_dir(ctx), mesh_resolver=scenario_mesh_resolver(meshes))
    limit = SEARCHED_LEGS * float(spec.options.time_limit_s)
    doc = spec.model_dump(mode="json")
    return new_job(CYCLE, tenant, doc, spec.name, sha, meshes, cycle_provenance(cyc), limit, key)


def _campaign_cycles(campaign: Any) -> int:
    """The most cycles a campaign may plan (its job's time limit counts them)."""
    n = len(campaign.units)
    if campaign.order == "given":
        return n
    return int(min(campaign.search.max_cycles, n * 2 ** (n - 1)))


def _campaign_job(ctx: AppContext, tenant: str, body: Any, key: str | None, sha: str) -> Job:
    from planner.task.campaign import campaign_sha256, check_campaign
    from planner.task.campaign_schema import campaign_from_dict

    campaign = campaign_from_dict(body, source="request")
    check_time_limit(ctx, float(campaign.options.time_limit_s))
    fields = _mesh_fields(body, "", cabin=True)
    for k, u in enumerate(body.get("units") or []):
        if isinstance(u, dict):
            fields += _mesh_fields(u, f"units[{k}].", cabin=False)
    meshes = stored_meshes(ctx, tenant, fields)
    check_campaign(campaign, base_dir=empty_dir(ctx), mesh_resolver=scenario_mesh_resolver(meshes))
    limit = SEARCHED_LEGS * float(campaign.options.time_limit_s) * _campaign_cycles(campaign)
    provenance = {"campaign_sha256": campaign_sha256(campaign)}
    doc = campaign.model_dump(mode="json")
    return new_job(CAMPAIGN, tenant, doc, campaign.name, sha, meshes, provenance, limit, key)


@router.post(
    "/cycles",
    status_code=202,
    summary="Submit an assembly cycle (JSON or YAML) for planning",
    responses=jobroutes.REPLAY_RESPONSE,
    openapi_extra={
        "requestBody": _request_body(
            "Cycle",
            "An assembly cycle (the CLI's cycle file, see the README): cabin, installed units, the unit with "
            "its dock and bay, retract line, park posture, dwell times, gripper, options.",
            aisle_cycle(),
        )
    },
)
async def submit_cycle(
    ctx: Ctx, principal: CurrentPrincipal, submission: jobroutes.SubmissionDep
) -> dict[str, Any]:
    """Queue a cycle job: 202 with the job document and ``Location``.

    422 naming the field for an invalid or unresolvable cycle (overlapping installed units name both, an
    occupied bay names the unit there, a dock in collision with its fixture names ``dock.pose``); 429 over
    the tenant's quota.
    """
    return await run_in_threadpool(
        jobroutes.submit_request, ctx, CYCLE, principal.tenant, submission, _cycle_job
    )


@router.post(
    "/campaigns",
    status_code=202,
    summary="Submit a campaign (JSON or YAML): units installed one cycle each, in a given or found order",
    responses=jobroutes.REPLAY_RESPONSE,
    openapi_extra={
        "requestBody": _request_body(
            "Campaign",
            "A campaign (the CLI's campaign file, see the README): cabin, installed units, park posture, the "
            "units with their docks and bays, order (given or find), options.",
            aisle_campaign(),
        )
    },
)
async def submit_campaign(
    ctx: Ctx, principal: CurrentPrincipal, submission: jobroutes.SubmissionDep
) -> dict[str, Any]:
    """Queue a campaign job: 202 with the job document (its ``units`` appear as they start) and ``Location``.

    What no order can install is refused before the job is queued
    (:func:`planner.task.campaign.check_campaign`): 422 naming ``units`` and both units when two overlap
    at their installed poses, ``units[k].<field>`` for a unit's own bad cycle (a dock in collision with
    its fixture), or the campaign's own field.
    """
    return await run_in_threadpool(
        jobroutes.submit_request, ctx, CAMPAIGN, principal.tenant, submission, _campaign_job
    )


# ------------------------------------------------------------------------------ the shared job routes
def _file_route(kind: JobKind, name: str, what: str) -> Any:
    """The route function of one download of ``kind`` (its name bound here, not a parameter)."""

    def get_file(job_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
        return jobroutes.file_answer(ctx, kind, principal.tenant, job_id, name, what)

    return get_file


def _job_routes(kind: JobKind) -> None:
    """GET list, GET one, files, DELETE of ``kind`` (thin calls into :mod:`api.routes.jobroutes`)."""
    c, noun = kind.collection, kind.noun

    def list_jobs(
        ctx: Ctx,
        principal: CurrentPrincipal,
        status: StatusQuery = None,
        limit: LimitQuery = 20,
        offset: OffsetQuery = 0,
    ) -> dict[str, Any]:
        return jobroutes.page(ctx, kind, principal.tenant, status, limit, offset)

    async def get_job(
        job_id: str, ctx: Ctx, principal: CurrentPrincipal, wait_s: jobroutes.WaitQuery = 0.0
    ) -> Response:
        return await jobroutes.waited_answer(ctx, kind, principal.tenant, job_id, wait_s)

    def delete_job(job_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
        return jobroutes.cancel_or_delete(ctx, kind, principal.tenant, job_id)

    router.add_api_route(
        f"/{c}",
        list_jobs,
        methods=["GET"],
        summary=f"List the tenant's {c} (paged, newest first)",
        description='`{"items": [job, ...], "total", "limit", "offset"}` without results.',
    )
    router.add_api_route(
        f"/{c}/{{job_id}}",
        get_job,
        methods=["GET"],
        summary=f"A {noun}'s status, progress, provenance and result",
        description=f"The job document; once finished, `result` is the {noun}'s result document"
        + (
            " (the summary with `cycles`: the cycle documents in install order); while running, `units`: "
            "each unit's status."
            if kind is CAMPAIGN
            else " (the cycle profile document: legs, events) or its refusal."
        )
        + " With `wait_s` the request waits for the job to end (long poll).",
        response_class=Response,
        responses={200: {"content": {"application/json": {}}}},
    )
    for f in kind.files:
        what = {"profile.csv": "profile", "units.csv": "unit table", "plot.png": "plot"}[f.name]

        get_file = _file_route(kind, f.name, what)
        router.add_api_route(
            f"/{c}/{{job_id}}/{f.name}",
            get_file,
            methods=["GET"],
            summary=f"The {noun}'s {what} ({f.media_type.split(';')[0]})",
            response_class=Response,
            responses={200: {"content": {f.media_type.split(";")[0]: {}}}, **problem_responses(409)},
        )
    router.add_api_route(
        f"/{c}/{{job_id}}",
        delete_job,
        methods=["DELETE"],
        summary=f"Cancel a queued or running {noun}; delete a finished one",
        responses={
            202: {"description": "Cancellation requested, the kill still pending"},
            204: {"description": "Deleted"},
            **problem_responses(409),
        },
    )


# -------------------------------------------------------------------------------------------- scenes
#: Scene documents made lately, by job, status and result digest (a few MB each).
_SCENES: BoundedLRU[str, bytes] = BoundedLRU(8)


def _finished(ctx: AppContext, kind: JobKind, tenant: str, job_id: str) -> Job:
    row = jobroutes.tenant_job(ctx, kind, tenant, job_id)
    if row.status in ACTIVE_STATES:
        raise Problem(
            409, "not_finished", f"{kind.noun} {job_id} is {row.status}; its scene exists once it finishes"
        )
    return row


def _planned(ctx: AppContext, row: Job, cycle: dict[str, Any], doc: dict[str, Any]) -> Any:
    import numpy as np

    from planner.documents.scene import PlannedCycle
    from planner.task.resolve import resolve_cycle
    from planner.task.schema import cycle_from_dict
    from planner.timing.profile import DriveProfile

    meshes = ctx.store.local_files(dict(row.meshes))
    cyc = resolve_cycle(
        cycle_from_dict(cycle, source="cycle"),
        base_dir=empty_dir(ctx),
        mesh_resolver=scenario_mesh_resolver(meshes),
    )
    prof = DriveProfile.from_dict(doc, cyc.robot)
    return PlannedCycle(
        cyc, prof.joints, prof.t, np.asarray(doc["leg"], dtype=np.int64), doc["legs"], doc["events"]
    )


def _scene_document(ctx: AppContext, kind: JobKind, row: Job) -> dict[str, Any]:
    from planner.documents.scene import task_scene
    from planner.task.campaign import cycle_document
    from planner.task.campaign_schema import campaign_from_dict

    found = jobroutes.result_json(ctx, row)
    result: dict[str, Any] = json.loads(found) if found else {}
    base = {
        "job_id": row.id,
        "status": row.status,
        kind.input_key: {"name": row.scenario_name, "sha256": row.provenance.get(f"{kind.input_key}_sha256")},
        "reason": row.reason,
        "message": row.message,
    }
    with rebuilding_scene(f"{kind.noun} {row.id}", "was a mesh deleted?"):
        if kind is CYCLE:
            if row.status != "succeeded":
                return {**base, "kind": "refusal", "details": result.get("details"), "frames": None}
            return {**base, **task_scene([_planned(ctx, row, dict(row.scenario), result)])}
        campaign = campaign_from_dict(dict(row.scenario), source="campaign")
        units = result.get("units") or [{"id": u, "status": row.status} for u in campaign.ids]
        planned = []
        docs = [d for d in result.get("cycles", []) if d.get("status") == "succeeded"]
        for entry in [u for u in units if u.get("status") == "planned"]:
            cycle = cycle_document(campaign, entry["id"], entry.get("installed_before") or [])
            doc = next(d for d in docs if any(e["unit"] == entry["id"] for e in d["events"]))
            planned.append(_planned(ctx, row, cycle, doc))
        if not planned:
            return {**base, "kind": "refusal", "units": units, "frames": None, "details": None}
        return {
            **base,
            **task_scene(planned, units, kind="campaign"),
            "summary_message": result.get("message"),
        }


def _scene(kind: JobKind, ctx: AppContext, tenant: str, job_id: str) -> Response:
    row = _finished(ctx, kind, tenant, job_id)
    digest = hashlib.sha256(jobroutes.result_json(ctx, row) or b"").hexdigest()
    key = f"{row.id}:{row.status}:{digest}"
    body = _SCENES.get(key)
    if body is None:
        body = json.dumps(_scene_document(ctx, kind, row), allow_nan=False, separators=(",", ":")).encode()
        _SCENES.put(key, body)
    return Response(body, media_type="application/json")


def _cabin_glb(kind: JobKind, ctx: AppContext, tenant: str, job_id: str) -> Response:
    import trimesh

    from planner.scenario.resolve import resolve_scenario
    from planner.scenario.schema import scenario_from_dict

    row = jobroutes.tenant_job(ctx, kind, tenant, job_id)
    data = dict(row.scenario)
    park = data["park"]
    spec = scenario_from_dict(
        {
            "name": "cabin",
            "robot": data.get("robot", "cabin8"),
            "cabin": data["cabin"],
            "start": park,
            "goal": park,
        }
    )
    with rebuilding_scene(f"{kind.noun} {row.id}", "was its cabin deleted?"):
        meshes = ctx.store.local_files(dict(row.meshes))
        sc = resolve_scenario(spec, base_dir=empty_dir(ctx), mesh_resolver=scenario_mesh_resolver(meshes))
    assert sc.cabin is not None
    mesh = trimesh.Trimesh(vertices=sc.cabin.vertices, faces=sc.cabin.faces, process=False)
    exported = mesh.export(file_type="glb")
    assert isinstance(exported, bytes)
    return Response(exported, media_type="model/gltf-binary")


def _scene_routes(kind: JobKind) -> None:
    c, noun = kind.collection, kind.noun

    def get_scene(job_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
        return _scene(kind, ctx, principal.tenant, job_id)

    def get_glb(job_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
        return _cabin_glb(kind, ctx, principal.tenant, job_id)

    router.add_api_route(
        f"/{c}/{{job_id}}/scene",
        get_scene,
        methods=["GET"],
        tags=["viewer"],
        summary=f"The {noun}'s 3D scene: bodies and the unit per frame, legs and events, clearance (viewer)",
        description="See `planner.documents.scene.task_scene`; 409 while the job is active.",
        response_class=Response,
        responses={200: {"content": {"application/json": {}}}, **problem_responses(409)},
    )
    router.add_api_route(
        f"/{c}/{{job_id}}/cabin.glb",
        get_glb,
        methods=["GET"],
        tags=["viewer"],
        summary=f"The {noun}'s cabin mesh as binary glTF (base frame, metres)",
        response_class=Response,
        responses={200: {"content": {"model/gltf-binary": {}}}},
    )


for _kind in (CYCLE, CAMPAIGN):
    _job_routes(_kind)
    _scene_routes(_kind)


__all__ = ["SEARCHED_LEGS", "router"]
