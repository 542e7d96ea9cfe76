"""Cabin meshes: upload (multipart), list, get, delete; the reference cabins are always listed.

A cabin's id is the SHA-256 of its bytes (reference cabins: their name). Scenarios name a cabin by that
id or by a reference name in ``cabin.mesh``.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from fastapi import APIRouter, File, Form, Query, Response, UploadFile

from api.auth import CurrentPrincipal
from api.problems import Problem, problem_responses
from api.routes.deps import Ctx
from api.store import MeshInUse, mesh_document
from planner.meshes import reference_cabins, reference_manifest

router = APIRouter(tags=["cabins"])

_NAME = r"^[A-Za-z0-9._ -]{1,100}$"


def reference_document(name: str) -> dict[str, Any]:
    """The public description of a reference cabin (from the packaged manifest)."""
    entry = next(c for c in reference_manifest()["cabins"] if c["name"] == name)
    return {
        "id": name,
        "name": name,
        "description": entry.get("description", ""),
        "units": entry.get("units", "m"),
        "n_faces": entry.get("n_faces"),
        "bounds_min_m": entry.get("bounds_m", {}).get("min"),
        "bounds_max_m": entry.get("bounds_m", {}).get("max"),
        "sha256": entry.get("sha256", {}).get("stl"),
        "reference": True,
    }


@router.post(
    "/cabins",
    status_code=201,
    summary="Upload a cabin mesh (STL, OBJ, PLY, GLB/glTF) or CAD file (STEP)",
    responses={200: {"description": "The same bytes are already stored"}, **problem_responses(409)},
)
def upload_cabin(
    ctx: Ctx,
    principal: CurrentPrincipal,
    response: Response,
    file: Annotated[UploadFile, File(description="The mesh or STEP file; its extension selects the format.")],
    units: Annotated[
        Literal["m", "mm"],
        Form(description="Length unit of the file's coordinates (a STEP file's own units are used)."),
    ] = "m",
    name: Annotated[str | None, Form(pattern=_NAME, description="Display name (default: file name).")] = None,
) -> dict[str, Any]:
    """Validate and store a mesh by content hash: 201 when new, 200 when the same bytes are stored.

    Bad meshes give 422 with the loader's reason (``details.check``: ``face_count``, ``non_finite``,
    ``scale``, ...; for STEP also ``truncated``, ``self_reference``, ``step_timeout``, ``step_memory``);
    bodies above ``CABINPLAN_MAX_UPLOAD_BYTES`` give 413. A STEP file is read and tessellated (default
    tolerance 0.1 mm) by OpenCASCADE in a worker process with time and memory limits, never in the server.
    """
    filename = file.filename or ""
    data = file.file.read(ctx.settings.max_upload_bytes + 1)
    if len(data) > ctx.settings.max_upload_bytes:
        raise Problem(413, "payload_too_large", f"mesh larger than {ctx.settings.max_upload_bytes} bytes")
    display = name or re.sub(r"[^A-Za-z0-9._ -]", "_", filename)[:100] or "mesh"
    row, created = ctx.store.add(principal.tenant, data, filename, units, display)
    response.status_code = 201 if created else 200
    response.headers["Location"] = f"/api/v1/cabins/{row.sha256}"
    return mesh_document(row)


@router.get("/cabins", summary="Reference cabins and the tenant's uploaded cabins")
def list_cabins(
    ctx: Ctx,
    principal: CurrentPrincipal,
    limit: Annotated[int, Query(ge=1, le=1000)] = 50,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> dict[str, Any]:
    """``{"references": [...], "items": [...], "total", "limit", "offset"}`` (uploads newest first)."""
    limit = min(limit, ctx.settings.page_size_max)
    rows, total = ctx.store.list(principal.tenant, limit, offset)
    return {
        "references": [reference_document(n) for n in reference_cabins()],
        "items": [mesh_document(r) for r in rows],
        "total": total,
        "limit": limit,
        "offset": offset,
    }


@router.get("/cabins/{cabin_id}", summary="One cabin (reference name or uploaded id)")
def get_cabin(cabin_id: str, ctx: Ctx, principal: CurrentPrincipal) -> dict[str, Any]:
    """The cabin's description; another tenant's id is not found (404)."""
    if cabin_id in reference_cabins():
        return reference_document(cabin_id)
    row = ctx.store.get(principal.tenant, cabin_id)
    if row is None:
        raise Problem(404, "not_found", f"no cabin {cabin_id!r}")
    return mesh_document(row)


@router.delete(
    "/cabins/{cabin_id}",
    status_code=204,
    summary="Delete an uploaded cabin",
    responses=problem_responses(409),
)
def delete_cabin(cabin_id: str, ctx: Ctx, principal: CurrentPrincipal) -> Response:
    """Forget the tenant's cabin (204); reference cabins and those of active plans stay (409)."""
    if cabin_id in reference_cabins():
        raise Problem(409, "reference_cabin", f"{cabin_id!r} is a reference cabin and cannot be deleted")
    try:
        deleted = ctx.store.delete(principal.tenant, cabin_id)
    except MeshInUse as exc:
        raise Problem(409, "cabin_in_use", f"{exc}: cancel them or wait until they finish") from None
    if not deleted:
        raise Problem(404, "not_found", f"no cabin {cabin_id!r}")
    return Response(status_code=204)
