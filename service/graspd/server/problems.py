"""Error bodies shared by HTTP and Zenoh: {"error": "<field>: <message>", "field", "detail": [...]}."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from graspd_client.codec import WireError


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


def from_validation(exc: ValidationError, status: int = 422) -> Problem:
    """A Problem listing every pydantic error with its dotted field path, the first one as the summary."""
    detail = []
    for err in exc.errors(include_url=False):
        message = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        field = _loc_text(tuple(err.get("loc", ())))
        if message.startswith(".") and ": " in message:  # a sub-field the array codec named (".data: ...")
            sub, _, message = message.partition(": ")
            field += sub
        detail.append({"field": field, "message": message})
    first = detail[0] if detail else {"field": "", "message": "invalid request"}
    return Problem(status, first["message"], first["field"] or None, detail=detail)


def from_wire(exc: WireError, status: int = 422) -> Problem:
    return Problem(status, exc.message, exc.field or None)
