"""Liveness and readiness probes (no authentication)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from api.problems import Problem
from api.routes.deps import Ctx

router = APIRouter(tags=["health"])


@router.get("/health", summary="Liveness: the process answers")
async def health() -> dict[str, str]:
    """Answers at once, without touching the database or the workers (runs on the event loop)."""
    return {"status": "ok"}


@router.get("/ready", summary="Readiness: database reachable and job runner up")
def ready(ctx: Ctx) -> dict[str, Any]:
    """200 when the database answers and the job runner runs, else a 503 problem naming what is down."""
    db_ok = ctx.db.ping()
    runner_ok = ctx.runner.alive()
    if not (db_ok and runner_ok):
        down = [name for name, ok in (("database", db_ok), ("workers", runner_ok)) if not ok]
        raise Problem(
            503, "not_ready", f"not ready: {', '.join(down)} down", database=db_ok, workers=runner_ok
        )
    return {
        "status": "ready",
        "database": "ok",
        "workers": {"running": ctx.runner.busy(), "max": ctx.settings.workers},
    }
