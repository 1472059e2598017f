"""Structured logs: one JSON object per line with the record's extra fields and the request id of the request
being served (a contextvar, so lines from worker threads carry it too)."""

from __future__ import annotations

import json
import logging
import sys
import time
import uuid
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

_STANDARD = set(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {"message", "asctime"}
#: Extra fields never written: uvicorn's ANSI-coloured copy of the message.
_DROPPED = {"color_message"}


@dataclass
class RequestContext:
    """The request being served; `id` is what the response returns as request_id (and X-Request-ID).  Mutable:
    a template detection replaces it with its detection id, seen by the request's later log lines."""

    id: str


_request: ContextVar[RequestContext | None] = ContextVar("graspd_request", default=None)


def begin_request() -> RequestContext:
    """A fresh request id (16 hex digits) for this task's context and the work it hands to threads."""
    ctx = RequestContext(uuid.uuid4().hex[:16])
    _request.set(ctx)
    return ctx


def current_request() -> RequestContext | None:
    """The request this code runs for, if any (None in Zenoh callbacks and background threads)."""
    return _request.get()


class RequestIdFilter(logging.Filter):
    """Adds request_id to every record logged while a request is served (unless the record sets its own)."""

    def filter(self, record: logging.LogRecord) -> bool:
        ctx = _request.get()
        if ctx is not None and not hasattr(record, "request_id"):
            record.request_id = ctx.id
        return True


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "ts": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        out.update({k: v for k, v in record.__dict__.items()
                    if k not in _STANDARD and k not in _DROPPED and not k.startswith("_")})
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def configure_logging(level: str = "INFO", as_json: bool = True) -> None:
    """Route graspd and uvicorn logs to stderr, as JSON lines unless as_json is False."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if as_json else logging.Formatter("%(asctime)s %(levelname)s %(name)s "
                                                                              "%(message)s"))
    handler.addFilter(RequestIdFilter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        logging.getLogger(name).handlers[:] = []
        logging.getLogger(name).propagate = True
