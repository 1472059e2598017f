"""POST /detect: a JSON DetectRequest, or a raw PCD/PLY file with options as query parameters."""

from __future__ import annotations

import logging
import time
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import Response

from ..deps import Authorized, State
from ..engine import parse_request
from ..problems import Problem
from ..schemas import DetectResponse, ErrorBody
from ..uploads import sniff, upload_request

router = APIRouter(tags=["detect"])
log = logging.getLogger("graspd.server")

UPLOAD_PARAMS: list[dict[str, Any]] = [
    {"name": "viewpoint", "in": "query", "required": False, "schema": {"type": "string"},
     "description": "camera position 'x,y,z' (m) for PCD/PLY uploads; may repeat; default: the PCD "
                    "VIEWPOINT header, else the origin"},
    {"name": "model", "in": "query", "required": False, "schema": {"type": "string"}},
    {"name": "hand", "in": "query", "required": False, "schema": {"type": "string"},
     "description": "hand preset name"},
    {"name": "num_samples", "in": "query", "required": False, "schema": {"type": "integer"}},
    {"name": "max_grasps", "in": "query", "required": False, "schema": {"type": "integer"}},
    {"name": "min_score", "in": "query", "required": False, "schema": {"type": "number"}},
    {"name": "workspace", "in": "query", "required": False, "schema": {"type": "string"},
     "description": "'xmin,xmax,ymin,ymax,zmin,zmax' (m)"},
    {"name": "selection", "in": "query", "required": False, "schema": {"type": "boolean"}},
    {"name": "clustering", "in": "query", "required": False, "schema": {"type": "boolean"}},
    {"name": "seed", "in": "query", "required": False, "schema": {"type": "integer"}},
    {"name": "method", "in": "query", "required": False, "schema": {"type": "string", "enum": ["gpd", "templates"]},
     "description": "detector (default gpd)"},
    {"name": "use_classifier", "in": "query", "required": False, "schema": {"type": "boolean"},
     "description": "false: no classifier runs (scores null)"},
    {"name": "gravity", "in": "query", "required": False, "schema": {"type": "string"},
     "description": "'x,y,z': direction gravity pulls (cloud frame); ranks by score x utility J(h)"},
    {"name": "exclude_support_plane", "in": "query", "required": False, "schema": {"type": "boolean"},
     "description": "sample no candidates on the dominant plane (a table)"},
    {"name": "min_aperture", "in": "query", "required": False, "schema": {"type": "number"},
     "description": "least grasp width (m)"},
    {"name": "max_aperture", "in": "query", "required": False, "schema": {"type": "number"},
     "description": "largest grasp width (m)"},
]

OPENAPI_EXTRA: dict[str, Any] = {
    "parameters": UPLOAD_PARAMS,
    "requestBody": {
        "required": True,
        "description": "a DetectRequest (JSON), or a PCD/PLY file (binary; query parameters carry the options)",
        "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/DetectRequest"}},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
        },
    },
}


async def read_capped(request: Request, cap: int) -> bytes:
    """The request body, or 413 as soon as it is known to exceed cap bytes."""
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > cap:
        raise Problem(413, f"request body of {length} bytes exceeds the limit of {cap}", "body")
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > cap:
            raise Problem(413, f"request body exceeds the limit of {cap} bytes", "body")
        chunks.append(chunk)
    return b"".join(chunks)


@router.post(
    "/detect",
    dependencies=[Authorized],
    summary="Ranked 6-DOF grasps for a point cloud",
    description="Grasps in the frame of the cloud (metres), best first.  Each grasp follows gpd_ros GraspConfig: "
                "position is the centre of the hand base, rotation columns [approach, binormal, axis].",
    response_class=Response,
    responses={
        200: {"model": DetectResponse, "description": "grasps, timings, model used"},
        400: {"model": ErrorBody}, 401: {"model": ErrorBody}, 413: {"model": ErrorBody},
        415: {"model": ErrorBody}, 422: {"model": ErrorBody},
        503: {"model": ErrorBody, "description": "queue full; retry after the Retry-After header (s)"},
        504: {"model": ErrorBody, "description": "deadline passed"},
    },
    openapi_extra=OPENAPI_EXTRA,
)
async def detect(request: Request, state: State) -> Response:
    t0 = time.perf_counter()
    metrics = state.metrics
    outcome = "error"
    status = 500
    try:
        data = await read_capped(request, state.settings.max_body_bytes)
        kind = sniff(data, request.headers.get("content-type", ""))
        if kind == "json":
            req = parse_request(data)
        else:
            q = request.query_params
            req = parse_request(upload_request(data, kind, {k: q[k] for k in q}, q.getlist("viewpoint")))
        timings = {"decode": time.perf_counter() - t0}
        body = await state.engine.run(req, timings)
        outcome, status = "ok", 200
        return Response(body, media_type="application/json")
    except Problem as exc:
        status = exc.status
        outcome = {503: "busy", 504: "deadline", 413: "too_large", 401: "unauthorized"}.get(
            exc.status, "invalid" if exc.status < 500 else "error")
        raise
    finally:
        elapsed = time.perf_counter() - t0
        metrics.requests.labels("http", outcome).inc()
        metrics.request_seconds.labels("http").observe(elapsed)
        log.info("detect", extra={"transport": "http", "status": status, "outcome": outcome,
                                  "ms": round(elapsed * 1000, 1)})
