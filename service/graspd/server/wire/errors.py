"""The error body on the wire: every 4xx/5xx answer (graspd.server.problems.error_body builds it)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class FieldProblem(BaseModel):
    field: str
    message: str


class ErrorBody(BaseModel):
    """Every 4xx/5xx body: the first problem as text, its field, and all problems."""

    error: str
    field: str | None = None
    detail: list[FieldProblem] = Field(default_factory=list)
