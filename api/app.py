"""The FastAPI application: :func:`create_app` wires settings, database, mesh store, job runner and routers.

Routers live one per resource in :mod:`api.routes` and are mounted under ``/api/v1``; the OpenAPI
document is at ``/openapi.json`` and the interactive docs at ``/docs``. The lifespan creates the tables,
recovers jobs of instances that died (:func:`api.jobs.recover_jobs`), and starts / stops the runner.

Middleware, outermost first: :class:`AccessLogMiddleware` (request id, one structured log line per
request, request metrics), then :class:`BodyLimitMiddleware` (body size and body read timeout).
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import time
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api import problems
from api.context import AppContext
from api.db import Database
from api.jobs import JobRunner, ProcessJobRunner, recover_jobs
from api.jobstore import JobStore
from api.metrics import QueueCollector, ServiceMetrics
from api.openapi import install_openapi
from api.ratelimit import TenantRateLimiter
from api.routes import (
    cabins,
    cycles,
    exports,
    health,
    keys,
    kinematics,
    metrics,
    plans,
    pprs6,
    robots,
    scene,
    stiffness,
    sweeps,
)
from api.settings import Settings
from api.store import MeshStore
from api.sweeps import SweepFeeder
from planner import __version__
from planner.meshio import MeshLimits

_LOG = logging.getLogger(__name__)

API_PREFIX = "/api/v1"
#: Where the operator page is served, and the folder of its static files.
VIEWER_PATH = "/viewer"
VIEWER_DIR = Path(__file__).resolve().parent / "viewer"


class BodyTooLarge(StarletteHTTPException):
    """413: the request body is larger than its limit (raised while the body is streamed)."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than the limit of {limit} bytes")


class BodyTimeout(StarletteHTTPException):
    """408: the client declared a body and stopped sending it."""

    def __init__(self, timeout_s: float) -> None:
        super().__init__(408, f"no request body data for {timeout_s:g} s: the body was not sent in time")


#: Scope key of the per-request log record (``tenant`` is added by :func:`api.auth.authenticate`).
LOG_SCOPE_KEY = "cabinplan.log"
#: Accepted client-supplied request ids (else a fresh one is made).
_REQUEST_ID = re.compile(r"^[A-Za-z0-9._:-]{1,64}$")
ACCESS_LOG = logging.getLogger("api.access")


def _route_template(scope: Scope, templates: dict[int, str]) -> str:
    """The template of the route that served ``scope`` (``/api/v1/plans/{plan_id}``) or ``(unmatched)``."""
    route = scope.get("route")
    if route is None:
        return "(unmatched)"
    return templates.get(id(route)) or str(getattr(route, "path", "(unmatched)"))


class AccessLogMiddleware:
    """One structured (JSON) access-log line per request, a request id, and the request metrics.

    The line has ``time`` (UNIX s), ``request_id`` (the client's ``X-Request-ID`` when well-formed, else
    a new one; echoed in the response), ``method``, ``route`` (the route template, e.g.
    ``/api/v1/plans/{plan_id}``, or ``(unmatched)``: raw paths are never logged), ``status``,
    ``latency_ms``, ``tenant`` (after authentication) and ``client``.
    """

    def __init__(
        self, app: ASGIApp, metrics: ServiceMetrics, templates: dict[int, str] | None = None
    ) -> None:
        self.app = app
        self.metrics = metrics
        self.templates = templates if templates is not None else {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """ASGI entry."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        given = dict(scope.get("headers", [])).get(b"x-request-id", b"").decode("latin-1")
        request_id = given if _REQUEST_ID.match(given) else uuid.uuid4().hex
        record: dict[str, Any] = {}
        scope[LOG_SCOPE_KEY] = record
        status = 500

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
                headers = list(message.get("headers", []))
                headers.append((b"x-request-id", request_id.encode("latin-1")))
                message = {**message, "headers": headers}
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            latency = time.perf_counter() - t0
            route = _route_template(scope, self.templates)
            method = str(scope.get("method", ""))
            self.metrics.http_requests.labels(method=method, route=route, status=str(status)).inc()
            self.metrics.http_latency.labels(method=method, route=route).observe(latency)
            client = scope.get("client")
            ACCESS_LOG.info(
                json.dumps(
                    {
                        "time": round(time.time(), 3),
                        "event": "request",
                        "request_id": request_id,
                        "method": method,
                        "route": route,
                        "status": status,
                        "latency_ms": round(latency * 1000.0, 3),
                        "tenant": record.get("tenant"),
                        "client": client[0] if client else None,
                    },
                    separators=(",", ":"),
                )
            )


class BodyLimitMiddleware:
    """Counts the bytes of every request body as it streams in (not only Content-Length) -> 413.

    Mesh uploads (``POST /api/v1/cabins``) have their own, larger limit. While a body is still expected,
    each chunk must arrive within ``body_timeout_s`` (408 ``body_timeout`` otherwise), so a client that
    declares a body and stalls does not hold a connection and a worker thread for ever.
    """

    def __init__(
        self, app: ASGIApp, max_body_bytes: int, max_upload_bytes: int, body_timeout_s: float = 10.0
    ) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.max_upload_bytes = max_upload_bytes
        self.body_timeout_s = body_timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """ASGI entry: reject by Content-Length at once, else count the streamed bytes."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        upload = scope["method"] == "POST" and scope["path"].rstrip("/") == f"{API_PREFIX}/cabins"
        limit = self.max_upload_bytes if upload else self.max_body_bytes
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
                if declared > limit:
                    await problems.Problem(
                        413, "payload_too_large", f"request body of {declared} bytes exceeds {limit} bytes"
                    ).response()(scope, receive, send)
                    return
        seen = 0
        body_done = False

        async def limited_receive() -> Message:
            nonlocal seen, body_done
            if body_done:  # only the disconnect is left to wait for: no timeout
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), self.body_timeout_s)
            except TimeoutError:
                raise BodyTimeout(self.body_timeout_s) from None
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise BodyTooLarge(limit)
                body_done = not message.get("more_body", False)
            else:
                body_done = True
            return message

        await self.app(scope, limited_receive, send)


