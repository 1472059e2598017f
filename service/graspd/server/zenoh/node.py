"""The Zenoh side of the service: one session and what it declares, put together from the parts in this package:
exposure (the session's config, and no anonymous exposure beyond loopback), gate (token, exact key, size cap, the
one reply of each query), queries (the detect queryables, instance info, the grasp-template endpoints), streams
(clouds in, grasps out as JSON and ROS messages) and options (the run-time options of streamed clouds and CDR
queries on <prefix>/config).

Several servers: Zenoh sends a query to one matching queryable, it does not balance.  Each server therefore
also declares <prefix>/instances/<id> (info) and <prefix>/instances/<id>/detect; clients list the instances with
a query on <prefix>/instances/* and rotate over their detect keys (graspd_client.ZenohGraspClient(balance=True)).
Each process has its own worker pool.  Feedback on a GPD grasp must reach the server that detected it (it
remembers its own recent detections); template grasp ids work on any server of the library.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable
from typing import Any

from graspd.server.metrics import Metrics
from graspd.server.requests import parse_model
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.lifecycle import Lifecycle
from graspd.server.services.outcome import Parsed
from graspd.server.services.ros_stream import DEFAULT_INPUT_KEYS, DEFAULT_OUTPUT_KEYS, StreamOptions, resolve_keys
from graspd.server.settings import Settings
from graspd.server.wire.templates import DemonstrationRequest, FeedbackRequest
from graspd_client.wire import (
    ZENOH_DEMONSTRATIONS_KEY,
    ZENOH_DETECT_KEY,
    ZENOH_FEEDBACK_KEY,
    ZENOH_LIBRARY_KEY,
)

from .exposure import (
    ZenohSetupError,
    authenticates,
    check_exposure,
    config_value,
    exposure,
    is_local_endpoint,
    zenoh_config,
)
from .gate import Gate, error_payload, guarded_parse, in_fresh_context, unauthorized
from .options import RuntimeOptions
from .queries import Queries, Selector, input_name, looks_like_cdr, parse_payload
from .streams import Stream

__all__ = ["Selector", "ZenohNode", "ZenohSetupError", "authenticates", "check_exposure", "error_payload",
           "exposure", "in_fresh_context", "input_name", "is_local_endpoint", "looks_like_cdr", "unauthorized",
           "zenoh_config"]

log = logging.getLogger("graspd.server")


class ZenohNode:
    """Owns one Zenoh session: opens it, declares the queryables, the stream's subscribers and publishers and the
    config key, and takes them down."""

    def __init__(self, settings: Settings, engine: DetectionEngine, metrics: Metrics) -> None:
        self.settings = settings
        self.engine = engine
        self.metrics = metrics
        self.prefix = settings.zenoh_prefix.rstrip("/")
        self.instance = settings.zenoh_instance or f"{socket.gethostname()}-{os.getpid()}-{id(self) % 10000}"
        self.session: Any = None
        self._declared: list[Any] = []
        self._publishers: dict[str, Any] = {}
        try:
            self.input_keys = resolve_keys(self.prefix, settings.stream_inputs, DEFAULT_INPUT_KEYS,
                                           "GRASPD_STREAM_INPUTS")
            self.output_keys = resolve_keys(self.prefix, settings.stream_outputs, DEFAULT_OUTPUT_KEYS,
                                            "GRASPD_STREAM_OUTPUTS")
        except ValueError as exc:
            raise ZenohSetupError(str(exc)) from None
        self.config_key = f"{self.prefix}/{settings.stream_config_key.strip('/')}"
        lifecycle = Lifecycle(engine, metrics)
        self.gate = Gate(settings)
        self.stream = Stream(settings, self.gate, lifecycle, metrics, self._parse_streamed, self._put)
        self.stream.outputs = frozenset(self.output_keys)
        self.runtime = RuntimeOptions(settings, self.gate, lifecycle, self.config_key,
                                      lambda problem: self.stream.put_error(problem, also_json=False),
                                      self.stream.refuse)
        self.queries = Queries(self.gate, lifecycle, lambda: self.runtime.current, self._info, self.instance_key)

    @property
    def options(self) -> StreamOptions:
        """The options streamed clouds and CDR queries are detected with now."""
        return self.runtime.current

    def set_options(self, payload: bytes) -> StreamOptions:
        """Validate a config payload (Problem naming the field) and make it the stream options."""
        return self.runtime.set(payload)

    @property
    def ready(self) -> bool:
        return self.session is not None and not self.stream.frames.closed

    @property
    def detect_key(self) -> str:
        return f"{self.prefix}/{ZENOH_DETECT_KEY}"

    @property
    def instance_key(self) -> str:
        return f"{self.prefix}/instances/{self.instance}"

    def _info(self) -> dict[str, Any]:
        return {"instance": self.instance, "detect_key": f"{self.instance_key}/{ZENOH_DETECT_KEY}",
                "workers": self.engine.workers, "pending": self.engine.pending}

    def _parse_streamed(self, payload: bytes, name: str) -> Parsed:
        return parse_payload(payload, name, self.runtime.current)

    def _put(self, output: str, payload: bytes) -> None:
        pub = self._publishers.get(output)
        if pub is not None:
            pub.put(payload)

    def start(self) -> None:
        """Open the session (ZenohSetupError for a bad or unsafe configuration) and declare the keys."""
        import zenoh  # noqa: PLC0415

        conf = zenoh_config(self.settings)
        check_exposure(self.settings, conf)
        self.session = zenoh.open(conf)
        s, q = self.session, self.queries
        on_detect, on_info, on_templates = (in_fresh_context(q.on_detect), in_fresh_context(q.on_info),
                                            in_fresh_context(q.on_templates))  # one request id per query
        for key in (self.detect_key, f"{self.instance_key}/{ZENOH_DETECT_KEY}"):
            self._declared.append(s.declare_queryable(key, lambda query, k=key: on_detect(query, k), complete=True))
        self._declared.append(s.declare_queryable(self.instance_key, on_info, complete=True))
        templates = self.engine.templates
        handlers: dict[str, Callable[[bytes], Any]] = {
            ZENOH_DEMONSTRATIONS_KEY: lambda p: templates.demonstrate(
                guarded_parse(lambda b: parse_model(DemonstrationRequest, b), p)),
            ZENOH_FEEDBACK_KEY: lambda p: templates.feedback(guarded_parse(lambda b: parse_model(FeedbackRequest, b),
                                                                           p)),
            ZENOH_LIBRARY_KEY: lambda _: templates.summary(),
        }
        for name, work in handlers.items():
            key = f"{self.prefix}/{name}"
            self._declared.append(s.declare_queryable(
                key, lambda query, n=name, k=key, w=work: on_templates(query, n, k, w), complete=True))
        self._declared.append(s.declare_queryable(self.config_key, in_fresh_context(self.runtime.on_query),
                                                  complete=True))
        self._declared.append(s.declare_subscriber(self.config_key, self.runtime.on_put))
        # BLOCK: a burst of outputs (one moveit_msgs/Grasp per grasp) is never dropped by a full queue; the stream
        # thread waits instead, and newer clouds replace the waiting one
        self._publishers = {name: s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                            for name, key in self.output_keys.items()}
        if self.settings.zenoh_stream:
            for name, key in self.input_keys.items():
                self._declared.append(s.declare_subscriber(key, lambda sample, n=name: self.stream.on_cloud(sample,
                                                                                                         n)))
            self.stream.start()
        log.info("zenoh node up", extra={"detect_key": self.detect_key, "instance": self.instance,
                                         "mode": config_value(conf, "mode"),
                                         "listen": config_value(conf, "listen/endpoints"),
                                         "connect": config_value(conf, "connect/endpoints"),
                                         "config_file": str(self.settings.zenoh_config or ""),
                                         "token": self.gate.expected is not None})

    def close(self) -> None:
        self.stream.close()
        for d in self._declared:
            try:
                d.undeclare()
            except Exception:  # already gone with the session
                pass
        self._declared.clear()
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception:  # already gone with the session
                pass
        self._publishers.clear()
        self.queries.close()
        if self.session is not None:
            self.session.close()
            self.session = None
