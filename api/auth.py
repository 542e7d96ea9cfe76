"""API-key authentication: each key belongs to one tenant; an admin key manages keys.

Clients send ``X-API-Key: <key>``. Keys are random 256-bit tokens (``cpk_...``); the database stores
only their SHA-256, which is sufficient for high-entropy secrets (no salt or slow hash is needed: a
table leak does not reveal keys that cannot be brute-forced). The admin key comes from
``CABINPLAN_ADMIN_KEY`` and is compared in constant time. Missing or unknown keys give 401, a tenant key
on an admin route gives 403, and another tenant's objects are simply not found (404). Every
authenticated request counts against its tenant's rate limit (:mod:`api.ratelimit`): 429 ``rate_limited``
with ``Retry-After`` beyond it. A key found valid is trusted for a second without asking the database
again (:mod:`api.keycache`); revoking it through this process takes effect at once, through another
instance sharing the database within that second.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import secrets
import uuid
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader
from sqlalchemy import select

from api.context import AppContext, get_context
from api.db import ApiKey, now_s
from api.problems import Problem
from api.ratelimit import retry_after_header

API_KEY_HEADER = "X-API-Key"
ADMIN_TENANT = "admin"

_header = APIKeyHeader(name=API_KEY_HEADER, auto_error=False, description="API key of a tenant (or admin).")


@dataclass(frozen=True)
class Principal:
    """Who is calling: the tenant every object is scoped to, and whether the key is the admin's."""

    tenant: str
    key_id: str
    admin: bool = False


def key_digest(key: str) -> str:
    """SHA-256 (hex) of an API key, as stored."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def new_key() -> str:
    """A fresh random API key (256 bits, URL-safe)."""
    return "cpk_" + secrets.token_urlsafe(32)


def create_key(ctx: AppContext, tenant: str, name: str = "", key: str | None = None) -> tuple[ApiKey, str]:
    """Store a new key for ``tenant``; returns the row and the secret (shown once, never stored)."""
    secret = key if key is not None else new_key()
    row = ApiKey(
        id=uuid.uuid4().hex, tenant=tenant, name=name, key_sha256=key_digest(secret), created_at=now_s()
    )
    with ctx.db.session() as s:
        s.add(row)
    return row, secret


def list_keys(ctx: AppContext) -> list[ApiKey]:
    """Every key's record, newest first."""
    with ctx.db.session() as s:
        return list(s.scalars(select(ApiKey).order_by(ApiKey.created_at.desc())).all())


def revoke_key(ctx: AppContext, key_id: str) -> bool:
    """Revoke the key ``key_id`` now (a revoked one stays revoked at its first time); ``False`` if unknown."""
    with ctx.db.session() as s:
        row = s.get(ApiKey, key_id)
        if row is None:
            return False
        if row.revoked_at is None:
            row.revoked_at = now_s()
    ctx.keys.clear()  # committed: no request of this process accepts it from now on
    return True


def ensure_key(ctx: AppContext, tenant: str, secret: str, name: str) -> None:
    """Store ``secret`` as a key of ``tenant`` unless it is already stored (the local default key)."""
    with ctx.db.session() as s:
        found = s.scalar(select(ApiKey).where(ApiKey.key_sha256 == key_digest(secret)))
        if found is None:
            s.add(
                ApiKey(
                    id=uuid.uuid4().hex,
                    tenant=tenant,
                    name=name,
                    key_sha256=key_digest(secret),
                    created_at=now_s(),
                )
            )


def _unauthorized(detail: str) -> Problem:
    return Problem(
        401, "unauthorized", detail, headers={"WWW-Authenticate": f'ApiKey header="{API_KEY_HEADER}"'}
    )


#: The tenant of the local default key that ``make serve`` creates on a loopback address.
LOCAL_TENANT = "local"


def is_loopback(host: str) -> bool:
    """Whether a host name or address is this machine's loopback."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def authenticate(
    request: Request,
    key: Annotated[str | None, Security(_header)],
) -> Principal:
    """The caller's principal from the ``X-API-Key`` header, counted against its tenant's rate limit.

    Raises:
        Problem: 401 when the header is missing, or the key is unknown or revoked; 429 when the tenant
            is over its rate limit.
    """
    principal = _principal(request, key)
    record = request.scope.get("cabinplan.log")
    if isinstance(record, dict):
        record["tenant"] = principal.tenant
    ctx = get_context(request)
    wait_s = ctx.limiter.hit(principal.tenant)
    if wait_s is not None:
        ctx.metrics.rate_limited.inc()
        raise Problem(
            429,
            "rate_limited",
            f"tenant {principal.tenant!r} is over its rate limit of {ctx.settings.rate_limit}; retry later",
            headers={"Retry-After": retry_after_header(wait_s)},
            limit=ctx.settings.rate_limit,
        )
    return principal


def _principal(request: Request, key: str | None) -> Principal:
    if not key:
        raise _unauthorized(f"missing API key (send the {API_KEY_HEADER} header)")
    ctx = get_context(request)
    admin = ctx.settings.admin_key
    if admin is not None and hmac.compare_digest(key.encode(), admin.get_secret_value().encode()):
        return Principal(tenant=ADMIN_TENANT, key_id="admin", admin=True)
    digest = key_digest(key)
    known = ctx.keys.get(digest)
    if known is None:
        with ctx.db.session() as s:
            row = s.scalar(select(ApiKey).where(ApiKey.key_sha256 == digest, ApiKey.revoked_at.is_(None)))
            if row is None:
                raise _unauthorized("invalid or revoked API key")
            known = (row.tenant, row.id)
        ctx.keys.put(digest, *known)
    tenant, key_id = known
    if tenant == LOCAL_TENANT and not is_loopback(request.client.host if request.client else ""):
        raise _unauthorized("the local default key is accepted from this machine (loopback) only")
    return Principal(tenant=tenant, key_id=key_id)


def require_admin(principal: Annotated[Principal, Depends(authenticate)]) -> Principal:
    """The admin principal, or 403 for a tenant key."""
    if not principal.admin:
        raise Problem(403, "forbidden", "this route needs the admin key")
    return principal


CurrentPrincipal = Annotated[Principal, Depends(authenticate)]
AdminPrincipal = Annotated[Principal, Depends(require_admin)]

__all__ = [
    "ADMIN_TENANT",
    "LOCAL_TENANT",
    "API_KEY_HEADER",
    "AdminPrincipal",
    "CurrentPrincipal",
    "Principal",
    "authenticate",
    "create_key",
    "ensure_key",
    "is_loopback",
    "key_digest",
    "new_key",
    "require_admin",
]
