"""Liveness and readiness.  /healthz is answered by graspd.server.app.RequestGuard before routing (no thread, no
dependency; this route documents it).  /readyz answers everyone a bare status (load balancers), and its details
(models, errors, workers) only to the token holder when the server sets GRASPD_TOKEN."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from graspd.server.api.access import bearer_ok
from graspd.server.api.deps import State

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Alive: the process answers (from the event loop, before any other route)")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", summary="Ready: the default model loaded (models that failed to load are listed by name "
            "in model_errors) and Zenoh up when enabled; with GRASPD_TOKEN set, only the token holder gets more "
            "than the status",
            responses={503: {"description": "not ready; problems says why (the default model by name)"}})
def readyz(request: Request, state: State) -> Any:
    problems = []
    if state.registry.load_error:
        problems.append(f"model: {state.registry.load_error}")
    if state.settings.zenoh_enabled and (state.zenoh is None or not state.zenoh.ready):
        problems.append("zenoh: session not open")
    if state.engine.closed:
        problems.append("shutting down")
    status = 200 if not problems else 503
    if not bearer_ok(state.settings, request):  # anonymous: the bare answer a load balancer needs
        return JSONResponse({"status": "ready" if not problems else "not ready"}, status_code=status)
    body = {
        "status": "ready" if not problems else "not ready",
        "problems": problems,
        "models": state.registry.names(),
        "default_model": state.registry.default,
        "scoring": state.registry.default is not None,
        # where the default model runs: onnxruntime's CUDAExecutionProvider (the gpu extra) or CPUExecutionProvider
        "provider": getattr(state.registry.classifiers.get(state.registry.default or ""), "provider", None),
        "model_errors": state.registry.errors,  # models that failed to load: name -> why (the others serve)
        "zenoh": state.zenoh is not None and state.zenoh.ready,
        "workers": state.engine.workers,
        "queue_capacity": state.engine.capacity,
    }
    return JSONResponse(body, status_code=status)
