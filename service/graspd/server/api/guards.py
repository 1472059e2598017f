"""ASGI guards of the HTTP entrance that uvicorn cannot express:

- HealthFastPath answers GET/HEAD /healthz itself, on the event loop, before routing, dependencies, the thread
  pool or any middleware that reads bodies: detection work (worker threads) and a flood of routes waiting on
  threads cannot delay it.  Connection floods are handled by the protocol (graspd.server.runner: header
  deadline, per-peer cap, eviction of header-pending connections), so a new /healthz connection gets in.
- BudgetGate refuses a POST /detect or /viewer whose Content-Length alone cannot fit the detection memory budget
  (413 naming body) or cannot fit now (503 with Retry-After), before a byte of the body is read
  (graspd.server.services.budget; the exact cost is taken on the worker after parsing).
- UploadRateGuard enforces a minimum upload rate on request bodies: after a grace period, a body must keep
  arriving at min_bytes_per_s on average, else 408 naming body and the connection closes.  uvicorn only has
  a keep-alive timeout and an incomplete-event size; the whole-body deadline lives in routers.detect.read_capped.
"""

from __future__ import annotations

import asyncio
import json
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from graspd.server.problems import Problem, error_body

HEALTH_BODY = b'{"status":"ok"}'


class HealthFastPath:
    """GET or HEAD /healthz -> 200 {"status": "ok"}, answered before anything else runs."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope.get("path") == "/healthz" and scope.get("method") in ("GET", "HEAD"):
            headers = [(b"content-type", b"application/json"), (b"content-length", str(len(HEALTH_BODY)).encode()),
                       (b"cache-control", b"no-store")]
            await send({"type": "http.response.start", "status": 200, "headers": headers})
            await send({"type": "http.response.body", "body": HEALTH_BODY if scope["method"] == "GET" else b""})
            return
        await self.app(scope, receive, send)


class UploadRateGuard:
    """A request body slower than min_bytes_per_s (averaged from the request's start, after grace_s seconds)
    makes receive() raise Problem 408 naming body: a client trickling a body holds a connection, a buffer and,
    on /detect, a queue place for at most grace_s + received / min_bytes_per_s seconds."""

    def __init__(self, app: ASGIApp, min_bytes_per_s: float, grace_s: float) -> None:
        self.app = app
        self.rate = min_bytes_per_s
        self.grace_s = grace_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or self.rate <= 0:
            await self.app(scope, receive, send)
            return
        start = time.monotonic()
        received = 0
        complete = False

        async def guarded_receive() -> Message:
            nonlocal received, complete
            if complete:  # the body is in: what follows is the wait for a disconnect
                return await receive()
            deadline = start + max(self.grace_s, received / self.rate)
            try:
                message = await asyncio.wait_for(receive(), timeout=max(0.0, deadline - time.monotonic()))
            except TimeoutError:
                elapsed = time.monotonic() - start
                raise Problem(408, f"request body arriving too slowly: {received} bytes in {elapsed:.1f} s, below "
                                   f"the minimum of {self.rate:g} bytes/s (GRASPD_HTTP_MIN_UPLOAD_RATE)",
                              "body") from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                complete = not message.get("more_body", False)
            else:
                complete = True
            return message

        await self.app(scope, guarded_receive, send)


#: Routes whose bodies are clouds to detect on (the memory budget applies before their body is read).
BUDGETED_PATHS = frozenset({"/detect", "/viewer"})


async def send_problem(send: Send, exc: Problem) -> None:
    """Answer exc as the app's error handler would (its JSON body, Retry-After), closing the connection: the
    request body was not read."""
    body = json.dumps(error_body(exc)).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
               (b"connection", b"close")]
    if exc.retry_after is not None:
        headers.append((b"retry-after", str(int(exc.retry_after)).encode()))
    await send({"type": "http.response.start", "status": exc.status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


class BudgetGate:
    """POST /detect and /viewer: the body's announced size checked against the detection memory budget
    (engine.budget.check_body) before the route runs or the body is read."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope.get("method") == "POST" and scope.get("path") in BUDGETED_PATHS:
            length = next((v for k, v in scope.get("headers", ()) if k == b"content-length"), b"")
            service = getattr(getattr(scope.get("app"), "state", None), "service", None)
            if length.isdigit() and service is not None:
                try:
                    service.engine.budget.check_body(int(length), service.engine.retry_after())
                except Problem as exc:
                    await send_problem(send, exc)
                    return
        await self.app(scope, receive, send)
