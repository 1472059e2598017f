"""The errors a request can get and their one body, shared by every transport: Problem (status, field, message),
the answers the service gives (500 internal error, 504 deadline, 503 busy with Retry-After, 413 too large, 422
invalid), built here and nowhere else, and the body every transport sends them as (error_body:
{"error": "<field>: <message>", "field", "detail": [...]})."""

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


def internal_error(request_id: str) -> Problem:
    """A genuine server fault: no exception text in the answer (it may hold internals), only a generic message
    and the request id; the log line with the traceback carries the same id."""
    return Problem(500, f"internal error (request {request_id}; the server log has the details)")


def deadline_passed(deadline_s: float, where: str = "while queued") -> Problem:
    """504 naming the deadline: it passed before an answer (where: "while queued", ...)."""
    return Problem(504, f"deadline of {deadline_s} s passed {where}", "deadline")


def gave_up(deadline_s: float, deadlines: float) -> Problem:
    """504 of a waiter whose detection started but ran past `deadlines` deadlines (the answer window)."""
    return Problem(504, f"no result within {deadlines:g} x the deadline of {deadline_s} s (the detection ran far "
                        "beyond its estimate)", "deadline")


def busy(message: str, retry_after: float) -> Problem:
    """503 with Retry-After (s): the server cannot take or finish this request now."""
    return Problem(503, f"server busy{': ' + message if message else ''}", retry_after=retry_after)


def shutting_down() -> Problem:
    """503 of a request that arrives or waits while the server shuts down."""
    return Problem(503, "server is shutting down", retry_after=1.0)


def too_large(what: str, size: int | str | None, limit: int, field: str) -> Problem:
    """413 naming the field: `what` of `size` bytes (None: not known yet) is over `limit` bytes."""
    if size is None:
        return Problem(413, f"{what} exceeds the limit of {limit} bytes", field)
    return Problem(413, f"{what} of {size} bytes exceeds the limit of {limit}", field)


def invalid(message: str, field: str | None, status: int = 422) -> Problem:
    """A caller's wrong value (422, or 400 for what is not even parsable), naming the field."""
    return Problem(status, message, field)


def error_body(problem: Problem, *, with_status: bool = False, request_id: str | None = None,
               **extra: Any) -> dict[str, Any]:
    """The JSON error body every transport sends: {"error": "<field>: <message>", "field", "detail": [...],
    "retry_after" (503)}; with_status adds the status (Zenoh and ROS 2 have no status line), request_id the id
    the log lines carry (they have no X-Request-ID header), extra anything else the transport names (topic)."""
    body = problem.body()
    if with_status:
        body["status"] = problem.status
    body.update(extra)
    if request_id is not None:
        body["request_id"] = request_id
    return body
