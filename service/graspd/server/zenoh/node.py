"""The Zenoh side of the service: a queryable on <prefix>/detect (same JSON request and response as
POST /detect, or a CDR ROS message: sensor_msgs/PointCloud2 by default, gpd_ros CloudSources / CloudIndexed /
CloudSamples with the selector parameter type=cloud_sources|cloud_indexed|cloud_samples), a per-instance
queryable for spreading load over several servers, and streaming: clouds in on <prefix>/cloud (JSON or
PointCloud2) and the gpd_ros keys, grasps out as JSON on <prefix>/grasps and as ROS messages (ros_stream.py).
The options of streamed clouds and CDR queries come from the settings and change at run time with a JSON put or
query on <prefix>/config (guarded like every writer; errors go to <prefix>/errors and the log).

Several servers: Zenoh sends a query to one matching queryable, it does not balance.  Each server
therefore also declares <prefix>/instances/<id> (info) and <prefix>/instances/<id>/detect; clients
list the instances with a query on <prefix>/instances/* and rotate over their detect keys
(graspd_client.ZenohGraspClient(balance=True)).  Each process has its own worker pool.

The grasp-template endpoints answer on <prefix>/demonstrations, <prefix>/feedback and <prefix>/library
with the JSON bodies of their HTTP twins.  Feedback on a GPD grasp must reach the server that detected
it (it remembers its own recent detections); template grasp ids work on any server of the library.
"""

from __future__ import annotations

import contextvars
import hmac
import ipaddress
import json
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

from graspd.io.ros import Header
from graspd.server.logs import RequestContext, begin_request
from graspd.server.metrics import Metrics
from graspd.server.problems import Problem
from graspd.server.requests import parse_model, parse_request
from graspd.server.schemas import DemonstrationRequest, DetectRequest, FeedbackRequest
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.ros_stream import (
    DEFAULT_INPUT_KEYS,
    DEFAULT_OUTPUT_KEYS,
    INPUT_TYPES,
    MAX_CONFIG_BYTES,
    Captured,
    LatestFrame,
    StreamOptions,
    decode_input,
    parse_options,
    resolve_keys,
    ros_header,
    ros_outputs,
    stream_request,
)
from graspd.server.settings import Settings
from graspd_client.wire import (
    ZENOH_DEMONSTRATIONS_KEY,
    ZENOH_DETECT_KEY,
    ZENOH_FEEDBACK_KEY,
    ZENOH_LIBRARY_KEY,
    zenoh_token_attachment,
)

log = logging.getLogger("graspd.server")

#: The Zenoh keys our settings fill in when GRASPD_ZENOH_CONFIG leaves them at Zenoh's defaults.
SETTINGS_KEYS = ("mode", "listen/endpoints", "connect/endpoints", "scouting/multicast/enabled")
_LOCAL_PROTOCOLS = frozenset({"unixsock-stream", "unixsock-seqpacket", "unixpipe"})


class ZenohSetupError(RuntimeError):
    """The Zenoh configuration is unusable or unsafe; the server refuses to start (names the setting)."""


def zenoh_config(settings: Settings) -> Any:
    """A zenoh.Config: the file GRASPD_ZENOH_CONFIG if set (TLS, auth, access control pass through untouched),
    then mode, listen/connect endpoints and multicast scouting from the settings for every one of those keys
    the file leaves at Zenoh's default (a key the file sets wins)."""
    import zenoh  # noqa: PLC0415

    if settings.zenoh_config is None:
        conf = zenoh.Config()
    else:
        path = settings.zenoh_config
        if not path.is_file():
            raise ZenohSetupError(f"GRASPD_ZENOH_CONFIG: {path} is not a file")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:  # zenoh.ZError: a JSON5 syntax error or an unknown key
            raise ZenohSetupError(f"GRASPD_ZENOH_CONFIG: {path} is not a valid Zenoh config ({exc})") from None
    default = zenoh.Config()
    ours: dict[str, Any] = {"mode": settings.zenoh_mode, "listen/endpoints": list(settings.zenoh_listen),
                            "connect/endpoints": list(settings.zenoh_connect),
                            "scouting/multicast/enabled": settings.zenoh_multicast}
    for key in SETTINGS_KEYS:
        if conf.get_json(key) == default.get_json(key):
            conf.insert_json5(key, json.dumps(ours[key]))
    if settings.token is not None and not settings.zenoh_admin_space and _json(conf, "adminspace/enabled") is True:
        # the admin space (@/<zid>/**: endpoints, peers, metrics) answers any peer, token or not
        log.warning("GRASPD_ZENOH_CONFIG enables the Zenoh admin space; turned off because a token is set "
                    "(GRASPD_ZENOH_ADMIN_SPACE=true keeps it)")
        conf.insert_json5("adminspace/enabled", "false")
    return conf


