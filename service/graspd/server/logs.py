"""Structured logs: one JSON object per line with the record's extra fields and the request id of the request
being served (a contextvar, so lines from worker threads carry it too)."""

from __future__ import annotations

import json
import logging
import re
import sys
import time
import uuid
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any

_STANDARD = set(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {"message", "asctime"}
#: Extra fields never written: uvicorn's ANSI-coloured copy of the message.
_DROPPED = {"color_message"}


#: Longest request id a client may choose (X-Request-ID), characters.
MAX_REQUEST_ID = 128
#: What a client-chosen request id may hold: letters, digits and . _ - : ; = + / @ (UUIDs, ULIDs, trace ids),
#: nothing that could break a log line, a header or a JSON string.
REQUEST_ID_PATTERN = re.compile(r"[A-Za-z0-9._\-:;=+/@]{1," + str(MAX_REQUEST_ID) + "}")


def new_id() -> str:
    """A server-made id: 16 hex digits."""
    return uuid.uuid4().hex[:16]


def valid_request_id(value: str | None) -> str | None:
    """value when it may serve as a request id (REQUEST_ID_PATTERN: 1 to MAX_REQUEST_ID safe characters),
    else None (the server makes one)."""
    if value is None or not REQUEST_ID_PATTERN.fullmatch(value):
        return None
    return value


@dataclass
class RequestContext:
    """The request being served.  `id` is what the response returns as request_id (and X-Request-ID) and what
    every log line of the request carries: the client's X-Request-ID when it sent a valid one (`given`), else
    one made here.  `detection_id` is always made here (16 hex digits, unique): GPD grasp ids are
    "<detection_id>-<k>", so a client reusing its ids cannot make feedback name another detection's grasp; it
    equals `id` when the client chose none.  Mutable: a template detection without a client id replaces `id`
    with its detection id, seen by the request's later log lines."""

    id: str
    given: bool = False
    detection_id: str = field(default_factory=new_id)


_request: ContextVar[RequestContext | None] = ContextVar("graspd_request", default=None)


def begin_request(given: str | None = None) -> RequestContext:
    """The request id for this task's context and the work it hands to threads: given (a client's
    X-Request-ID, already checked with valid_request_id) or a fresh one (16 hex digits)."""
    made = new_id()
    ctx = RequestContext(given, True, made) if given is not None else RequestContext(made, False, made)
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
