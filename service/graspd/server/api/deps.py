"""FastAPI dependencies as Annotated aliases: the service state and bearer-token auth."""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from graspd.server.metrics import Metrics
from graspd.server.problems import Problem
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.instance_jobs import InstanceJobs
from graspd.server.services.lifecycle import Lifecycle
from graspd.server.services.registry import ModelRegistry
from graspd.server.settings import Settings


@dataclass
class ServiceState:
    """Everything the routes share, created at startup (app.state.service)."""

    settings: Settings
    registry: ModelRegistry
    metrics: Metrics
    engine: DetectionEngine
    jobs: InstanceJobs  # instance models being made (POST /models)
    zenoh: Any = None  # graspd.server.zenoh.node.ZenohNode when enabled
    lifecycle: Lifecycle = field(init=False)  # a detect request's life, every transport's (lifecycle.py)

    def __post_init__(self) -> None:
        self.lifecycle = Lifecycle(self.engine, self.metrics)


def get_state(request: Request) -> ServiceState:
    state: ServiceState = request.app.state.service
    return state


State = Annotated[ServiceState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="required only when the server sets GRASPD_TOKEN")


def require_token(state: State,
                  credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    token = state.settings.token
    if token is None:
        return
    if credentials is None or not secrets.compare_digest(credentials.credentials.encode(),
                                                         token.get_secret_value().encode()):
        raise Problem(401, "missing or wrong bearer token", "Authorization")


Authorized = Depends(require_token)