def _strings(value: Any) -> list[str]:
    """Every string in a JSON value (endpoint lists may be keyed by mode: {"router": [...], "peer": [...]})."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in _strings(v)]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def is_local_endpoint(endpoint: str) -> bool:
    """Whether a Zenoh endpoint ("tcp/127.0.0.1:7447", "tls/[::1]:7447", "unixsock-stream//run/z.sock") only
    reaches this machine; a host name other than localhost, or an unspecified address, does not."""
    proto, _, rest = endpoint.partition("/")
    if proto in _LOCAL_PROTOCOLS:
        return True
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _json(conf: Any, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except Exception:  # a key this zenoh version does not know
        return None


def exposure(conf: Any) -> list[str]:
    """What makes a Zenoh config reachable from other machines: non-loopback listen/connect endpoints,
    multicast scouting.  Empty: loopback only."""
    out = [e for key in ("listen/endpoints", "connect/endpoints") for e in _strings(_json(conf, key))
           if not is_local_endpoint(e)]
    if _json(conf, "scouting/multicast/enabled") is not False:
        out.append("multicast scouting")
    return out


def authenticates(conf: Any) -> bool:
    """Whether a Zenoh config authenticates peers itself: user/password, mutual TLS, or access control."""
    return (_json(conf, "transport/auth/usrpwd/user") is not None
            or _json(conf, "transport/link/tls/enable_mtls") is True
            or _json(conf, "access_control/enabled") is True)


def check_exposure(settings: Settings, conf: Any) -> None:
    """Refuse (ZenohSetupError) to open Zenoh beyond loopback when nothing authenticates peers: no
    GRASPD_TOKEN, no auth in GRASPD_ZENOH_CONFIG, and no explicit GRASPD_ZENOH_ALLOW_ANONYMOUS."""
    reach = exposure(conf)
    if not reach or settings.token is not None or authenticates(conf) or settings.zenoh_allow_anonymous:
        return
    raise ZenohSetupError(
        f"Zenoh would be reachable from other machines ({', '.join(reach)}) with no authentication, so anyone "
        "there could run detections and write the template library.  Set GRASPD_TOKEN (clients send it: "
        "ZenohGraspClient(token=...)), or GRASPD_ZENOH_CONFIG with user/password, mTLS or access control, or "
        "listen on loopback (GRASPD_ZENOH_LISTEN='[\"tcp/127.0.0.1:7447\"]'); on a trusted network only, "
        "GRASPD_ZENOH_ALLOW_ANONYMOUS=true")


def error_payload(exc: Problem, request_id: str | None = None) -> bytes:
    """The JSON error body of a Zenoh error reply: HTTP's error body plus its status, and the request id that
    the server's log lines for it carry (HTTP sends it as X-Request-ID; Zenoh replies have no headers)."""
    body: dict[str, Any] = {**exc.body(), "status": exc.status}
    if request_id is not None:
        body["request_id"] = request_id
    return json.dumps(body).encode()


def unauthorized() -> Problem:
    """The 401 of a query without the token (the body HTTP sends, naming the attachment)."""
    return Problem(401, "missing or wrong token: send the attachment b'Bearer <token>' "
                   "(graspd_client.wire.zenoh_token_attachment)", "attachment")


def internal_error(request_id: str) -> Problem:
    """A genuine server fault: no exception text in the reply (it may hold internals), only a generic message
    and the request id; the log line with the traceback carries the same id (HTTP's 500 says the same)."""
    return Problem(500, f"internal error (request {request_id}; the server log has the details)")


