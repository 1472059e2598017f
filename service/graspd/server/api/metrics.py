"""Prometheus exposition: with GRASPD_TOKEN set, for the token holder only (scrape with a bearer token) unless
GRASPD_PUBLISH_METRICS publishes it (counts of requests, errors and timings tell an attacker what works)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from graspd.server.api.access import require_bearer
from graspd.server.api.deps import State

router = APIRouter(tags=["metrics"])


@router.get("/metrics", summary="Prometheus metrics (with GRASPD_TOKEN set: the bearer token, unless "
            "GRASPD_PUBLISH_METRICS)", response_class=Response)
def metrics(request: Request, state: State) -> Response:
    require_bearer(state.settings, request, state.settings.publish_metrics)
    return Response(generate_latest(state.metrics.registry), media_type=CONTENT_TYPE_LATEST)
