"""GET /viewer: a page to drop a PCD/PLY cloud on; POST /viewer: that cloud (multipart field "file", options as
the query parameters of a /detect upload, target_object among them) detected by the engine and answered as the
interactive 3D view (graspd.viz.viewer.viewer_html: the cloud coloured by environment label, the environment, the
scene's objects a colour each with the targeted one marked, the ranked grippers).  Picking an object in the view
makes the drop page POST the same file again with target_object."""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import AsyncGenerator
from pathlib import PurePath
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse
from starlette.datastructures import Headers, UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.server.api.deps import Authorized, State
from graspd.server.api.detect import read_capped
from graspd.server.problems import Problem
from graspd.server.requests import parse_body
from graspd.server.services.mapping import detection_params
from graspd.server.services.outcome import GpdResult, Outcome, Parsed
from graspd.server.uploads import openapi_parameters
from graspd.server.wire.errors import ErrorBody
from graspd.viz.viewer import DROP_CSP, VIEWER_CSP, drop_page_html, security_headers, targeted_object, viewer_html

router = APIRouter(tags=["viewer"])
log = logging.getLogger("graspd.server")

#: Grasps drawn in the page, and most points (object points first).
VIEW_TOP = 50
VIEW_MAX_POINTS = 150_000


async def _once(data: bytes) -> AsyncGenerator[bytes, None]:
    yield data


async def multipart_file(headers: Headers, body: bytes, field: str = "file") -> tuple[bytes, str, str]:
    """(bytes, content type, file name) of the multipart form field `field` of an already capped body;
    Problem 415 when the body is not multipart/form-data, 422 naming the field when it is missing."""
    if not headers.get("content-type", "").lower().startswith("multipart/form-data"):
        raise Problem(415, "send the cloud as multipart/form-data with a field \"file\" (a .pcd or .ply)", "body")
    try:
        form = await MultiPartParser(headers, _once(body), max_files=1, max_fields=16).parse()
    except MultiPartException as exc:
        raise Problem(400, f"malformed multipart body ({exc.message})", "body") from None
    try:
        part = form.get(field)
        if not isinstance(part, UploadFile):
            raise Problem(422, f"multipart field {field!r} with a .pcd or .ply file is required", field)
        return await part.read(), part.content_type or "", PurePath(part.filename or "cloud").name
    finally:
        await form.close()


def _page(outcome: Outcome, name: str, warnings: list[dict[str, Any]]) -> str:
    """The viewer page of a finished detection (on a worker thread: encoding the page takes a while), listing the
    response's warnings."""
    result = outcome.result
    if not isinstance(result, GpdResult):
        raise Problem(422, "the viewer draws method \"gpd\" detections", "method")
    det, req, cloud, hand = result.detection, outcome.request, outcome.cloud, result.hand
    params = detection_params(req)
    shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size, workspace=params.workspace))
    title = (f"{name}: {len(det.grasps)} grasps from {det.num_candidates} candidates, "
             f"model {det.model or 'none (unscored)'}")
    target = req.target
    picked = targeted_object(det, None if target is None else target.object, target is not None)
    return viewer_html(shown, det, hand, top=VIEW_TOP, max_points=VIEW_MAX_POINTS, title=title,
                       gravity=params.gravity, warnings=warnings, picked=picked)


def _warnings(outcome: Outcome) -> list[dict[str, Any]]:
    """The warnings ({code, message}) of a detection's answer."""
    return [w.to_dict() for w in outcome.warnings]


@router.get("/viewer", response_class=HTMLResponse, summary="A page to drop a point cloud on and see its grasps",
            description="Static page (no data): a dropped .pcd/.ply is POSTed to /viewer with the token typed into "
                        "the page (kept in its memory only) and the answer shown in a sandboxed frame, with the "
                        "response's warnings.  Sent with a strict Content-Security-Policy (only its own hashed "
                        "scripts run, nothing loads from elsewhere, never framed), nosniff and no referrer.")
async def viewer_page() -> HTMLResponse:
    return HTMLResponse(drop_page_html("/viewer"), headers=security_headers(DROP_CSP))


@router.post(
    "/viewer",
    dependencies=[Authorized],
    response_class=HTMLResponse,
    summary="The interactive 3D view of a cloud's grasps",
    description="multipart/form-data with a field \"file\" (PCD or PLY); options as the query parameters of a "
                "/detect upload.  Answers a self-contained HTML page (a small WebGL viewer, nothing fetched) of "
                "the cloud coloured by environment label, the environment, the scene's objects (a colour each; "
                "target_object=K draws K's grasps only and marks it) and the top 50 grippers coloured by score.",
    responses={200: {"content": {"text/html": {}}}, 400: {"model": ErrorBody}, 401: {"model": ErrorBody},
               408: {"model": ErrorBody}, 413: {"model": ErrorBody}, 415: {"model": ErrorBody},
               422: {"model": ErrorBody}, 503: {"model": ErrorBody}, 504: {"model": ErrorBody}},
    openapi_extra={"parameters": openapi_parameters(),
                   "requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
                       "type": "object", "required": ["file"],
                       "properties": {"file": {"type": "string", "format": "binary"}}}}}}},
)
async def viewer(request: Request, state: State) -> HTMLResponse:
    life = state.lifecycle
    with life.track("http", "viewer", ok_status=200) as tracked:
        life.admit()  # 503 when full, before the body is read
        try:
            body = await read_capped(request, state.settings.max_body_bytes)
            data, content_type, name = await multipart_file(request.headers, body)
        except BaseException:
            life.release()
            raise
        q = request.query_params
        query, viewpoints, poses = {k: q[k] for k in q}, q.getlist("viewpoint"), q.getlist("camera_pose")
        if query.get("method", "gpd") != "gpd":
            life.release()
            raise Problem(422, "the viewer draws method \"gpd\" detections", "method")
        outcome = await life.detect(lambda: Parsed(parse_body(data, content_type, query, viewpoints, poses)),
                                    {"read": time.perf_counter() - tracked.t0})
        warnings = _warnings(outcome)
        page = await asyncio.to_thread(_page, outcome, name, warnings)
        headers = security_headers(VIEWER_CSP)
        headers["X-Graspd-Warnings"] = json.dumps(warnings, ensure_ascii=True)  # the drop page lists them
        return HTMLResponse(page, headers=headers)