def in_fresh_context(fn: Callable[..., None]) -> Callable[..., None]:
    """fn run in a context of its own, so that the request id begin_request() sets there is seen by the lines
    it logs and the work it hands to threads (engine.enqueue copies the context), never by the Zenoh
    callback thread's later, unrelated callbacks."""
    return lambda *args: contextvars.Context().run(fn, *args)


def _attachment(obj: Any) -> bytes | None:
    att = getattr(obj, "attachment", None)
    return None if att is None else bytes(att.to_bytes())


def _size(zbytes: Any) -> int:
    return 0 if zbytes is None else len(zbytes)


def looks_like_cdr(payload: bytes) -> bool:
    """CDR encapsulation header: 0x00 0x00 (big-endian CDR) or 0x00 0x01 (little-endian), then options."""
    return len(payload) >= 4 and payload[0] == 0 and payload[1] in (0, 1)


def input_name(parameters: str) -> str:
    """The input of a CDR query from its selector parameters: type=pointcloud2 (default), cloud_sources,
    cloud_indexed, cloud_samples, or the ROS type name (gpd_ros/msg/CloudSources, gpd_ros/CloudSources)."""
    given = ""
    for part in parameters.split(";"):
        name, _, value = part.partition("=")
        if name.strip() == "type":
            given = value.strip()
    if not given:
        return "pointcloud2"
    for name, ros_type in INPUT_TYPES.items():
        if given in (name, ros_type, ros_type.replace("/msg/", "/")):
            return name
    raise Problem(400, f"unknown message type {given!r}; known: {sorted(INPUT_TYPES)} or their ROS names",
                  "type")


