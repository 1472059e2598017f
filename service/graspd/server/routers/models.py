"""The classifiers this server can use."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..deps import Authorized, State
from ..schemas import ModelsResponse

router = APIRouter(tags=["models"])


@router.get("/models", response_model=ModelsResponse, dependencies=[Authorized],
            summary="Model names, the default, and each model card (how it was made, what it scored)")
def models(state: State) -> Any:
    return state.registry.describe()
