"""The FastAPI application: :func:`create_app` wires settings, database, mesh store, job runner and routers.

Routers live one per resource in :mod:`api.routes` and are mounted under ``/api/v1``; the OpenAPI
document is at ``/openapi.json`` and the interactive docs at ``/docs``. The lifespan creates the tables,
recovers jobs interrupted by a dead process (:func:`api.jobs.recover_jobs`), and starts / stops the runner.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api import problems
from api.context import AppContext
from api.db import Database
from api.jobs import JobRunner, ProcessJobRunner, recover_jobs
from api.routes import cabins, health, keys, kinematics, plans, pprs6, robots, stiffness, sweeps
from api.settings import Settings
from api.store import MeshStore
from api.sweeps import SweepFeeder
from planner import __version__
from planner.collision.mesh_loader import MeshLimits

_LOG = logging.getLogger(__name__)

API_PREFIX = "/api/v1"


class BodyTooLarge(StarletteHTTPException):
    """413: the request body is larger than its limit (raised while the body is streamed)."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than the limit of {limit} bytes")


class BodyLimitMiddleware:
    """Counts the bytes of every request body as it streams in (not only Content-Length) -> 413.

    Mesh uploads (``POST /api/v1/cabins``) have their own, larger limit.
    """

    def __init__(self, app: ASGIApp, max_body_bytes: int, max_upload_bytes: int) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.max_upload_bytes = max_upload_bytes

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

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise BodyTooLarge(limit)
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
    job_runner: JobRunner = runner or ProcessJobRunner(db, settings)
    ctx = AppContext(settings=settings, db=db, store=store, runner=job_runner)
    feeder = SweepFeeder(db, settings, job_runner)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
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
    )
    for module in (health, robots, cabins, plans, sweeps, kinematics, pprs6, stiffness, keys):
        router: Any = module.router
        app.include_router(router, prefix=API_PREFIX)
    return app


__all__ = ["API_PREFIX", "BodyLimitMiddleware", "BodyTooLarge", "create_app"]
