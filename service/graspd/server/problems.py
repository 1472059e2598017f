"""Error bodies shared by HTTP and Zenoh: {"error": "<field>: <message>", "field", "detail": [...]}."""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

from pydantic import ValidationError

from graspd.core.errors import FieldError
from graspd_client.codec import WireError

#: The errors a caller's wrong value raises: the core's FieldError (CloudError, TemplateError, ...) and the wire
#: codec's WireError.  Both carry .field and .message; the edge answers both alike, a 4xx naming the field.
CALLER_ERRORS = (FieldError, WireError)


class Problem(Exception):
    """A request the service refuses: HTTP status, the offending field (dotted path) and why."""

    def __init__(self, status: int, message: str, field: str | None = None, retry_after: float | None = None,
                 detail: list[dict[str, str]] | None = None) -> None:
        self.status = status
        self.field = field
        self.message = message
        self.retry_after = retry_after
        self.detail = detail if detail is not None else ([{"field": field, "message": message}] if field else [])
        super().__init__(f"{field}: {message}" if field else message)

    def body(self) -> dict[str, Any]:
        out: dict[str, Any] = {"error": str(self), "field": self.field, "detail": self.detail}
        if self.retry_after is not None:
            out["retry_after"] = self.retry_after
        return out


def _loc_text(loc: tuple[Any, ...]) -> str:
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f"[{item}]")
        elif item not in ("body", "query"):
            parts.append(("." if parts else "") + str(item))
    return "".join(parts)


def _join(base: str, sub: str) -> str:
    """A field path below base: sub relative (".data") or a plain name ("image_png")."""
    if not sub:
        return base
    if sub.startswith("."):
        return base + sub if base else sub[1:]
    return f"{base}.{sub}" if base else sub


def from_validation(exc: ValidationError, status: int = 422) -> Problem:
    """A Problem listing every pydantic error with its dotted field path, the first one as the summary.  An
    error a validator raised as a FieldError or WireError names its sub-field (.field, relative to pydantic's path)."""
    detail = []
    for err in exc.errors(include_url=False):
        field = _loc_text(tuple(err.get("loc", ())))
        cause = (err.get("ctx") or {}).get("error")
        if isinstance(cause, CALLER_ERRORS):
            field, message = _join(field, cause.field), cause.message
        elif isinstance(cause, BaseException):  # a validator's ValueError: its own text
            message = str(cause)
        else:
            message = str(err.get("msg", "invalid"))
        detail.append({"field": field, "message": message})
    first = detail[0] if detail else {"field": "", "message": "invalid request"}
    return Problem(status, first["message"], first["field"] or None, detail=detail)


def from_wire(exc: FieldError | WireError, status: int = 422) -> Problem:
    """A Problem naming the field the error carries."""
    return Problem(status, exc.message, exc.field or None)


def from_error(exc: ValueError, fields: Collection[str], status: int = 422, default: str = "body") -> Problem:
    """A Problem from an error a request caused outside validation.  A FieldError (graspd.core.cloud.CloudError and
    graspd.templates.TemplateError are ones) carries its field, named when it is default or its first part is
    one of fields (the request's); any other error, or a field the request does not have, is named default."""
    if isinstance(exc, CALLER_ERRORS) and exc.field and (exc.field == default or exc.field.split(".", 1)[0] in fields):
        return from_wire(exc, status)
    return Problem(status, str(exc), default)
