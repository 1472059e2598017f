"""A detect request's life on every transport, written once: admit -> queue -> deadline -> outcome ->
classification -> metrics and the one log line.  The error answers it gives (500 internal error, 504 past the
answer window, 503 shutting down) are graspd.server.problems' builders, as every other error answer.

The transports (HTTP routes, uploads, the Zenoh queryables and streams, the ROS 2 node) are adapters around it:
they parse a payload into services.outcome.Parsed, call Lifecycle, and encode the Outcome or the Problem."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from graspd.server.logs import RequestContext, current_request
from graspd.server.metrics import Metrics
from graspd.server.problems import Problem, gave_up, internal_error
from graspd.server.services.engine import ANSWER_DEADLINES, DetectionEngine
from graspd.server.services.outcome import Outcome, Parsed

log = logging.getLogger("graspd.server")

# ---- classification, metrics, the log line ----------------------------------------------------------------
def outcome_of(problem: Problem | None) -> str:
    """The outcome label of an answer: ok, or by the Problem's status: unauthorized (401), too_large (413), busy
    (503; model_unavailable when it names the model), deadline (504), invalid (other 4xx), error (5xx)."""
    if problem is None:
        return "ok"
    if problem.status == 503 and problem.field == "model":
        return "model_unavailable"
    return {401: "unauthorized", 413: "too_large", 503: "busy", 504: "deadline"}.get(
        problem.status, "invalid" if problem.status < 500 else "error")


@dataclass
class Tracked:
    """One request on one transport, from arrival to its answer: finish() counts it (graspd_requests by
    transport and outcome; graspd_request_seconds for detections) and logs its one line, once."""

    metrics: Metrics
    transport: str  # http, zenoh, ros2
    name: str = "detect"  # what was asked: detect, viewer, config, instance, demonstrations, ...
    label: str | None = None  # the graspd_requests transport label (default: transport; zenoh-stream, ...)
    log_success: bool = True  # streams count every frame but log only what went wrong
    timed: bool = True  # into graspd_request_seconds by transport (streamed frames are not)
    t0: float = field(default_factory=time.perf_counter)
    done: bool = False
    #: the request's context (logs.begin_request) when tracking began: its id at the end goes into the log line
    #: (the templates method may replace an id the server made with the detection's)
    ctx: RequestContext | None = field(default_factory=current_request)

    def finish(self, problem: Problem | None = None, status: int | None = None, outcome: str | None = None) -> str:
        """Count and log the answer (problem: the error answered, None: success); returns the outcome."""
        outcome = outcome or outcome_of(problem)
        if self.done:
            return outcome
        self.done = True
        elapsed = time.perf_counter() - self.t0
        label = self.label or self.transport
        if self.name == "detect":
            self.metrics.requests.labels(label, outcome).inc()
            if self.timed:
                self.metrics.request_seconds.labels(self.transport).observe(elapsed)
        elif outcome == "unauthorized":
            self.metrics.requests.labels(f"{label}-{self.name}", outcome).inc()
        if problem is None and not self.log_success:
            return outcome
        extra: dict[str, Any] = {"transport": self.transport, "outcome": outcome, "ms": round(elapsed * 1000, 1)}
        if self.ctx is not None:
            extra["request_id"] = self.ctx.id
        if status is not None or problem is not None:
            extra["status"] = status if status is not None else problem.status  # type: ignore[union-attr]
        if problem is not None:  # say why: the field and the message
            extra.update(field=problem.field, error=problem.message)
        (log.warning if outcome == "unauthorized" else log.info)(self.name, extra=extra)
        return outcome

    # as a context manager (the HTTP routes): whatever ends the block is the answer tracked
    ok_status: int | None = None  # the status a success is logged with (HTTP: 200)
    gone: tuple[type[BaseException], ...] = ()  # what says the client went away (logged 499, "disconnected")

    def __enter__(self) -> Tracked:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, _tb: Any) -> None:
        if exc is None:
            self.finish(status=self.ok_status)
        elif isinstance(exc, Problem):
            self.finish(exc)
        elif isinstance(exc, self.gone):
            self.finish(status=499, outcome="disconnected")
        else:  # a fault: the app's last line of defence answers 500 (app.RequestGuard)
            self.finish(status=500, outcome="error")


# ---- the detection's life ---------------------------------------------------------------------------------
class Lifecycle:
    """The engine's entrances for the transports: admit, queue, wait to the answer window, classify."""

    def __init__(self, engine: DetectionEngine, metrics: Metrics) -> None:
        self.engine = engine
        self.metrics = metrics

    def track(self, transport: str, name: str = "detect", label: str | None = None, log_success: bool = True,
              timed: bool = True, ok_status: int | None = None, gone: tuple[type[BaseException], ...] = ()
              ) -> Tracked:
        """Begin tracking a request of the current request context (logs.begin_request); see Tracked."""
        return Tracked(self.metrics, transport, name, label, log_success, timed, ok_status=ok_status, gone=gone)

    def admit(self) -> None:
        """Reserve a place before the payload is read (503 when full); release() it if the request ends first."""
        self.engine.admit()

    def release(self) -> None:
        self.engine.release()

    async def detect(self, parse: Callable[[], Parsed], timings: dict[str, float], size: int = 0) -> Outcome:
        """Parse and detect an admitted request on a worker, awaited (HTTP): the Outcome, or a Problem (504 past
        ANSWER_DEADLINES deadlines).  size: the payload's bytes when known (0: not)."""
        fut, give_up = self.engine.enqueue(parse, timings, size)
        self.engine.trim_after(fut)
        try:
            return await asyncio.wait_for(asyncio.wrap_future(fut), timeout=max(0.0, give_up - time.perf_counter()))
        except TimeoutError:
            fut.cancel()
            raise gave_up(self.engine.settings.deadline_s, ANSWER_DEADLINES) from None

    def detect_sync(self, parse: Callable[[], Parsed], timings: dict[str, float] | None = None) -> Outcome:
        """Admit, parse and detect, blocking (the streams): the Outcome, or a Problem."""
        return self.engine.detect_sync(parse, timings)

    def start(self, parse: Callable[[], Parsed], timings: dict[str, float],
              answer: Callable[[Outcome | None, Problem | None], None], what: str = "detect", size: int = 0
              ) -> Future[Outcome]:
        """Queue an admitted request and return at once (a listener thread must not block): answer(outcome,
        None) or answer(None, problem) is called once, from the worker, or at the end of the answer window
        (504); a fault becomes internal_error (its traceback logged with the request id).  Raises a Problem
        when the request cannot be queued (shutting down; its place was given back).  size: the payload's bytes
        when known (0: not).  Returns the engine's future, done when the work is (what the request holds beside
        its place in the queue is given back then, not at a 504)."""
        ctx = current_request()
        rid = ctx.id if ctx is not None else "-"
        once = threading.Lock()

        def reply(outcome: Outcome | None, problem: Problem | None) -> None:
            if not once.acquire(blocking=False):
                return
            try:
                answer(outcome, problem)
            except Exception:  # never leave a worker or a timer with an exception
                log.exception(f"{what} answer failed", extra={"request_id": rid})

        def done(f: Future[Outcome]) -> None:
            if f.cancelled():
                return
            exc = f.exception()
            if exc is None:
                reply(f.result(), None)
            elif isinstance(exc, Problem):
                reply(None, exc)
            else:
                log.error(f"{what} failed", exc_info=exc, extra={"request_id": rid, "error": type(exc).__name__})
                reply(None, internal_error(rid))

        try:
            fut, give_up = self.engine.enqueue(parse, timings, size)
        except Problem:
            raise
        except Exception:
            self.engine.release()
            raise
        fut.add_done_callback(done)
        self.engine.trim_after(fut)
        # the engine answers queued work itself; this bounds a detection far beyond its estimate
        timer = threading.Timer(max(0.0, give_up - time.perf_counter()), self._expire, (fut, reply))
        timer.daemon = True
        timer.start()
        fut.add_done_callback(lambda _: timer.cancel())
        return fut

    def _expire(self, fut: Future[Outcome], reply: Callable[[Outcome | None, Problem | None], None]) -> None:
        if fut.cancel() or not fut.done():
            reply(None, gave_up(self.engine.settings.deadline_s, ANSWER_DEADLINES))
