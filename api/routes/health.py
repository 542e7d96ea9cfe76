"""Liveness and readiness probes (no authentication)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from api.problems import Problem, problem_responses
from api.routes.deps import Ctx

router = APIRouter(tags=["health"])


@router.get("/health", summary="Liveness: the process answers")
async def health() -> dict[str, str]:
    """Answers at once, without touching the database or the workers (runs on the event loop)."""
    return {"status": "ok"}


@router.get(
    "/ready",
    summary="Readiness: database reachable, job runner up and warm; the queue depth",
    responses=problem_responses(503),
)
def ready(ctx: Ctx) -> dict[str, Any]:
    """200 when the database answers and the job runner runs and is warm, else a 503 naming what is not.

    While the job forkserver warms up (``stage: compiling kernels``: imports, numba kernels, one reference
    plan) the answer is 503, so a balancer sends no traffic to an instance whose first job would wait.
    The body has the queue depth (``queue.queued``, ``queue.running``: every instance on the database).
    """
    db_ok = ctx.db.ping()
    runner_ok = ctx.runner.alive()
    warming = ctx.runner.warming()
    if not (db_ok and runner_ok) or warming is not None:
        down = [name for name, ok in (("database", db_ok), ("workers", runner_ok)) if not ok]
        what = f"{', '.join(down)} down" if down else f"warming up ({warming})"
        raise Problem(
            503,
            "not_ready",
            f"not ready: {what}",
            database=db_ok,
            workers=runner_ok,
            stage=warming,
            headers={"Retry-After": "5"},
        )
    queued, running = ctx.jobs.queue_counts()
    return {
        "status": "ready",
        "instance": ctx.runner.instance_id,
        "database": "ok",
        "workers": {"running": ctx.runner.busy(), "max": ctx.settings.workers},
        "queue": {"queued": queued, "running": running},
    }
