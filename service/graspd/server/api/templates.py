"""POST /demonstrations, POST /feedback and GET /library: teach the grasp-template detector, report grasp
outcomes, and list the library (Herzog et al. 2012; graspd.server.services.templates does the work)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

import anyio
from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel

from graspd.server.api.deps import Authorized, State
from graspd.server.api.detect import read_capped
from graspd.server.problems import Problem
from graspd.server.requests import parse_model
from graspd.server.wire.errors import ErrorBody
from graspd.server.wire.templates import (
    DemonstrationRequest,
    DemonstrationResponse,
    FeedbackRequest,
    FeedbackResponse,
    LibraryResponse,
)

router = APIRouter(tags=["templates"])
log = logging.getLogger("graspd.server")

#: Request bodies these routes read by hand (for the size cap and field-named errors); app.openapi adds them.
REQUEST_MODELS: tuple[type[BaseModel], ...] = (DemonstrationRequest, FeedbackRequest)

M = TypeVar("M", bound=BaseModel)
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorBody}, 401: {"model": ErrorBody}, 413: {"model": ErrorBody}, 422: {"model": ErrorBody},
    503: {"model": ErrorBody, "description": "the template library cannot be opened (field template_library)"},
}


def json_body(model: type[BaseModel]) -> dict[str, Any]:
    """openapi_extra for a route whose JSON body (model) is read by hand."""
    return {"requestBody": {"required": True, "content": {
        "application/json": {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}}}}


class TemplateGate:
    """Bounds the writers as /detect is bounded: at most workers + queue_size requests in flight (503 with
    Retry-After when full, decided before the body is read), and at most `workers` bodies parsed and worked
    on at once, on threads (never the event loop: a megabyte of JSON lists takes tens of milliseconds)."""

    def __init__(self, workers: int, queue_size: int) -> None:
        self.capacity = workers + queue_size
        self.limiter = anyio.CapacityLimiter(workers)
        self.in_flight = 0  # touched on the event loop only

    @classmethod
    def of(cls, request: Request, state: State) -> TemplateGate:
        """The app's gate, made on first use (on the event loop: the limiter needs one)."""
        gate: TemplateGate | None = getattr(request.app.state, "template_gate", None)
        if gate is None:
            gate = request.app.state.template_gate = cls(state.engine.workers, state.settings.queue_size)
        return gate

    def admit(self) -> None:
        if self.in_flight >= self.capacity:
            raise Problem(503, f"server busy ({self.in_flight} template requests in flight)", retry_after=1.0)
        self.in_flight += 1

    def release(self) -> None:
        self.in_flight -= 1


async def _call(request: Request, state: State, name: str, model: type[M], work: Callable[[M], Any]) -> Any:
    """Take a place (503 when full), read the body (capped in size and time), then validate it and run work
    on a thread of the gate's bounded pool; log and count the outcome."""
    t0 = time.perf_counter()
    status = 500
    problem: Problem | None = None
    gate = TemplateGate.of(request, state)
    try:
        gate.admit()
        try:
            data = await read_capped(request, state.settings.max_body_bytes)
            out = await anyio.to_thread.run_sync(lambda: work(parse_model(model, data)), limiter=gate.limiter)
        finally:
            gate.release()
        status = 200
        return out
    except Problem as exc:
        problem, status = exc, exc.status
        raise
    finally:
        extra: dict[str, Any] = {"transport": "http", "status": status,
                                 "ms": round((time.perf_counter() - t0) * 1e3, 1)}
        if problem is not None:  # say why, as /detect's lines do
            extra.update(field=problem.field, error=problem.message)
        log.info(name, extra=extra)


@router.post("/demonstrations", dependencies=[Authorized], response_model=DemonstrationResponse,
             summary="Teach a grasp: add a demonstrated hand pose on a cloud to the template library",
             description="The cloud holds the table and one object; hand_pose is the demonstrated grasp (4x4, cloud "
                         "frame, rotation columns [approach, binormal, axis], translation the hand-base centre).  "
                         "Answers the new entry's id and the library counts.",
             responses=ERRORS, openapi_extra=json_body(DemonstrationRequest))
async def demonstrations(request: Request, state: State) -> Any:
    return await _call(request, state, "demonstration", DemonstrationRequest, state.engine.templates.demonstrate)


@router.post("/feedback", dependencies=[Authorized], response_model=FeedbackResponse,
             summary="Report the outcome of executing a grasp this service returned (by its id)",
             description="Stores the outcome with the grasp's 15-channel GPD image (for fine-tuning).  A failed "
                         "grasp from method templates also adds its candidate template to the failure set F_l of "
                         "the library entry that produced it, which lowers similar candidates' rank.  Template "
                         "grasp ids persist in the library; GPD grasp ids are remembered in this server's memory "
                         "for its most recent detections.  An unknown or forgotten id answers 404.",
             responses={**ERRORS, 404: {"model": ErrorBody, "description": "unknown or forgotten grasp_id"}},
             openapi_extra=json_body(FeedbackRequest))
async def feedback(request: Request, state: State) -> Any:
    return await _call(request, state, "feedback", FeedbackRequest, state.engine.templates.feedback)


@router.get("/library", dependencies=[Authorized], response_model=LibraryResponse,
            summary="The grasp-template library: entries with their failure counts, and totals",
            responses={401: {"model": ErrorBody}, 503: ERRORS[503]})
async def library(state: State) -> Any:
    return await run_in_threadpool(state.engine.templates.summary)
