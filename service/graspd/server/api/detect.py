"""POST /detect: a JSON DetectRequest, or a raw PCD/PLY file with options as query parameters."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect

from graspd.server.api.deps import Authorized, State
from graspd.server.problems import Problem, too_large
from graspd.server.requests import parse_body
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import Parsed
from graspd.server.uploads import openapi_parameters
from graspd.server.wire.errors import ErrorBody
from graspd.server.wire.response import DetectResponse

router = APIRouter(tags=["detect"])

OPENAPI_EXTRA: dict[str, Any] = {
    "parameters": openapi_parameters(),  # generated from DetectRequest (uploads.QUERY_PARAMS)
    "requestBody": {
        "required": True,
        "description": "a DetectRequest (JSON), or a PCD, PLY, NPY or NPZ file, or a 16-bit depth PNG with "
                       "intrinsics (binary; query parameters carry the options)",
        "content": {
            "application/json": {"schema": {"$ref": "#/components/schemas/DetectRequest"}},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            **{ct: {"schema": {"type": "string", "format": "binary"}} for ct in (
                "application/x-pcd", "application/ply", "application/x-npy", "application/x-npz", "image/png")},
        },
    },
}


async def read_capped(request: Request, cap: int, timeout_s: float | None = None) -> bytes:
    """The request body, or 413 as soon as it is known to exceed cap bytes, or 408 when it has not all
    arrived within timeout_s (default: the service's http_body_timeout_s): a trickling client cannot hold a
    connection and its buffer indefinitely."""
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > cap:
        raise too_large("request body", length, cap, "body")
    if timeout_s is None:
        service = getattr(request.app.state, "service", None)
        timeout_s = service.settings.http_body_timeout_s if service is not None else 60.0
    chunks: list[bytes] = []
    size = 0
    stream = request.stream().__aiter__()
    end = time.monotonic() + timeout_s
    while True:
        try:
            chunk = await asyncio.wait_for(anext(stream), timeout=max(0.0, end - time.monotonic()))
        except StopAsyncIteration:
            break
        except TimeoutError:
            raise Problem(408, f"request body not received within {timeout_s:g} s ({size} bytes arrived)",
                          "body") from None
        size += len(chunk)
        if size > cap:
            raise too_large("request body", None, cap, "body")
        chunks.append(chunk)
    return b"".join(chunks)


@router.post(
    "/detect",
    dependencies=[Authorized],
    summary="Ranked 6-DOF grasps for a point cloud",
    description="Grasps in the frame of the cloud (metres), best first.  Each grasp follows gpd_ros GraspConfig: "
                "position is the centre of the hand base, rotation columns [approach, binormal, axis].",
    response_model=DetectResponse,  # services.mapping builds and validates it
    response_class=Response,
    responses={
        200: {"model": DetectResponse, "description": "grasps, timings, model used",
              "links": {"FeedbackOnTheBestGrasp": {  # a robot reports how the best grasp went
                  "operationId": "feedback_feedback_post",
                  "requestBody": {"grasp_id": "$response.body#/grasps/0/id"}}}},
        400: {"model": ErrorBody}, 401: {"model": ErrorBody, "description": "missing or wrong bearer token"},
        408: {"model": ErrorBody, "description": "the body did not arrive in time"}, 413: {"model": ErrorBody},
        415: {"model": ErrorBody}, 422: {"model": ErrorBody},
        503: {"model": ErrorBody, "description": "queue full (retry after the Retry-After header, s), or the "
                                                 "model asked for, or the default, is unavailable (field model)"},
        504: {"model": ErrorBody, "description": "deadline passed"},
    },
    openapi_extra=OPENAPI_EXTRA,
)
async def detect(request: Request, state: State) -> Response:
    life = state.lifecycle
    with life.track("http", ok_status=200, gone=(ClientDisconnect,)) as tracked:
        life.admit()  # 503 when full, before the body is read or parsed
        try:
            data = await read_capped(request, state.settings.max_body_bytes)
        except BaseException:
            life.release()
            raise
        q = request.query_params
        query, viewpoints, poses = {k: q[k] for k in q}, q.getlist("viewpoint"), q.getlist("camera_pose")
        content_type = request.headers.get("content-type", "")
        outcome = await life.detect(lambda: Parsed(parse_body(data, content_type, query, viewpoints, poses)),
                                    {"read": time.perf_counter() - tracked.t0}, size=len(data))
        body = await asyncio.to_thread(response_json, outcome)  # off the event loop (~1 ms per 100 grasps)
        return Response(body, media_type="application/json")
