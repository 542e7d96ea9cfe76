"""Scene data of the operator viewer (``/viewer/``): a plan's bodies over time, its cabin as GLB, pprs6.

Every pose here comes from the planner's own robot model (:mod:`planner.documents.scene`); the page
only draws.

* ``GET /plans/{id}/scene``: for a succeeded plan the collision bodies posed per frame, the closest pair
  and its distance per frame, the start and goal payload poses, the approach line and the drive limits;
  for a refused one the configuration the refusal is about with its contacts (see
  :func:`planner.documents.scene.refusal_scene`). 409 while the plan is queued or running.
* ``GET /plans/{id}/cabin.glb``: the plan's cabin mesh in the robot base frame (metres, y up -- glTF's
  convention is the base frame's), made with trimesh. 404 for a plan in free space.
* ``POST /robots/pprs6/scene``: a pprs6 pose path (as ``POST /robots/pprs6/profiles``) -> its validated
  profile, the chain points per frame and the workspace at the path's first orientation as boundary points.

Scenes are immutable for a finished plan: they are computed once (about a second for a 400-frame plan:
the exact distance queries) and kept in a small in-process cache keyed by the plan's id and result hash.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict, Field

from api.auth import CurrentPrincipal
from api.context import AppContext
from api.db import ACTIVE_STATES, Job
from api.jobkinds import PLAN
from api.problems import Problem
from api.routes.deps import Ctx
from api.routes.inputs import empty_dir
from api.routes.jobroutes import result_json
from api.routes.pprs6 import Orientation, PosePath
from api.store import scenario_mesh_resolver
from planner.core.exceptions import InvalidInput, InvalidMesh
from planner.core.lru import BoundedLRU
from planner.scenario import ResolvedScenario, resolve_scenario, scenario_from_dict

router = APIRouter(tags=["viewer"])

_CACHE_SIZE = 16


_SCENES: BoundedLRU[str, bytes] = BoundedLRU(_CACHE_SIZE)
_GLBS: BoundedLRU[str, bytes] = BoundedLRU(4)


def _finished_job(ctx: AppContext, tenant: str, plan_id: str) -> Job:
    row = ctx.jobs.get(tenant, plan_id, PLAN)
    if row is None:
        raise Problem(404, "not_found", f"no plan {plan_id!r}")
    if row.status in ACTIVE_STATES:
        raise Problem(
            409, "not_finished", f"plan {plan_id} is {row.status}; its scene exists once it finishes"
        )
    return row


def _resolved(ctx: AppContext, row: Job) -> ResolvedScenario:
    """The job's scenario resolved again against the files it was planned with."""
    spec = scenario_from_dict(row.scenario, source="plan")
    with rebuilding_scene(f"plan {row.id}", "was its cabin deleted?"):
        meshes = ctx.store.local_files(dict(row.meshes))  # the files may have come through another instance
        return resolve_scenario(spec, base_dir=empty_dir(ctx), mesh_resolver=scenario_mesh_resolver(meshes))


@contextmanager
def rebuilding_scene(subject: str, hint: str) -> Iterator[None]:
    """Rebuild a finished job's scene inside: a mesh that cannot be read again is a 409 problem.

    Args:
        subject: The job, as the message names it (``"plan 3f2a..."``).
        hint: The likely cause, appended to the message (``"was its cabin deleted?"``).

    Raises:
        Problem: 409 ``scene_unavailable`` for an :class:`InvalidMesh`, :class:`InvalidInput` or
            ``OSError`` inside, naming the subject and the error.
    """
    try:
        yield
    except (InvalidMesh, InvalidInput, OSError) as exc:
        raise Problem(
            409, "scene_unavailable", f"{subject}: its scene cannot be rebuilt ({exc}); {hint}"
        ) from None


def _json(doc: Any) -> bytes:
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode()


def _scene_document(ctx: AppContext, row: Job) -> dict[str, Any]:
    from planner.documents.scene import plan_scene, refusal_scene
    from planner.timing.profile import DriveProfile

    found = result_json(ctx, row)
    result: dict[str, Any] = json.loads(found) if found else {}
    sc = _resolved(ctx, row)
    base: dict[str, Any] = {
        "plan_id": row.id,
        "status": row.status,
        "scenario": {"name": row.scenario_name, "sha256": row.provenance.get("scenario_sha256")},
        "provenance": row.provenance,
    }
    if row.status == "succeeded":
        prof = DriveProfile.from_dict(result, sc.robot)
        at = ((result.get("report") or {}).get("gate") or {}).get("min_clearance_at") or {}
        closest = at.get("sample")
        extra = (closest,) if isinstance(closest, int) and not isinstance(closest, bool) else ()
        return {**base, **plan_scene(sc, prof.joints, prof.t, extra_samples=extra)}
    reason = str(result.get("reason") or row.reason or row.status)
    details = result.get("details") or {}
    doc = refusal_scene(sc, reason, details if isinstance(details, dict) else {})
    return {
        **base,
        **doc,
        "reason": reason,
        "message": result.get("message") or row.message,
        "details": details,
    }


