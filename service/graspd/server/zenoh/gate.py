"""The gate every Zenoh entrance goes through, and its answers: the token (when GRASPD_TOKEN is set) as the
attachment, compared in constant time; an exact key; the size cap; all before the payload is copied or parsed.
Every query gets one reply: the body, or an error reply with the error body of graspd.server.lifecycle (plus
"status" and the request id: Zenoh replies have neither a status line nor headers)."""

from __future__ import annotations

import contextvars
import hmac
import json
import logging
from collections.abc import Callable
from typing import Any, TypeVar

from graspd.server.problems import Problem, error_body, too_large
from graspd.server.services.lifecycle import Tracked
from graspd.server.settings import Settings
from graspd_client.wire import zenoh_token_attachment

log = logging.getLogger("graspd.server")
T = TypeVar("T")


def unauthorized() -> Problem:
    """The 401 of a query without the token (the body HTTP sends, naming the attachment)."""
    return Problem(401, "missing or wrong token: send the attachment b'Bearer <token>' "
                   "(graspd_client.wire.zenoh_token_attachment)", "attachment")


def error_payload(problem: Problem, request_id: str | None = None) -> bytes:
    """The JSON error body of a Zenoh error reply or error put (lifecycle.error_body with the status and the
    request id the server's log lines for it carry)."""
    return json.dumps(error_body(problem, with_status=True, request_id=request_id)).encode()


def in_fresh_context(fn: Callable[..., None]) -> Callable[..., None]:
    """fn run in a context of its own, so that the request id begin_request() sets there is seen by the lines
    it logs and the work it hands to threads (engine.enqueue copies the context), never by the Zenoh
    callback thread's later, unrelated callbacks."""
    return lambda *args: contextvars.Context().run(fn, *args)


def attachment(obj: Any) -> bytes | None:
    att = getattr(obj, "attachment", None)
    return None if att is None else bytes(att.to_bytes())


def size_of(zbytes: Any) -> int:
    return 0 if zbytes is None else len(zbytes)


def payload_of(query: Any) -> bytes:
    return b"" if query.payload is None else bytes(query.payload.to_bytes())


def guarded_parse(parse: Callable[[bytes], T], payload: bytes) -> T:
    """parse(payload), with JSON nested too deep for the parser (RecursionError) answered as the caller's
    error (400 naming the body), never a server fault or a lost reply."""
    try:
        return parse(payload)
    except RecursionError:
        raise Problem(400, "JSON nested too deep", "body") from None


class Gate:
    """Who may in (the token) and what (an exact key, the size cap), and the one reply each query gets."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        token = settings.token
        self.expected = None if token is None else zenoh_token_attachment(token.get_secret_value())

    def authorized(self, attachment: bytes | None) -> bool:
        """Whether a query or sample may be served: no token configured, or its attachment is
        b"Bearer <token>" (constant-time comparison)."""
        if self.expected is None:
            return True
        return attachment is not None and hmac.compare_digest(attachment, self.expected)

    def check(self, query: Any, key: str | None = None) -> None:
        """Let a query in or raise Problem: the token (401), an exact-key query when key is given (400: a
        wildcard such as <prefix>/** never reaches a detector or a writer), the size cap (413), all before the
        payload is copied or parsed."""
        if not self.authorized(attachment(query)):
            raise unauthorized()
        if key is not None and str(query.key_expr) != key:
            raise Problem(400, f"send the query to the exact key {key!r}, not {str(query.key_expr)!r}", "key_expr")
        size = size_of(query.payload)
        if size > self.settings.max_body_bytes:
            raise too_large("payload", size, self.settings.max_body_bytes, "payload")

    def admit(self, query: Any, key: str | None = None) -> bytes:
        """The payload of a query allowed in by check() (token, exact key, size cap)."""
        self.check(query, key)
        return payload_of(query)

    @staticmethod
    def reply(query: Any, tracked: Tracked, problem: Problem | None, body: bytes | None = None,
              key: str | None = None) -> None:
        """Answer a query once: body on key (default the query's), or the problem's error reply; then count and
        log it (tracked).  A query already finalised (the deadline raced the result) is left alone."""
        try:
            if problem is None:
                query.reply(key or query.key_expr, body)
            else:
                query.reply_err(error_payload(problem, None if tracked.ctx is None else tracked.ctx.id))
            query.drop()
        except Exception as exc:
            log.debug("zenoh reply dropped", extra={"request_id": None if tracked.ctx is None else tracked.ctx.id,
                                                    "error": repr(exc)})
            return
        tracked.finish(problem)
