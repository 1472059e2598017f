"""Zenoh streaming: clouds in on <prefix>/cloud (JSON or PointCloud2) and the gpd_ros keys, the newest kept (a
robot wants grasps for what it sees now), detected one at a time with the run-time options, and grasps out as
JSON on <prefix>/grasps and, for a ROS input, as ROS messages (services.ros_stream.ros_outputs); errors on
<prefix>/errors (and the JSON grasps key)."""

from __future__ import annotations

import contextvars
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from graspd.io.ros import Header
from graspd.server.logs import begin_request
from graspd.server.metrics import Metrics
from graspd.server.problems import Problem, internal_error, too_large
from graspd.server.services.lifecycle import Lifecycle
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import Parsed
from graspd.server.services.ros_stream import LatestFrame, ros_outputs
from graspd.server.settings import Settings

from .gate import Gate, attachment, error_payload, size_of

log = logging.getLogger("graspd.server")


class Stream:
    """The stream thread and its subscribers' callbacks.  parse(payload, input name) makes the request of a
    payload (queries.parse_payload: JSON, or CDR with the run-time options); publish(output, payload) puts on an
    output key."""

    def __init__(self, settings: Settings, gate: Gate, lifecycle: Lifecycle, metrics: Metrics,
                 parse: Callable[[bytes, str], Parsed], publish: Callable[[str, bytes], None]) -> None:
        self.settings = settings
        self.gate = gate
        self.lifecycle = lifecycle
        self.metrics = metrics
        self.parse = parse
        self.publish = publish
        self.frames = LatestFrame()
        self.thread: threading.Thread | None = None
        self._refused = 0
        self._refused_logged = 0.0

    def start(self) -> None:
        self.thread = threading.Thread(target=self._loop, name="graspd-zenoh-stream", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.frames.close()
        if self.thread is not None:
            self.thread.join(timeout=self.settings.deadline_s)

    def put_error(self, problem: Problem, request_id: str | None = None, also_json: bool = True) -> None:
        """An error body on the errors key, and on the JSON grasps key (where stream errors always went)."""
        body = error_payload(problem, request_id)
        self.publish("errors", body)
        if also_json:
            self.publish("json", body)

    def on_cloud(self, sample: Any, name: str) -> None:
        """Keep only the newest cloud.  A cloud without the token is dropped (counted, logged at most every
        10 s); one over the size cap gets a 413 on the error keys."""
        try:
            if self.settings.zenoh_stream_token and not self.gate.authorized(attachment(sample)):
                self.refuse()
                return
            size = size_of(sample.payload)
            if size > self.settings.max_body_bytes:
                self.metrics.requests.labels("zenoh-stream", "too_large").inc()
                self.put_error(too_large("cloud", size, self.settings.max_body_bytes, "payload"))
                return
            payload = bytes(sample.payload.to_bytes())
        except Exception:
            log.exception("zenoh stream sample refused")
            return
        if self.frames.put(payload, name):
            self.metrics.stream_dropped.inc()

    def refuse(self, what: str = "stream cloud") -> None:
        """Count a sample without the token and log it at most every 10 s."""
        self.metrics.requests.labels("zenoh-stream", "unauthorized").inc()
        self._refused += 1
        now = time.monotonic()
        if now - self._refused_logged >= 10.0:
            self._refused_logged = now
            log.warning(f"{what} without the token dropped",
                        extra={"transport": "zenoh", "outcome": "unauthorized", "dropped": self._refused})

    def _loop(self) -> None:
        while (frame := self.frames.take()) is not None:
            payload, name = frame
            contextvars.Context().run(self.frame, payload, name)

    def frame(self, payload: bytes, name: str = "pointcloud2") -> None:
        """Detect on one streamed cloud and publish: the JSON answer, then for a ROS input its ROS outputs with
        its header (MarkerArray last); or the error (a 500 says nothing internal)."""
        t0 = time.perf_counter()
        ctx = begin_request()
        tracked = self.lifecycle.track("zenoh", label="zenoh-stream", log_success=False, timed=False)
        try:
            parsed = self.parse(payload, name)  # on the stream thread, before it takes a place (as ROS 2's)
            outcome = self.lifecycle.detect_sync(lambda: parsed, {"decode": time.perf_counter() - t0})
            self.publish("json", response_json(outcome))
            header: Header | None = outcome.context
            if header is not None:
                result = outcome.result
                for output, message in ros_outputs(result.grasps, header, result.hand,
                                                   outcome.request.approach_distance, self.outputs):
                    self.publish(output, message)
            tracked.finish()
        except Problem as exc:
            self.put_error(exc, ctx.id)
            tracked.finish(exc)
        except Exception:  # keep streaming whatever one frame did
            log.exception("stream detect failed", extra={"request_id": ctx.id})
            problem = internal_error(ctx.id)
            self.put_error(problem, ctx.id)
            tracked.finish(problem)

    #: the ROS outputs the node publishes (set by the node to its output keys' names)
    outputs: frozenset[str] = frozenset()