@router.get(
    "/plans/{plan_id}/scene",
    summary="The plan's 3D scene: bodies per frame, clearance per frame, poses, limits (viewer)",
    response_class=Response,
    responses={200: {"content": {"application/json": {}}}},
)
def get_scene(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """The scene document of a finished plan (see :mod:`planner.documents.scene`); 409 while it is active."""
    row = _finished_job(ctx, principal.tenant, plan_id)
    digest = hashlib.sha256(result_json(ctx, row) or b"").hexdigest()
    key = f"{row.id}:{row.status}:{digest}"
    body = _SCENES.get(key)
    if body is None:
        body = _json(_scene_document(ctx, row))
        _SCENES.put(key, body)
    return Response(body, media_type="application/json")


@router.get(
    "/plans/{plan_id}/cabin.glb",
    summary="The plan's cabin mesh as binary glTF (base frame, metres)",
    response_class=Response,
    responses={200: {"content": {"model/gltf-binary": {}}}},
)
def get_cabin_glb(plan_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """The cabin the plan was made in, as GLB (vertices in the robot base frame); 404 in free space."""
    import trimesh

    row = ctx.jobs.get(principal.tenant, plan_id, PLAN)
    if row is None:
        raise Problem(404, "not_found", f"no plan {plan_id!r}")
    sc = _resolved(ctx, row)
    if sc.cabin is None:
        raise Problem(404, "not_found", f"plan {plan_id} is planned in free space: it has no cabin")
    key = sc.cabin.sha256 + hashlib.sha256(np.ascontiguousarray(sc.cabin.T_base_mesh).tobytes()).hexdigest()
    body = _GLBS.get(key)
    if body is None:
        mesh = trimesh.Trimesh(vertices=sc.cabin.vertices, faces=sc.cabin.faces, process=False)
        exported = mesh.export(file_type="glb")
        assert isinstance(exported, bytes)
        body = exported
        _GLBS.put(key, body)
    return Response(body, media_type="model/gltf-binary")


class Pprs6SceneRequest(BaseModel):
    """A pose path (none: the paper's E-F-G-H-E) and the workspace grid step."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    path: PosePath | None = None
    workspace_step_m: Annotated[
        float, Field(ge=0.01, le=0.02, description="Grid step of the workspace search [m] (a display).")
    ] = 0.01


@lru_cache(maxsize=8)
def _workspace_points(orientation: Orientation, step_m: float) -> bytes:
    from planner.documents.scene import workspace_boundary_points
    from planner.tools import pprs6 as pprs6_tools

    ws, _ = pprs6_tools.search_workspace(orientation.model_dump(), step_m)
    return np.ascontiguousarray(workspace_boundary_points(ws.inside, ws.axes)).tobytes()


@router.post(
    "/robots/pprs6/scene",
    summary="pprs6 pose path -> profile, chain points per frame, workspace",
    tags=["pprs6"],
)
def pprs6_scene(body: Pprs6SceneRequest, _principal: CurrentPrincipal) -> Response:
    """The validated profile (as ``POST /robots/pprs6/profiles``) and its scene (``planner.documents.scene``).

    A path the profile tool refuses gives its 422 (reason and evidence); the workspace is the one at the
    orientation of the path's first waypoint.
    """
    from planner.documents.scene import pprs6_scene as scene_of
    from planner.robots import load_robot
    from planner.robots.pprs6 import Pprs6
    from planner.tools import pprs6 as pprs6_tools

    spec = None if body.path is None else body.path.model_dump(exclude_none=True)
    profile = pprs6_tools.profile_document(spec)
    first = profile["pose"][0]
    orientation = Orientation(phi=first[3], theta=first[4], psi=first[5])
    points = np.frombuffer(_workspace_points(orientation, body.workspace_step_m)).reshape(-1, 3)
    robot = load_robot("pprs6")
    assert isinstance(robot, Pprs6)
    scene = scene_of(robot, profile, points)
    scene["workspace"]["orientation"] = orientation.model_dump()
    scene["workspace"]["step_m"] = body.workspace_step_m
    return Response(_json({"profile": profile, "scene": scene}), media_type="application/json")


__all__ = ["router"]
