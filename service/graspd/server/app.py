"""The FastAPI application: create_app(settings) wires settings, models, engine, Zenoh node and routes."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.datastructures import MutableHeaders
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from graspd import __version__
from graspd.core.parallel import THREADS
from graspd.server.api import detect, docs, health, metrics, models, viewer
from graspd.server.api.deps import ServiceState
from graspd.server.api.guards import BudgetGate, HealthFastPath, UploadRateGuard
from graspd.server.api.templates import REQUEST_MODELS
from graspd.server.api.templates import router as templates_router
from graspd.server.logs import MAX_REQUEST_ID, begin_request, valid_request_id
from graspd.server.metrics import Metrics
from graspd.server.problems import Problem, error_body, internal_error
from graspd.server.requests import dumps
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.instance_jobs import InstanceJobs
from graspd.server.services.registry import ModelRegistry
from graspd.server.settings import Settings, available_cores
from graspd.server.wire.detect import DetectRequest
from graspd.server.zenoh.node import ZenohNode

log = logging.getLogger("graspd.server")

DESCRIPTION = """Grasp Pose Detection (ten Pas, Gualtieri, Saenko, Platt; IJRR 2017) as a service.

**Frames and units.** Metres, right-handed, everything in the frame of the cloud you send; viewpoints
are the camera positions in that frame.

**Grasps** follow gpd_ros `GraspConfig`: `position` is the centre of the hand base; `approach` (hand x)
is the direction the hand moves to reach the object; `binormal` (hand y) the closing direction;
`axis` = approach x binormal (hand z); `width` the object extent between the fingers (m);
`pose` is 4x4 row-major with rotation columns [approach, binormal, axis]; `quat_xyzw` the same rotation.
Fingertips are at `position + hand_depth * approach`.

**Arrays** are `{"dtype", "shape", "data": base64 of little-endian C-order bytes}` or nested lists.
The same request and response travel over Zenoh on `<prefix>/detect` (default prefix `graspd`).

**Grasp templates** (Herzog et al. 2012): teach grasps with `POST /demonstrations`, detect with
`"method": "templates"` on `/detect`, report outcomes of any returned grasp by its `id` with
`POST /feedback` (failures teach the library), list the library with `GET /library`.