class ZenohNode:
    """Owns one Zenoh session and turns queries and streamed clouds into engine requests.

    Every queryable and the stream go through the same gate: the token (when GRASPD_TOKEN is set) as the
    attachment, compared in constant time, then the size cap, before any parsing; every query gets a reply,
    an error reply with HTTP's JSON error body (plus "status") when anything goes wrong."""

    def __init__(self, settings: Settings, engine: DetectionEngine, metrics: Metrics) -> None:
        self.settings = settings
        self.engine = engine
        self.metrics = metrics
        self.prefix = settings.zenoh_prefix.rstrip("/")
        self.instance = settings.zenoh_instance or f"{socket.gethostname()}-{os.getpid()}-{id(self) % 10000}"
        self.session: Any = None
        self._declared: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._frames = LatestFrame()
        self._stream_thread: threading.Thread | None = None
        self._templates_pool = ThreadPoolExecutor(1, thread_name_prefix="graspd-zenoh-templates")
        token = settings.token
        self._expected = None if token is None else zenoh_token_attachment(token.get_secret_value())
        self._refused_stream = 0
        self._refused_logged = 0.0
        try:
            self.input_keys = resolve_keys(self.prefix, settings.stream_inputs, DEFAULT_INPUT_KEYS,
                                           "GRASPD_STREAM_INPUTS")
            self.output_keys = resolve_keys(self.prefix, settings.stream_outputs, DEFAULT_OUTPUT_KEYS,
                                            "GRASPD_STREAM_OUTPUTS")
        except ValueError as exc:
            raise ZenohSetupError(str(exc)) from None
        self.config_key = f"{self.prefix}/{settings.stream_config_key.strip('/')}"
        self._options_lock = threading.Lock()
        base = {"num_samples": settings.stream_num_samples, **settings.stream_options}
        try:
            self._options = parse_options(base, {}, (settings.stream_viewpoint,))
        except Problem as exc:
            raise ZenohSetupError(f"GRASPD_STREAM_OPTIONS: {exc.field}: {exc.message}") from None
        self._base_options = self._options.source

    @property
    def options(self) -> StreamOptions:
        """The options streamed clouds and CDR queries are detected with now."""
        with self._options_lock:
            return self._options

    @property
    def ready(self) -> bool:
        return self.session is not None and not self._frames.closed

    @property
    def detect_key(self) -> str:
        return f"{self.prefix}/{ZENOH_DETECT_KEY}"

    @property
    def instance_key(self) -> str:
        return f"{self.prefix}/instances/{self.instance}"

    def start(self) -> None:
        """Open the session (ZenohSetupError for a bad or unsafe configuration) and declare the keys."""
        import zenoh  # noqa: PLC0415

        conf = zenoh_config(self.settings)
        check_exposure(self.settings, conf)
        self.session = zenoh.open(conf)
        s = self.session
        on_query, on_info, on_templates = (in_fresh_context(self._on_query), in_fresh_context(self._on_info),
                                           in_fresh_context(self._on_templates))  # one request id per query
        for key in (self.detect_key, f"{self.instance_key}/{ZENOH_DETECT_KEY}"):
            self._declared.append(s.declare_queryable(key, lambda q, k=key: on_query(q, k), complete=True))
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
            self._declared.append(s.declare_queryable(
                f"{self.prefix}/{name}", lambda q, n=name, w=work: on_templates(q, n, w), complete=True))
        self._declared.append(s.declare_queryable(self.config_key, in_fresh_context(self._on_config_query),
                                                  complete=True))
        self._declared.append(s.declare_subscriber(self.config_key, self._on_config_put))
        # BLOCK: a burst of outputs (one moveit_msgs/Grasp per grasp) is never dropped by a full queue; the stream
        # thread waits instead, and newer clouds replace the waiting one
        self._publishers = {name: s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                            for name, key in self.output_keys.items()}
        if self.settings.zenoh_stream:
            for name, key in self.input_keys.items():
                self._declared.append(s.declare_subscriber(key, lambda sample, n=name: self._on_cloud(sample, n)))
            self._stream_thread = threading.Thread(target=self._stream_loop, name="graspd-zenoh-stream", daemon=True)
            self._stream_thread.start()
        log.info("zenoh node up", extra={"detect_key": self.detect_key, "instance": self.instance,
                                         "mode": _json(conf, "mode"), "listen": _json(conf, "listen/endpoints"),
                                         "connect": _json(conf, "connect/endpoints"),
                                         "config_file": str(self.settings.zenoh_config or ""),
                                         "token": self._expected is not None})

    def close(self) -> None:
        self._frames.close()
        if self._stream_thread is not None:
            self._stream_thread.join(timeout=self.settings.deadline_s)
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
        self._templates_pool.shutdown(wait=True, cancel_futures=True)
        if self.session is not None:
            self.session.close()
            self.session = None

    # ---- the gate every entrance goes through ------------------------------------------------
    def authorized(self, attachment: bytes | None) -> bool:
        """Whether a query or sample may be served: no token configured, or its attachment is
        b"Bearer <token>" (constant-time comparison)."""
        if self._expected is None:
            return True
        return attachment is not None and hmac.compare_digest(attachment, self._expected)

    def check(self, query: Any, key: str | None = None) -> None:
        """Let a query in or raise Problem: the token (401), an exact-key query when key is given (400: a
        wildcard such as <prefix>/** never reaches a detector or a writer), the size cap (413), all before the
        payload is copied or parsed."""
        if not self.authorized(_attachment(query)):
            raise unauthorized()
        if key is not None and str(query.key_expr) != key:
            raise Problem(400, f"send the query to the exact key {key!r}, not {str(query.key_expr)!r}", "key_expr")
        size = _size(query.payload)
        if size > self.settings.max_body_bytes:
            raise Problem(413, f"payload of {size} bytes exceeds the limit of {self.settings.max_body_bytes}",
                          "payload")

    @staticmethod
    def payload_of(query: Any) -> bytes:
        return b"" if query.payload is None else bytes(query.payload.to_bytes())

    def admit(self, query: Any, key: str | None = None) -> bytes:
        """The payload of a query allowed in by check() (token, exact key, size cap)."""
        self.check(query, key)
        return self.payload_of(query)

    # ---- requests --------------------------------------------------------------------------
    def request_from_payload(self, payload: bytes, name: str = "pointcloud2"
                             ) -> tuple[DetectRequest, dict[str, Any] | None, Header | None]:
        """A DetectRequest from JSON or CDR bytes (a ROS message of input name, detected with the stream
        options), plus for CDR its header, as the JSON answer's "header" and as a graspd.io.ros Header."""
        if looks_like_cdr(payload):
            options = self.options
            msg = decode_input(payload, name, options)
            return stream_request(msg, options), ros_header(msg.header), msg.header
        if name != "pointcloud2" or not payload.lstrip()[:1] == b"{":
            raise Problem(400, f"payload is not a CDR {INPUT_TYPES[name]}" + (
                " nor a JSON DetectRequest" if name == "pointcloud2" else ""), "payload")
        return guarded_parse(parse_request, payload), None, None

    def _on_info(self, query: Any) -> None:
        t0 = time.perf_counter()
        ctx = begin_request()
        try:
            self.check(query)
            info = {"instance": self.instance, "detect_key": f"{self.instance_key}/{ZENOH_DETECT_KEY}",
                    "workers": self.engine.workers, "pending": self.engine.pending}
            self._finish(query, t0, ctx, None, json.dumps(info).encode(), "instance", self.instance_key)
        except Problem as exc:
            self._finish(query, t0, ctx, exc, name="instance")
        except Exception:
            log.exception("zenoh instance info failed", extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id), name="instance")

    def _on_query(self, query: Any, key: str) -> None:
        """Check the query (token, key, size), take a place in the engine's queue (503 when full, before the
        payload is even copied), then parse and detect on a worker; the reply is sent from the worker when done
        (the Zenoh thread is never blocked, nor the payload parsed on it)."""
        t0 = time.perf_counter()
        ctx = begin_request()
        try:
            self.check(query, key)
            name = input_name(str(query.parameters))
            self.engine.admit()
        except Problem as exc:
            self._finish(query, t0, ctx, exc)
            return
        except Exception:  # a server fault before admission: still an answer
            log.exception("zenoh detect failed", extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id))
            return
        header: dict[str, Any] = {}  # the ROS header of a CDR payload, filled in on the worker; the engine puts
        # it into the response before serialising it

        def parse() -> DetectRequest:
            req, json_header, _ = self.request_from_payload(self.payload_of(query), name)
            header.update(json_header or {})
            return req

        try:
            fut, give_up = self.engine.enqueue(parse, {"read": time.perf_counter() - t0}, header)
        except Problem as exc:  # shutting down (the place was given back)
            self._finish(query, t0, ctx, exc)
            return
        except Exception:
            self.engine.release()
            log.exception("zenoh detect failed", extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id))
            return
        fut.add_done_callback(lambda f: self._reply(query, f, t0, key, ctx))
        self.engine.trim_after(fut)
        if self.settings.deadline_s:  # the engine answers queued work itself; this bounds a runaway detection
            timer = threading.Timer(max(0.0, give_up - time.perf_counter()), self._expire, (query, fut, t0, ctx))
            timer.daemon = True
            timer.start()
            fut.add_done_callback(lambda _: timer.cancel())

    def _expire(self, query: Any, fut: Future[bytes], t0: float, ctx: RequestContext) -> None:
        if fut.cancel() or not fut.done():
            self._finish(query, t0, ctx, self.engine.gave_up())

    def _reply(self, query: Any, fut: Future[bytes], t0: float, key: str, ctx: RequestContext) -> None:
        if fut.cancelled():
            return
        try:
            exc = fut.exception()
            if exc is None:
                self._finish(query, t0, ctx, None, fut.result(), key=key)
            elif isinstance(exc, Problem):
                self._finish(query, t0, ctx, exc)
            else:
                log.error("zenoh detect failed", exc_info=exc, extra={"request_id": ctx.id,
                                                                      "error": type(exc).__name__})
                self._finish(query, t0, ctx, internal_error(ctx.id))
        except Exception:
            log.exception("zenoh detect reply failed", extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id))

    def _on_templates(self, query: Any, name: str, work: Callable[[bytes], Any]) -> None:
        """A demonstrations/feedback/library query: checked here (token, exact key, size); the payload is
        copied, parsed and worked on by a small pool, not the Zenoh thread."""
        t0 = time.perf_counter()
        ctx = begin_request()
        key = f"{self.prefix}/{name}"
        try:
            self.check(query, key)
        except Problem as exc:
            self._finish(query, t0, ctx, exc, name=name)
            return
        except Exception:
            log.exception("zenoh %s failed", name, extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id), name=name)
            return

        def run() -> None:
            try:
                out = work(self.payload_of(query))
                self._finish(query, t0, ctx, None, json.dumps(out).encode(), name, key)
            except Problem as exc:
                self._finish(query, t0, ctx, exc, name=name)
            except Exception:
                log.exception("zenoh %s failed", name, extra={"request_id": ctx.id})
                self._finish(query, t0, ctx, internal_error(ctx.id), name=name)

        try:  # the work's own log lines carry the request id too
            self._templates_pool.submit(contextvars.copy_context().run, run)
        except RuntimeError:  # shutting down
            self._finish(query, t0, ctx, Problem(503, "server is shutting down", retry_after=1.0), name=name)

    def _finish(self, query: Any, t0: float, ctx: RequestContext, problem: Problem | None,
                body: bytes | None = None, name: str = "detect", key: str | None = None) -> None:
        outcome = "ok"
        try:
            if problem is None:
                query.reply(key or query.key_expr, body)
            else:
                outcome = {401: "unauthorized", 413: "too_large", 503: "busy", 504: "deadline"}.get(
                    problem.status, "invalid" if problem.status < 500 else "error")
                if problem.status == 503 and problem.field == "model":
                    outcome = "model_unavailable"
                query.reply_err(error_payload(problem, ctx.id))
            query.drop()
        except Exception as exc:  # query already finalised (deadline raced the result)
            log.debug("zenoh reply dropped", extra={"request_id": ctx.id, "error": repr(exc)})
            return
        elapsed = time.perf_counter() - t0
        if name == "detect":  # the request metrics count detections
            self.metrics.requests.labels("zenoh", outcome).inc()
            self.metrics.request_seconds.labels("zenoh").observe(elapsed)
        elif outcome == "unauthorized":
            self.metrics.requests.labels("zenoh-" + name, outcome).inc()
        extra: dict[str, Any] = {"transport": "zenoh", "request_id": ctx.id, "outcome": outcome,
                                 "ms": round(elapsed * 1000, 1)}
        if problem is not None:  # say why, as HTTP's lines do
            extra.update(status=problem.status, field=problem.field, error=problem.message)
        (log.warning if outcome == "unauthorized" else log.info)(name, extra=extra)

    # ---- streaming -------------------------------------------------------------------------
    def _put(self, output: str, payload: bytes) -> None:
        pub = self._publishers.get(output)
        if pub is not None:
            pub.put(payload)

    def _put_error(self, problem: Problem, request_id: str | None = None, also_json: bool = True) -> None:
        """An error body on the errors key, and on the JSON grasps key (where stream errors always went)."""
        body = error_payload(problem, request_id)
        self._put("errors", body)
        if also_json:
            self._put("json", body)

    def _on_cloud(self, sample: Any, name: str) -> None:
        """Keep only the newest cloud: a robot wants grasps for what it sees now.  A cloud without the token
        is dropped (counted, logged at most every 10 s); one over the size cap gets a 413 on the error keys."""
        try:
            if self.settings.zenoh_stream_token and not self.authorized(_attachment(sample)):
                self._refuse_stream()
                return
            size = _size(sample.payload)
            if size > self.settings.max_body_bytes:
                self.metrics.requests.labels("zenoh-stream", "too_large").inc()
                self._put_error(Problem(
                    413, f"cloud of {size} bytes exceeds the limit of {self.settings.max_body_bytes}", "payload"))
                return
            payload = bytes(sample.payload.to_bytes())
        except Exception:
            log.exception("zenoh stream sample refused")
            return
        if self._frames.put(payload, name):
            self.metrics.stream_dropped.inc()

    def _refuse_stream(self, what: str = "stream cloud") -> None:
        self.metrics.requests.labels("zenoh-stream", "unauthorized").inc()
        self._refused_stream += 1
        now = time.monotonic()
        if now - self._refused_logged >= 10.0:
            self._refused_logged = now
            log.warning(f"{what} without the token dropped",
                        extra={"transport": "zenoh", "outcome": "unauthorized", "dropped": self._refused_stream})

    def _stream_loop(self) -> None:
        while (frame := self._frames.take()) is not None:
            payload, name = frame
            contextvars.Context().run(self._stream_frame, payload, name)

    def _stream_frame(self, payload: bytes, name: str = "pointcloud2") -> None:
        """Detect on one streamed cloud and publish: the JSON answer, then for a ROS input its ROS outputs with
        its header (MarkerArray last); or the error (a 500 says nothing internal)."""
        t0 = time.perf_counter()
        ctx = begin_request()
        try:
            req, json_header, header = self.request_from_payload(payload, name)
            captured = Captured()
            self._put("json", self.engine.run_sync(req, {"decode": time.perf_counter() - t0}, json_header,
                                                   on_detection=captured))
            if header is not None and captured.grasps is not None and captured.hand is not None:
                for output, message in ros_outputs(captured.grasps, header, captured.hand, req.approach_distance,
                                                   self._publishers):
                    self._put(output, message)
            outcome = "ok"
        except Problem as exc:
            self._put_error(exc, ctx.id)
            outcome = "invalid" if exc.status < 500 else "error"
        except Exception:  # keep streaming whatever one frame did
            log.exception("stream detect failed", extra={"request_id": ctx.id})
            self._put_error(internal_error(ctx.id), ctx.id)
            outcome = "error"
        self.metrics.requests.labels("zenoh-stream", outcome).inc()

    # ---- run-time options ------------------------------------------------------------------
    def set_options(self, payload: bytes) -> StreamOptions:
        """Validate a config payload (Problem naming the field) and make it the stream options."""
        options = guarded_parse(lambda p: parse_options(p, self._base_options, (self.settings.stream_viewpoint,)),
                                payload)
        with self._options_lock:
            self._options = options
        log.info("stream options set", extra={"transport": "zenoh", "options": options.source})
        return options

    def _on_config_put(self, sample: Any) -> None:
        """A JSON put on <prefix>/config: with a token set it must carry it (whatever zenoh_stream_token says);
        an invalid config is logged and its error put on <prefix>/errors; the options in force stay."""
        try:
            if not self.authorized(_attachment(sample)):
                self._refuse_stream("config put")
                return
            size = _size(sample.payload)
            if size > MAX_CONFIG_BYTES:
                raise Problem(413, f"config of {size} bytes exceeds the limit of {MAX_CONFIG_BYTES}", "payload")
            self.set_options(bytes(sample.payload.to_bytes()))
        except Problem as exc:
            log.warning("stream config refused", extra={"transport": "zenoh", "status": exc.status,
                                                        "field": exc.field, "error": exc.message})
            self._put_error(exc, also_json=False)
        except Exception:  # never take the node down
            log.exception("stream config failed")

    def _on_config_query(self, query: Any) -> None:
        """A query on <prefix>/config: empty, the options in force; with a JSON payload, set them first.  The
        reply is the options in force, or an error reply naming the field (the options in force stay)."""
        t0 = time.perf_counter()
        ctx = begin_request()
        try:
            self.check(query, self.config_key)
            size = _size(query.payload)
            if size > MAX_CONFIG_BYTES:
                raise Problem(413, f"config of {size} bytes exceeds the limit of {MAX_CONFIG_BYTES}", "payload")
            payload = self.payload_of(query)
            options = self.set_options(payload) if payload.strip() else self.options
            self._finish(query, t0, ctx, None, options.to_json(), "config", self.config_key)
        except Problem as exc:
            if exc.status != 401:
                log.warning("stream config refused", extra={"transport": "zenoh", "status": exc.status,
                                                            "field": exc.field, "error": exc.message})
            self._finish(query, t0, ctx, exc, name="config")
        except Exception:
            log.exception("zenoh config failed", extra={"request_id": ctx.id})
            self._finish(query, t0, ctx, internal_error(ctx.id), name="config")


T = TypeVar("T")


def guarded_parse(parse: Callable[[bytes], T], payload: bytes) -> T:
    """parse(payload), with JSON nested too deep for the parser (RecursionError) answered as the caller's
    error (400 naming the body), never a server fault or a lost reply."""
    try:
        return parse(payload)
    except RecursionError:
        raise Problem(400, "JSON nested too deep", "body") from None
