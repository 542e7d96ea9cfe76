"""RFC 9457 problem details: every error of the service is ``application/problem+json``.

A body has ``type`` (a URN naming the problem, ``urn:cabinplan:problem:<code>``), ``title``, ``status``,
``detail`` and, for 422, ``errors: [{field, reason}]`` with dotted field paths
(``options.time_limit_s``). One type per kind of error: a body that cannot be parsed (bad JSON or
YAML, not UTF-8) is 400 ``malformed_body`` whatever the route; any body over its limit is 413
``payload_too_large``; a stalled body is 408 ``body_timeout``; schema violations are 422
``invalid_input``. Planner errors add ``reason`` (the planner's machine-readable code) and
``details`` (its evidence). Unexpected exceptions become a 500 problem with the exception's type only:
never a stack trace.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from planner.core.exceptions import PlannerError

_LOG = logging.getLogger(__name__)

PROBLEM_JSON = "application/problem+json"


def problem_type(code: str) -> str:
    """The ``type`` URI of a problem code."""
    return f"urn:cabinplan:problem:{code}"


class Problem(Exception):
    """An HTTP error answered as problem+json.

    Args:
        status: HTTP status code.
        code: Short snake_case code; the body's ``type`` is ``urn:cabinplan:problem:<code>``.
        detail: Human-readable explanation of this occurrence.
        errors: For 422: ``[{"field": dotted.path, "reason": text}]``.
        headers: Extra response headers (e.g. ``Retry-After``).
        extra: Extension members added to the body.
    """

    def __init__(
        self,
        status: int,
        code: str,
        detail: str,
        *,
        errors: Sequence[Mapping[str, str]] | None = None,
        headers: Mapping[str, str] | None = None,
        **extra: Any,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.code = code
        self.detail = detail
        self.errors = [dict(e) for e in errors] if errors is not None else None
        self.headers = dict(headers or {})
        self.extra = extra

    def body(self) -> dict[str, Any]:
        """The problem document."""
        out: dict[str, Any] = {
            "type": problem_type(self.code),
            "title": _title(self.status),
            "status": self.status,
            "detail": self.detail,
        }
        if self.errors is not None:
            out["errors"] = self.errors
        out.update(self.extra)
        return out

    def response(self) -> JSONResponse:
        """The problem as a response."""
        return JSONResponse(
            self.body(), status_code=self.status, headers=self.headers, media_type=PROBLEM_JSON
        )


def _title(status: int) -> str:
    try:
        return HTTPStatus(status).phrase
    except ValueError:
        return "Error"


def _field(loc: Sequence[Any]) -> str:
    return ".".join(str(p) for p in loc)


def pydantic_errors(errors: Sequence[Mapping[str, Any]], drop_prefix: int = 0) -> list[dict[str, str]]:
    """``[{field, reason}]`` of pydantic error dicts, field paths dotted (after dropping a prefix)."""
    return [
        {"field": _field(list(e.get("loc", ()))[drop_prefix:]), "reason": str(e.get("msg", ""))}
        for e in errors
    ]


#: Kind of problem of each status the service answers with when nothing more specific applies.
STATUS_CODES: dict[int, str] = {
    400: "malformed_body",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    408: "body_timeout",
    409: "conflict",
    413: "payload_too_large",
    415: "unsupported_media_type",
    422: "invalid_input",
    429: "rate_limited",
    500: "internal_error",
    503: "not_ready",
}

#: OpenAPI schema of a problem document (``components.schemas.Problem``).
PROBLEM_SCHEMA: dict[str, Any] = {
    "title": "Problem",
    "type": "object",
    "description": "RFC 9457 problem details.",
    "required": ["type", "title", "status", "detail"],
    "properties": {
        "type": {"type": "string", "description": "urn:cabinplan:problem:<code>, one per kind of error."},
        "title": {"type": "string"},
        "status": {"type": "integer"},
        "detail": {"type": "string"},
        "errors": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {"field": {"type": "string"}, "reason": {"type": "string"}},
                "required": ["field", "reason"],
            },
        },
        "reason": {"type": "string", "description": "The planner's machine-readable reason."},
        "details": {"type": "object", "description": "The planner's evidence."},
    },
    "additionalProperties": True,
}

_DESCRIPTIONS = {
    400: "Malformed body (not JSON/YAML, not UTF-8)",
    401: "Missing, unknown or revoked API key",
    403: "The key may not use this route",
    404: "No such resource (or another tenant's)",
    408: "The request body was not sent in time",
    409: "Conflict with the resource's state",
    413: "Request body too large",
    415: "Unsupported Content-Type",
    422: "Invalid input (errors name the fields)",
    429: "Rate limit or quota exceeded (see Retry-After)",
    500: "Internal error",
    503: "Not ready",
}


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries of problem statuses (``application/problem+json``)."""
    return {
        status: {
            "description": _DESCRIPTIONS.get(status, _title(status)),
            "content": {PROBLEM_JSON: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        }
        for status in statuses
    }


def malformed_body(detail: str) -> Problem:
    """400 ``malformed_body``: the request body cannot be parsed."""
    return Problem(400, "malformed_body", detail, errors=[{"field": "body", "reason": detail}])


def from_planner_error(exc: PlannerError, status: int = 422) -> Problem:
    """A planner exception as a problem (422 by default) with ``reason``, ``details`` and ``errors``.

    ``errors`` lists every schema error the planner reported (``details['errors']``), else the one field
    it names (``details['field']``).
    """
    listed = exc.details.get("errors")
    if isinstance(listed, list) and listed:
        errors = [
            {"field": str(e.get("field", "")), "reason": str(e.get("message", e.get("reason", "")))}
            for e in listed
            if isinstance(e, Mapping)
        ]
    else:
        field = exc.details.get("field")
        errors = [{"field": str(field) if field else "", "reason": exc.message}]
    details = {k: v for k, v in exc.details.items() if k != "errors"}
    return Problem(
        status, exc.reason, exc.message, errors=errors, reason=exc.reason, details=_jsonable(details)
    )


def from_validation_error(exc: ValidationError, what: str) -> Problem:
    """A pydantic validation error of a named input (e.g. ``pose``) as a 422 problem."""
    errors = [
        {"field": ".".join(p for p in (what, _field(e["loc"])) if p), "reason": e["msg"]}
        for e in exc.errors()
    ]
    first = errors[0]
    return Problem(422, "invalid_input", f"{first['field']}: {first['reason']}", errors=errors)


def _jsonable(value: Any) -> Any:
    """Strict-JSON copy: mappings and sequences recursively, non-finite floats as ``None``."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, bool | str | int) or value is None:
        return value
    try:
        f = float(value)
    except (TypeError, ValueError):
        return str(value)
    return f if math.isfinite(f) else None


class SafeJSONResponse(JSONResponse):
    """JSON response that never fails on NaN/inf: such values (e.g. an infinite residual) become null."""

    def render(self, content: Any) -> bytes:
        """Strict JSON; values that are not JSON numbers are replaced by ``null``."""
        try:
            return json.dumps(content, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()
        except ValueError:
            return json.dumps(
                _jsonable(content), ensure_ascii=False, allow_nan=False, separators=(",", ":")
            ).encode()


def allowed_methods(app: Any, path: str) -> list[str]:
    """Every method some route of ``app`` answers at ``path`` (sorted; ``HEAD`` with ``GET``).

    FastAPI makes one route per operation, so the 405 Starlette raises lists only the methods of the
    first route whose path matched (``POST`` at ``/cabins``, which also answers ``GET``): the ``Allow``
    header of a 405 is made from every route instead (RFC 9110 section 15.5.6).
    """
    methods: set[str] = set()
    for route in app.router.routes:
        regex = getattr(route, "path_regex", None)
        if regex is not None and getattr(route, "methods", None) and regex.match(path):
            methods |= set(route.methods)
    return sorted(methods)


def install(app: FastAPI) -> None:
    """Register the exception handlers that turn every error into problem+json."""

    async def on_problem(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, Problem)
        return exc.response()

    async def on_request_validation(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        raw = list(exc.errors())
        if any(e.get("type") == "json_invalid" for e in raw):
            first_bad = next(e for e in raw if e.get("type") == "json_invalid")
            loc = list(first_bad.get("loc", ()))
            where = f" at byte {loc[-1]}" if loc and isinstance(loc[-1], int) else ""
            return malformed_body(f"request body: not valid JSON{where}").response()
        errors = []
        for e in raw:
            loc = list(e.get("loc", ()))
            if loc and loc[0] in ("body", "query", "path", "header"):
                loc = loc[1:] if loc[0] == "body" else loc
            errors.append({"field": _field(loc), "reason": str(e.get("msg", ""))})
        first = errors[0] if errors else {"field": "", "reason": "invalid request"}
        detail = f"{first['field']}: {first['reason']}" if first["field"] else first["reason"]
        return Problem(422, "invalid_input", detail, errors=errors).response()

    async def on_planner_error(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, PlannerError)
        return from_planner_error(exc).response()

    async def on_http(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        code = STATUS_CODES.get(exc.status_code, "http_error")
        detail = exc.detail if isinstance(exc.detail, str) else _title(exc.status_code)
        if exc.status_code == 404 and detail == "Not Found":
            detail = "no such resource"
        if exc.status_code == 400:
            return malformed_body(f"request body: {detail}").response()
        headers = dict(exc.headers or {})
        if exc.status_code == 405:  # every method of the path, not only those of the first route matched
            headers["Allow"] = ", ".join(allowed_methods(request.app, request.url.path))
        return Problem(exc.status_code, code, detail, headers=headers).response()

    async def on_unexpected(_request: Request, exc: Exception) -> JSONResponse:
        _LOG.exception("unexpected error")
        return Problem(500, "internal_error", f"internal error ({type(exc).__name__})").response()

    app.add_exception_handler(Problem, on_problem)
    app.add_exception_handler(RequestValidationError, on_request_validation)
    app.add_exception_handler(PlannerError, on_planner_error)
    app.add_exception_handler(StarletteHTTPException, on_http)
    app.add_exception_handler(Exception, on_unexpected)


__all__ = [
    "PROBLEM_JSON",
    "PROBLEM_SCHEMA",
    "STATUS_CODES",
    "allowed_methods",
    "malformed_body",
    "problem_responses",
    "Problem",
    "SafeJSONResponse",
    "from_planner_error",
    "from_validation_error",
    "install",
    "problem_type",
    "pydantic_errors",
]
