"""The classifiers this server can use, and instance models made on request (POST /models)."""

from __future__ import annotations

import logging
import time
from collections.abc import AsyncGenerator
from pathlib import Path
from typing import Any

import anyio
from fastapi import APIRouter, Request
from starlette.datastructures import FormData, UploadFile
from starlette.formparsers import FormParser, MultiPartException, MultiPartParser

from graspd.core.hand import HAND_PRESETS
from graspd.io.mesh_file import MESH_SUFFIXES
from graspd.server.api.deps import Authorized, State
from graspd.server.api.detect import read_capped
from graspd.server.problems import Problem, from_wire
from graspd.server.services.instance_jobs import InstanceJob, check_declared, check_mesh
from graspd.server.wire.errors import ErrorBody
from graspd.server.wire.models import InstanceJobOut, ModelsResponse
from graspd.store.instances import INSTANCE_CATEGORIES, NAME_PATTERN, InstanceError, check_category, check_name

router = APIRouter(tags=["models"])
log = logging.getLogger("graspd.server")

#: Bytes of a multipart upload beyond the mesh itself (boundaries, headers, the small fields).
FORM_OVERHEAD = 64 << 10
FORM_FIELDS = ("mesh", "name", "category", "hand")

UPLOAD_BODY: dict[str, Any] = {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
    "type": "object", "required": ["mesh", "name"], "additionalProperties": False,
    "properties": {
        "mesh": {"type": "string", "format": "binary",
                 "description": f"the object's surface mesh: a {', '.join(MESH_SUFFIXES)} file (named with its "
                                "suffix), sizes in metres, at most GRASPD_INSTANCE_MAX_MESH_BYTES"},
        "name": {"type": "string", "pattern": NAME_PATTERN.pattern,
                 "description": "the new model's name (not in use): POST /detect selects it with model=name"},
        "category": {"type": "string", "enum": list(INSTANCE_CATEGORIES),
                     "description": "the object's category: fine-tune the category model (box15, cylinder15) "
                                    "instead of the generic one"},
        "hand": {"type": "string", "enum": sorted(HAND_PRESETS), "default": "gpd",
                 "description": "hand preset the grasp images are made for"},
    }}}}}}


@router.get("/models", response_model=ModelsResponse, dependencies=[Authorized],
            summary="Model names, the default, each model card (how it was made, what it scored), and the "
                    "instance models being made")
def models(state: State) -> Any:
    return {**state.registry.describe(), "jobs": state.jobs.describe()}


async def _form(request: Request, cap: int) -> FormData:
    """The multipart form of the request, its size capped (413 naming mesh)."""
    content_type = request.headers.get("content-type", "").lower()
    multipart = content_type.startswith("multipart/form-data")
    if not multipart and not content_type.startswith("application/x-www-form-urlencoded"):
        raise Problem(415, "send multipart/form-data: a mesh file and the fields name, category, hand", "body")
    try:
        data = await read_capped(request, cap)
    except Problem as exc:
        if exc.status == 413:
            raise Problem(413, f"the upload exceeds {cap} bytes (GRASPD_INSTANCE_MAX_MESH_BYTES)", "mesh") from None
        raise

    async def stream() -> AsyncGenerator[bytes, None]:
        yield data

    try:
        if not multipart:  # fields but no file: read, so that the answer can name what is missing
            return await FormParser(request.headers, stream()).parse()
        return await MultiPartParser(request.headers, stream(), max_files=1, max_fields=len(FORM_FIELDS),
                                     max_part_size=1024).parse()
    except (MultiPartException, ValueError) as exc:
        raise Problem(400, f"malformed multipart form: {exc}", "body") from None


def _text(form: FormData, key: str) -> str | None:
    value = form.get(key)
    if value is None:
        return None
    if not isinstance(value, str):
        raise Problem(422, "must be a text field, not a file", key)
    return value


