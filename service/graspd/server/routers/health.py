"""Liveness and readiness."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from ..deps import State

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Alive: the process answers")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", summary="Ready: the default model loaded (models that failed to load are listed by name "
            "in model_errors) and Zenoh up when enabled",
            responses={503: {"description": "not ready; problems says why (the default model by name)"}})
def readyz(state: State) -> Any:
    problems = []
    if state.registry.load_error:
        problems.append(f"model: {state.registry.load_error}")
    if state.settings.zenoh_enabled and (state.zenoh is None or not state.zenoh.ready):
        problems.append("zenoh: session not open")
    if state.engine.closed:
        problems.append("shutting down")
    body = {
        "status": "ready" if not problems else "not ready",
        "problems": problems,
        "models": state.registry.names(),
        "default_model": state.registry.default,
        "scoring": state.registry.default is not None,
        "model_errors": state.registry.errors,  # models that failed to load: name -> why (the others serve)
        "zenoh": state.zenoh is not None and state.zenoh.ready,
        "workers": state.engine.workers,
        "queue_capacity": state.engine.capacity,
    }
    return JSONResponse(body, status_code=200 if not problems else 503)
