"""``GET /metrics``: the instance's Prometheus metrics (text exposition format, no authentication)."""

from __future__ import annotations

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from api.routes.deps import Ctx

router = APIRouter(tags=["health"])


@router.get(
    "/metrics",
    summary="Prometheus metrics: queue depth, running jobs, job durations and outcomes, requests",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST.split(";")[0]: {"schema": {"type": "string"}}}}},
)
def metrics(ctx: Ctx) -> Response:
    """The metrics of :mod:`api.metrics` in the Prometheus text format."""
    return Response(generate_latest(ctx.metrics.registry), media_type=CONTENT_TYPE_LATEST)