def create_app(settings: Settings | None = None, runner: JobRunner | None = None) -> FastAPI:
    """The service application.

    Args:
        settings: Configuration; default :class:`Settings` () from the environment.
        runner: Job runner; default a :class:`~api.jobs.ProcessJobRunner` on the same database.

    Returns:
        The FastAPI app; its lifespan starts and stops the runner.
    """
    settings = settings or Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    db = Database(settings.resolved_database_url(), settings.database_schema)
    store = MeshStore(
        db,
        settings.mesh_dir,
        MeshLimits(max_bytes=settings.max_upload_bytes, max_faces=settings.max_mesh_faces),
    )
    service_metrics = ServiceMetrics()
    job_runner: JobRunner = runner or ProcessJobRunner(db, settings, service_metrics)
    ctx = AppContext(
        settings=settings,
        db=db,
        store=store,
        runner=job_runner,
        metrics=service_metrics,
        limiter=TenantRateLimiter(
            settings.rate_limit, settings.rate_limit_storage_uri, settings.rate_limit_namespace
        ),
        jobs=JobStore(db),
    )
    service_metrics.registry.register(
        QueueCollector(ctx.jobs.queue_counts, job_runner.busy, lambda: job_runner.warming() is not None)
    )
    feeder = SweepFeeder(db, settings, job_runner)
    ctx.sweep_submitted = feeder.wake
    job_runner.on_job_end(ctx.waiters.notify)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        ctx.waiters.bind(asyncio.get_running_loop())
        db.create_all()
        recover_jobs(db)
        job_runner.start()
        feeder.start()
        try:
            yield
        finally:
            feeder.stop()
            job_runner.stop()
            db.dispose()

    app = FastAPI(
        title="cabinplan",
        version=__version__,
        description="Trajectory planning and redundancy control for cabin assembly robots. Every error "
        "is an RFC 9457 problem (application/problem+json). Authenticate with the X-API-Key header.",
        lifespan=lifespan,
        default_response_class=problems.SafeJSONResponse,
        docs_url="/docs",
        openapi_url="/openapi.json",
    )
    app.state.ctx = ctx
    problems.install(app)
    app.add_middleware(
        BodyLimitMiddleware,
        max_body_bytes=settings.max_body_bytes,
        max_upload_bytes=settings.max_upload_bytes,
        body_timeout_s=settings.body_timeout_s,
    )
    templates: dict[int, str] = {}  # route object -> full path template, for the access log
    routers = [
        health,
        robots,
        cabins,
        plans,
        exports,
        cycles,
        sweeps,
        scene,
        kinematics,
        pprs6,
        stiffness,
        keys,
    ]
    for module in routers:
        router: Any = module.router
        app.include_router(router, prefix=API_PREFIX)
        templates.update({id(r): API_PREFIX + r.path for r in router.routes})
    app.include_router(metrics.router)
    templates.update({id(r): str(getattr(r, "path", "")) for r in metrics.router.routes})
    app.add_middleware(AccessLogMiddleware, metrics=service_metrics, templates=templates)
    install_openapi(app)
    # The operator page: static files of the package (three.js and uPlot vendored, no CDN; api/viewer).
    app.mount(VIEWER_PATH, StaticFiles(directory=VIEWER_DIR, html=True), name="viewer")
    return app


__all__ = [
    "API_PREFIX",
    "VIEWER_DIR",
    "VIEWER_PATH",
    "AccessLogMiddleware",
    "BodyLimitMiddleware",
    "BodyTimeout",
    "BodyTooLarge",
    "create_app",
]