@router.post("/models", status_code=202, response_model=InstanceJobOut, dependencies=[Authorized],
             summary="Make an instance model: fine-tune a classifier for one object from its mesh (background job)",
             description="Uploads the object's mesh (multipart: mesh file, name, optional category and hand).  A "
                         "job renders and labels views of the mesh, fine-tunes the generic model (or the category "
                         "model) on them for GRASPD_INSTANCE_MAX_MINUTES, compares generic, category and instance "
                         "models on held-out views (the card's instance_comparison), and loads the new model: GET "
                         "/models shows the job's progress, and once its state is done POST /detect takes "
                         "model=name.  One job runs at a time; GRASPD_INSTANCE_QUEUE more may wait.  The IROS 2016 "
                         "GPD paper's instance prior (Figure 7).",
             responses={400: {"model": ErrorBody}, 401: {"model": ErrorBody},
                        409: {"model": ErrorBody, "description": "the name is taken by a model or a running job"},
                        413: {"model": ErrorBody}, 415: {"model": ErrorBody},
                        422: {"model": ErrorBody, "description": "a bad mesh, name, category or hand (its field)"},
                        503: {"model": ErrorBody, "description": "training is off or impossible here, the models "
                                                                 "folder is not writable, or the queue is full"}},
             openapi_extra=UPLOAD_BODY)
async def create_model(request: Request, state: State) -> Any:
    t0 = time.perf_counter()
    status, problem = 500, None
    jobs = state.jobs
    try:
        form = await _form(request, state.settings.instance_max_mesh_bytes + FORM_OVERHEAD)
        unknown = sorted(set(form.keys()) - set(FORM_FIELDS))
        if unknown:
            raise Problem(422, f"unknown form field; known: {list(FORM_FIELDS)}", unknown[0])
        try:
            name = check_name(_text(form, "name"))
            category = check_category(_text(form, "category") or None)
        except InstanceError as exc:
            raise from_wire(exc) from None
        hand = _text(form, "hand") or "gpd"
        if hand not in HAND_PRESETS:
            raise Problem(422, f"unknown hand preset {hand!r}; known: {sorted(HAND_PRESETS)}", "hand")
        mesh = form.get("mesh")
        if not isinstance(mesh, UploadFile):
            raise Problem(422, f"a mesh file ({', '.join(MESH_SUFFIXES)}) is required", "mesh")
        suffix = Path(mesh.filename or "").suffix.lower()
        if suffix not in MESH_SUFFIXES:
            raise Problem(422, f"must be a {', '.join(MESH_SUFFIXES)} file (named with its suffix), got "
                               f"{(mesh.filename or '')[:100]!r}", "mesh")
        jobs.check_can_train()
        jobs.check_name_free(name)
        base = jobs.base_model(category)
        work = jobs.work_dir(name)
        job = InstanceJob(name=name, category=category, hand=hand, base_model=base, mesh=work, work=work)
        job.mesh = work / f"mesh-{job.id}{suffix}"
        content = await mesh.read()
        cap = state.settings.instance_max_mesh_bytes
        if len(content) > cap:
            raise Problem(413, f"the mesh has {len(content)} bytes, more than {cap} (GRASPD_INSTANCE_MAX_MESH_BYTES)",
                          "mesh")

        check_declared(content, suffix, cap)  # a lying header: 422 here, before any parser or process runs
        settings = state.settings

        def store_and_check() -> None:
            with jobs.checks.slot(settings.instance_check_timeout_s):  # 503 + Retry-After when all are busy
                work.mkdir(parents=True, exist_ok=True)
                job.mesh.write_bytes(content)
                try:
                    check_mesh(job.mesh, category, HAND_PRESETS[hand].to_dict(), cap,
                               settings.instance_check_timeout_s, settings.instance_check_memory_mb)
                except Problem:
                    job.mesh.unlink(missing_ok=True)
                    raise

        await anyio.to_thread.run_sync(store_and_check)
        try:
            jobs.submit(job)
        except Problem:
            job.mesh.unlink(missing_ok=True)
            raise
        status = 202
        return job.describe()
    except Problem as exc:
        status, problem = exc.status, exc
        raise
    finally:
        ms = round((time.perf_counter() - t0) * 1e3, 1)
        extra: dict[str, Any] = {"transport": "http", "status": status, "ms": ms}
        if problem is not None:
            extra.update(field=problem.field, error=problem.message)
        log.info("instance model", extra=extra)
