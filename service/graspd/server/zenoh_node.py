"""The Zenoh side of the service: a queryable on <prefix>/detect (same JSON request and response as
POST /detect, or a CDR sensor_msgs/PointCloud2), a per-instance queryable for spreading load over
several servers, and streaming: clouds on <prefix>/cloud in, grasps on <prefix>/grasps out.

Several servers: Zenoh sends a query to one matching queryable, it does not balance.  Each server
therefore also declares <prefix>/instances/<id> (info) and <prefix>/instances/<id>/detect; clients
list the instances with a query on <prefix>/instances/* and rotate over their detect keys
(graspd_client.ZenohGraspClient(balance=True)).  Each process has its own worker pool.

The grasp-template endpoints answer on <prefix>/demonstrations, <prefix>/feedback and <prefix>/library
with the JSON bodies of their HTTP twins.  Feedback on a GPD grasp must reach the server that detected
it (it remembers its own recent detections); template grasp ids work on any server of the library.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from graspd_client.wire import (
    ZENOH_CLOUD_KEY,
    ZENOH_DEMONSTRATIONS_KEY,
    ZENOH_DETECT_KEY,
    ZENOH_FEEDBACK_KEY,
    ZENOH_GRASPS_KEY,
    ZENOH_LIBRARY_KEY,
)

from .engine import DetectionEngine, parse_model, parse_request
from .metrics import Metrics
from .pointcloud2 import PointCloud2Error, decode_pointcloud2, looks_like_cdr
from .problems import Problem
from .schemas import DemonstrationRequest, FeedbackRequest
from .settings import Settings

log = logging.getLogger("graspd.server")


def zenoh_config(settings: Settings) -> Any:
    """A zenoh.Config from the settings: mode, listen/connect endpoints, multicast scouting."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.zenoh_mode))
    conf.insert_json5("listen/endpoints", json.dumps(list(settings.zenoh_listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(settings.zenoh_connect)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.zenoh_multicast))
    return conf


def error_payload(exc: Problem) -> bytes:
    return json.dumps({**exc.body(), "status": exc.status}).encode()


class ZenohNode:
    """Owns one Zenoh session and turns queries and streamed clouds into engine requests."""

    def __init__(self, settings: Settings, engine: DetectionEngine, metrics: Metrics) -> None:
        self.settings = settings
        self.engine = engine
        self.metrics = metrics
        self.prefix = settings.zenoh_prefix.rstrip("/")
        self.instance = settings.zenoh_instance or f"{socket.gethostname()}-{os.getpid()}-{id(self) % 10000}"
        self.session: Any = None
        self._declared: list[Any] = []
        self._publisher: Any = None
        self._latest: bytes | None = None
        self._wake = threading.Condition()
        self._stop = False
        self._stream_thread: threading.Thread | None = None
        self._templates_pool = ThreadPoolExecutor(1, thread_name_prefix="graspd-zenoh-templates")

    @property
    def ready(self) -> bool:
        return self.session is not None and not self._stop

    @property
    def detect_key(self) -> str:
        return f"{self.prefix}/{ZENOH_DETECT_KEY}"

    @property
    def instance_key(self) -> str:
        return f"{self.prefix}/instances/{self.instance}"

    def start(self) -> None:
        import zenoh

        self.session = zenoh.open(zenoh_config(self.settings))
        s = self.session
        self._declared.append(s.declare_queryable(self.detect_key, self._on_query, complete=True))
        self._declared.append(s.declare_queryable(f"{self.instance_key}/{ZENOH_DETECT_KEY}", self._on_query,
                                                  complete=True))
        self._declared.append(s.declare_queryable(self.instance_key, self._on_info, complete=True))
        templates = self.engine.templates
        handlers: dict[str, Callable[[bytes], Any]] = {
            ZENOH_DEMONSTRATIONS_KEY: lambda p: templates.demonstrate(parse_model(DemonstrationRequest, p)),
            ZENOH_FEEDBACK_KEY: lambda p: templates.feedback(parse_model(FeedbackRequest, p)),
            ZENOH_LIBRARY_KEY: lambda _: templates.summary(),
        }
        for name, work in handlers.items():
            self._declared.append(s.declare_queryable(
                f"{self.prefix}/{name}", lambda q, n=name, w=work: self._on_templates(q, n, w), complete=True))
        if self.settings.zenoh_stream:
            self._publisher = s.declare_publisher(f"{self.prefix}/{ZENOH_GRASPS_KEY}")
            self._declared.append(s.declare_subscriber(f"{self.prefix}/{ZENOH_CLOUD_KEY}", self._on_cloud))
            self._stream_thread = threading.Thread(target=self._stream_loop, name="graspd-zenoh-stream", daemon=True)
            self._stream_thread.start()
        log.info("zenoh node up", extra={"detect_key": self.detect_key, "instance": self.instance,
                                         "mode": self.settings.zenoh_mode, "listen": self.settings.zenoh_listen,
                                         "connect": self.settings.zenoh_connect})

    def close(self) -> None:
        with self._wake:
            self._stop = True
            self._wake.notify_all()
        if self._stream_thread is not None:
            self._stream_thread.join(timeout=self.settings.deadline_s)
        for d in self._declared:
            try:
                d.undeclare()
            except Exception:  # already gone with the session
                pass
        self._declared.clear()
        if self._publisher is not None:
            self._publisher.undeclare()
        self._templates_pool.shutdown(wait=True, cancel_futures=True)
        if self.session is not None:
            self.session.close()
            self.session = None

    # ---- requests --------------------------------------------------------------------------
    def request_from_payload(self, payload: bytes) -> tuple[Any, dict[str, Any] | None]:
        """A DetectRequest from JSON or CDR PointCloud2 bytes, plus the ROS header for CDR input."""
        if looks_like_cdr(payload):
            try:
                cloud = decode_pointcloud2(payload)
            except PointCloud2Error as exc:
                raise Problem(422, str(exc), "payload") from None
            body = {"cloud": {"points": cloud.points, "viewpoints": [list(self.settings.stream_viewpoint)]},
                    "num_samples": self.settings.stream_num_samples}
            header = {"frame_id": cloud.frame_id, "stamp": {"sec": cloud.stamp[0], "nanosec": cloud.stamp[1]}}
            return parse_request(body), header
        if not payload.lstrip()[:1] == b"{":
            raise Problem(400, "payload is neither a JSON DetectRequest nor a CDR sensor_msgs/PointCloud2",
                          "payload")
        return parse_request(payload), None

    def _on_info(self, query: Any) -> None:
        info = {"instance": self.instance, "detect_key": f"{self.instance_key}/{ZENOH_DETECT_KEY}",
                "workers": self.engine.workers, "pending": self.engine.pending}
        query.reply(query.key_expr, json.dumps(info).encode())
        query.drop()

    def _on_query(self, query: Any) -> None:
        """Admit the query and reply from the worker when done (the Zenoh thread is not blocked)."""
        t0 = time.perf_counter()
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            req, header = self.request_from_payload(payload)
            timings = {"decode": time.perf_counter() - t0}
            fut, _deadline = self.engine.submit(req, timings)
        except Problem as exc:
            self._finish(query, t0, exc)
            return
        fut.add_done_callback(lambda f: self._reply(query, f, header, t0))
        self.engine.trim_after(fut)
        if self.settings.deadline_s:
            timer = threading.Timer(self.settings.deadline_s, self._expire, (query, fut, t0))
            timer.daemon = True
            timer.start()
            fut.add_done_callback(lambda _: timer.cancel())

    def _expire(self, query: Any, fut: Future[bytes], t0: float) -> None:
        if fut.cancel() or not fut.done():
            self._finish(query, t0, Problem(504, f"no result within the deadline of {self.settings.deadline_s} s",
                                            "deadline"))

    def _reply(self, query: Any, fut: Future[bytes], header: dict[str, Any] | None, t0: float) -> None:
        if fut.cancelled():
            return
        exc = fut.exception()
        if exc is None:
            body = fut.result()
            if header is not None:
                body = json.dumps({**json.loads(body), "header": header}).encode()
            self._finish(query, t0, None, body)
        elif isinstance(exc, Problem):
            self._finish(query, t0, exc)
        else:
            log.error("zenoh detect failed", extra={"error": repr(exc)})
            self._finish(query, t0, Problem(500, f"internal error: {type(exc).__name__}: {exc}"))

    def _on_templates(self, query: Any, name: str, work: Callable[[bytes], Any]) -> None:
        """A demonstrations/feedback/library query: the work runs on a small pool, not the Zenoh thread."""
        t0 = time.perf_counter()
        payload = query.payload.to_bytes() if query.payload is not None else b""

        def run() -> None:
            try:
                self._finish(query, t0, None, json.dumps(work(payload)).encode(), name)
            except Problem as exc:
                self._finish(query, t0, exc, name=name)
            except Exception as exc:
                log.exception("zenoh %s failed", name)
                self._finish(query, t0, Problem(500, f"internal error: {type(exc).__name__}: {exc}"), name=name)

        try:
            self._templates_pool.submit(run)
        except RuntimeError:  # shutting down
            self._finish(query, t0, Problem(503, "server is shutting down", retry_after=1.0), name=name)

    def _finish(self, query: Any, t0: float, problem: Problem | None, body: bytes | None = None,
                name: str = "detect") -> None:
        outcome = "ok"
        try:
            if problem is None:
                query.reply(query.key_expr, body)
            else:
                outcome = {503: "busy", 504: "deadline"}.get(problem.status,
                                                             "invalid" if problem.status < 500 else "error")
                query.reply_err(error_payload(problem))
            query.drop()
        except Exception as exc:  # query already finalised (deadline raced the result)
            log.debug("zenoh reply dropped", extra={"error": repr(exc)})
            return
        elapsed = time.perf_counter() - t0
        if name == "detect":  # the request metrics count detections
            self.metrics.requests.labels("zenoh", outcome).inc()
            self.metrics.request_seconds.labels("zenoh").observe(elapsed)
        log.info(name, extra={"transport": "zenoh", "outcome": outcome, "ms": round(elapsed * 1000, 1)})

    # ---- streaming -------------------------------------------------------------------------
    def _on_cloud(self, sample: Any) -> None:
        """Keep only the newest cloud: a robot wants grasps for what it sees now."""
        with self._wake:
            if self._latest is not None:
                self.metrics.stream_dropped.inc()
            self._latest = sample.payload.to_bytes()
            self._wake.notify()

    def _stream_loop(self) -> None:
        while True:
            with self._wake:
                while self._latest is None and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                payload: bytes = self._latest or b""
                self._latest = None
            t0 = time.perf_counter()
            try:
                req, header = self.request_from_payload(payload)
                body = self.engine.run_sync(req, {"decode": time.perf_counter() - t0})
                out = json.loads(body)
                if header is not None:
                    out["header"] = header
                self._publisher.put(json.dumps(out).encode())
                outcome = "ok"
            except Problem as exc:
                self._publisher.put(error_payload(exc))
                outcome = "invalid" if exc.status < 500 else "error"
            except Exception as exc:  # keep streaming whatever one frame did
                log.exception("stream detect failed")
                self._publisher.put(error_payload(Problem(500, f"internal error: {type(exc).__name__}: {exc}")))
                outcome = "error"
            self.metrics.requests.labels("zenoh-stream", outcome).inc()
