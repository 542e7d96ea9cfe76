"""API keys (admin only): create a tenant key (the secret is shown once), list, revoke."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict, Field

from api import auth
from api.auth import ADMIN_TENANT, LOCAL_TENANT, AdminPrincipal, create_key
from api.db import ApiKey
from api.problems import Problem, problem_responses
from api.routes.deps import Ctx

router = APIRouter(tags=["keys"], responses=problem_responses(403))


class KeyRequest(BaseModel):
    """A new key for a tenant."""

    model_config = ConfigDict(extra="forbid")

    tenant: Annotated[
        str, Field(pattern=r"^[a-z0-9][a-z0-9_-]{0,63}$", description="Tenant the key acts for.")
    ]
    name: Annotated[str, Field(max_length=100, description="What the key is for.")] = ""


def _doc(row: ApiKey) -> dict[str, Any]:
    return {
        "id": row.id,
        "tenant": row.tenant,
        "name": row.name,
        "created_at": row.created_at,
        "revoked_at": row.revoked_at,
    }


@router.post("/keys", status_code=201, summary="Create an API key for a tenant (admin)")
def create(body: KeyRequest, ctx: Ctx, _admin: AdminPrincipal) -> dict[str, Any]:
    """The new key's record with its secret in ``key`` (shown this once; only its hash is stored).

    The tenants ``admin`` and ``local`` (the loopback-only default key of ``make serve``) are reserved:
    422 naming ``tenant``.
    """
    if body.tenant in (ADMIN_TENANT, LOCAL_TENANT):
        raise Problem(
            422,
            "invalid_input",
            f"tenant: {body.tenant!r} is reserved",
            errors=[{"field": "tenant", "reason": "reserved"}],
        )
    row, secret = create_key(ctx, body.tenant, body.name)
    return {**_doc(row), "key": secret}


@router.get("/keys", summary="List API keys (admin; no secrets)")
def list_keys(ctx: Ctx, _admin: AdminPrincipal) -> dict[str, Any]:
    """Every key's record, newest first."""
    return {"items": [_doc(r) for r in auth.list_keys(ctx)]}


@router.delete("/keys/{key_id}", status_code=204, summary="Revoke an API key (admin)")
def revoke(key_id: str, ctx: Ctx, _admin: AdminPrincipal) -> Response:
    """Revoke the key at once (204); unknown ids give 404."""
    if not auth.revoke_key(ctx, key_id):
        raise Problem(404, "not_found", f"no key {key_id!r}")
    return Response(status_code=204)