**Instance models** (the IROS 2016 GPD paper's instance prior): `POST /models` with an object's mesh fine-tunes
a classifier for that object in the background; `GET /models` shows the job, and `/detect` takes the new
model by name once it is done.
"""


def problem_response(exc: Problem, headers: Mapping[str, str] | None = None) -> JSONResponse:
    """The JSON error body of a Problem with its headers: Retry-After (503), WWW-Authenticate (401),
    Connection: close (408: the rest of the body is not read)."""
    out = dict(headers or {})
    if exc.retry_after is not None:
        out["Retry-After"] = str(int(exc.retry_after))
    if exc.status == 401:
        out["WWW-Authenticate"] = "Bearer"
    if exc.status == 408:
        out["Connection"] = "close"
    return JSONResponse(error_body(exc), status_code=exc.status, headers=out or None)


class RequestGuard:
    """ASGI middleware around every HTTP request: a request id (the contextvar of graspd.server.logs, so every
    log line carries it; returned as X-Request-ID and in a detection's body): the client's X-Request-ID when it
    is valid (logs.valid_request_id: 1 to 128 letters, digits and . _ - : ; = + / @), else one made here (an
    invalid one is logged and replaced, the response header shows which), and the last line of defence: an
    exception escaping the routes becomes a 500 whose body holds no internal text (the log has the traceback),
    answered without re-raising so that uvicorn keeps the keep-alive connection; a client that went away is
    logged at INFO."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        sent = next((v for k, v in scope.get("headers", ()) if k == b"x-request-id"), None)
        given = valid_request_id(sent.decode("latin-1")) if sent is not None else None
        ctx = begin_request(given)
        if sent is not None and given is None:
            log.info("X-Request-ID refused: 1 to %d letters, digits or . _ - : ; = + / @ are allowed; using a new "
                     "id", MAX_REQUEST_ID, extra={"path": scope.get("path"), "refused_id": repr(sent[:MAX_REQUEST_ID])})
        started = False

        async def send_with_id(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                MutableHeaders(scope=message)["X-Request-ID"] = ctx.id  # the id the body returns (templates: later)
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        except ClientDisconnect:
            log.info("client disconnected before its request was read", extra={"path": scope.get("path")})
        except Exception as exc:
            log.error("unhandled error", exc_info=True, extra={"path": scope.get("path"), "error": type(exc).__name__})
            if started:  # nothing can be said any more; uvicorn closes the half-sent response
                return
            body = dumps(error_body(internal_error(ctx.id)))
            headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                       (b"x-request-id", ctx.id.encode())]
            await send({"type": "http.response.start", "status": 500, "headers": headers})
            await send({"type": "http.response.body", "body": body})


def add_unauthorized_responses(schema: dict[str, Any]) -> None:
    """Document the 401 on every operation that takes the bearer token (FastAPI lists the scheme only)."""
    for path in schema.get("paths", {}).values():
        for op in path.values():
            if isinstance(op, dict) and op.get("security"):
                responses = op.setdefault("responses", {})
                responses.setdefault("401", {
                    "description": "missing or wrong bearer token (when the server sets GRASPD_TOKEN)",
                    "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}})


def create_app(settings: Settings | None = None, registry: ModelRegistry | None = None) -> FastAPI:
    """A service app; models load and the Zenoh node starts in the lifespan (use `with TestClient(app)`)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        reg = registry or ModelRegistry.load(settings.resolved_models_dir(), settings.default_model,
                                             settings.model_threads, allow_unscored=settings.allow_unscored,
                                             cascade=settings.cascade_model or None)
        THREADS.cores = settings.threads or available_cores()
        mets = Metrics()
        # warms up each detect worker before the first request can arrive (uvicorn answers nothing, /readyz
        # included, until this returns)
        engine = DetectionEngine(settings, reg, mets)
        state = ServiceState(settings, reg, mets, engine, InstanceJobs(settings, reg))
        app.state.service = state
        if settings.zenoh_enabled:
            state.zenoh = ZenohNode(settings, engine, mets)
            state.zenoh.start()
        if settings.ros2_enabled:  # graspd serve --ros2: the DDS node (the extra graspd[ros2])
            from graspd.server.ros2 import make_node  # noqa: PLC0415

            app.state.ros2 = make_node(settings, engine, mets)
        log.info("graspd ready", extra={"models": reg.names(), "default_model": reg.default,
                                        "model_errors": reg.errors, "not_ready": reg.load_error,
                                        "workers": engine.workers, "queue": settings.queue_size,
                                        "zenoh": settings.zenoh_enabled, "ros2": settings.ros2_enabled,
                                        "warmup_s": engine.warmup_s})
        try:
            yield
        finally:
            log.info("graspd shutting down: finishing running detections")
            if state.zenoh is not None:
                state.zenoh.close()
            if getattr(app.state, "ros2", None) is not None:
                app.state.ros2.close()
            await asyncio.to_thread(state.jobs.close)
            engine.close(wait=True)

    # /docs, /redoc and /openapi.json: routers.docs (offline assets, the token unless GRASPD_PUBLISH_DOCS)
    app = FastAPI(title="graspd", version=__version__, description=DESCRIPTION, lifespan=lifespan,
                  docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(BudgetGate)  # innermost: its refusals carry RequestGuard's X-Request-ID
    app.add_middleware(RequestGuard)
    app.add_middleware(UploadRateGuard, min_bytes_per_s=settings.http_min_upload_rate,
                       grace_s=settings.http_upload_grace_s)
    app.add_middleware(HealthFastPath)  # outermost: /healthz never waits on anything
    for r in (detect.router, health.router, models.router, metrics.router, templates_router, viewer.router,
              docs.router):
        app.include_router(r)

    @app.exception_handler(Problem)
    async def _problem(_: Request, exc: Problem) -> JSONResponse:
        return problem_response(exc)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        detail = [{"field": ".".join(str(p) for p in e.get("loc", ()) if p not in ("body", "query")),
                   "message": str(e.get("msg", "invalid"))} for e in exc.errors()]
        first = detail[0] if detail else {"field": "", "message": "invalid request"}
        log.info("invalid request", extra={"path": request.url.path, "status": 422, "field": first["field"],
                                           "error": first["message"]})
        return problem_response(Problem(422, first["message"], first["field"] or None, detail=detail))

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        return problem_response(Problem(exc.status_code, str(exc.detail)), headers=exc.headers)  # 405: Allow

    def openapi() -> dict[str, Any]:
        """FastAPI's schema plus DetectRequest (its body is read by hand to also accept PCD/PLY files)."""
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description,
                                 routes=app.routes)
            comps = schema.setdefault("components", {}).setdefault("schemas", {})
            models: list[type[BaseModel]] = [DetectRequest, *REQUEST_MODELS]  # bodies read by hand
            for model in models:
                extra = model.model_json_schema(ref_template="#/components/schemas/{model}")
                comps.update(extra.pop("$defs", {}))
                comps[model.__name__] = extra
            add_unauthorized_responses(schema)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app
