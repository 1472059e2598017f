"""ZenohGraspClient (blocking) and AsyncZenohGraspClient (asyncio): the detect request as a Zenoh query on
`<prefix>/detect` (needs the zenoh extra), and the grasp-template requests on `<prefix>/demonstrations`,
`<prefix>/feedback`, `<prefix>/library`.

Where the server is: connect= lists the Zenoh endpoints to open a session to, default ["tcp/127.0.0.1:7447"]
(the server's default GRASPD_ZENOH_LISTEN), e.g. connect=["tcp/192.168.1.20:7447"] for a server on another
machine, or a router's endpoint; mode= is "peer" (default) or "client"; config= a Zenoh JSON5 file (TLS
certificates, user/password), whose keys win over connect/mode.  token= is sent as the attachment
b"Bearer <token>" of every query and streamed cloud (a server with GRASPD_TOKEN set refuses others: 401).

Failures raise what GraspClient raises for the same failure: TransportError when no server can be reached or
none answers within timeout= seconds, ServerBusy after the retries of 503 answers, RequestRejected (4xx, with
.field), ServerError (5xx, or an answer that is not JSON).
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Sequence
from os import PathLike
from typing import Any

from numpy.typing import ArrayLike

from .errors import RequestRejected, ServerBusy, ServerError, TransportError
from .grasps import Grasps
from .http import file_upload, parse_grasps
from .wire import (
    ZENOH_CLOUD_KEY,
    ZENOH_DEMONSTRATIONS_KEY,
    ZENOH_DETECT_KEY,
    ZENOH_FEEDBACK_KEY,
    ZENOH_LIBRARY_KEY,
    build_demonstration_request,
    build_detect_request,
    build_feedback_request,
    camera_poses_json,
    zenoh_token_attachment,
)

DEFAULT_ENDPOINTS = ("tcp/127.0.0.1:7447",)


def zenoh_config(mode: str = "peer", connect: Sequence[str] = DEFAULT_ENDPOINTS,
                 listen: Sequence[str] = (), multicast: bool = False,
                 config_file: str | PathLike[str] | None = None) -> Any:
    """A zenoh.Config for mode/endpoints; multicast scouting off unless asked (loopback default).  With
    config_file (Zenoh JSON5: TLS, user/password...), a key the file sets wins; the arguments fill in the rest."""
    import zenoh  # noqa: PLC0415

    conf = zenoh.Config() if config_file is None else zenoh.Config.from_file(str(config_file))
    default = zenoh.Config()
    ours = {"mode": mode, "connect/endpoints": list(connect), "listen/endpoints": list(listen),
            "scouting/multicast/enabled": multicast}
    for key, value in ours.items():
        if conf.get_json(key) == default.get_json(key):
            conf.insert_json5(key, json.dumps(value))
    return conf


#: How long a query with no server in sight is retried (declarations of a server just started take a moment to
#: reach a new session) before TransportError says none is reachable; at most the timeout.
DISCOVERY_S = 2.0


def _is_zenoh_timeout(reply: Any) -> bool:
    """Whether a reply is the error Zenoh itself gives a query whose queryable did not answer in time (the
    text "Timeout"; every graspd error reply is a JSON object)."""
    err = getattr(reply, "err", None)
    return err is not None and bytes(err.payload.to_bytes()).strip() == b"Timeout"


class ZenohGraspClient:
    """Blocking Zenoh client: `ZenohGraspClient(connect=["tcp/host:7447"]).detect(points, viewpoints)` → Grasps.

    connect: endpoints to reach the server (or a router) at, default the local server's loopback listener;
    mode "peer" or "client"; config: a Zenoh JSON5 file (its keys win); session: an open zenoh.Session to use
    instead (not closed by close()).  timeout (s): the longest a request waits for its answer; retries: how
    often a 503 (busy) is retried after its retry_after; balance: rotate over every server's own detect key
    (<prefix>/instances/<id>/detect); token: GRASPD_TOKEN of the server.  Errors as for GraspClient."""

    def __init__(self, *, prefix: str = "graspd", connect: Sequence[str] = DEFAULT_ENDPOINTS,
                 mode: str = "peer", timeout: float = 30.0, retries: int = 3, session: Any = None,
                 balance: bool = False, token: str | None = None,
                 config: str | PathLike[str] | None = None) -> None:
        import zenoh  # noqa: PLC0415

        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout}")

        self.prefix = prefix.rstrip("/")
        self.key = f"{self.prefix}/{ZENOH_DETECT_KEY}"
        self.timeout = timeout
        self.retries = retries
        self.balance = balance
        self._keys: list[str] = []
        self._next = 0
        self._own = session is None
        if session is None:
            try:
                session = zenoh.open(zenoh_config(mode, connect, config_file=config))
            except Exception as exc:  # zenoh.ZError: a bad endpoint, an unreadable config, nothing to connect to
                raise TransportError(f"zenoh: cannot open a session to {list(connect)} ({exc})") from None
        self._session = session
        #: what every query and published cloud carries as its attachment (None without a token)
        self.attachment: bytes | None = zenoh_token_attachment(token) if token else None
        self._publisher: Any = None

    def __enter__(self) -> ZenohGraspClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._publisher is not None:
            self._publisher.undeclare()
            self._publisher = None
        if self._own:
            self._session.close()

    def instances(self) -> list[dict[str, Any]]:
        """Every server answering on <prefix>/instances/* (their ids and per-instance detect keys)."""
        import zenoh  # noqa: PLC0415

        out = []
        try:
            replies = list(self._session.get(f"{self.prefix}/instances/*", target=zenoh.QueryTarget.ALL,
                                             consolidation=zenoh.ConsolidationMode.NONE,
                                             timeout=min(self.timeout, 5.0), attachment=self.attachment))
        except Exception as exc:  # the session is closed
            raise TransportError(f"zenoh {self.prefix}/instances/*: {exc}") from None
        for reply in replies:
            if reply.ok is not None:
                try:
                    out.append(json.loads(reply.ok.payload.to_bytes()))
                except ValueError:
                    continue
        return sorted(out, key=lambda i: str(i.get("instance")))

    def _target_key(self) -> str:
        """The shared detect key, or with balance=True the next instance's own key (round robin)."""
        if not self.balance:
            return self.key
        if not self._keys:
            self._keys = [str(i["detect_key"]) for i in self.instances() if "detect_key" in i] or [self.key]
        key = self._keys[self._next % len(self._keys)]
        self._next += 1
        return key

    def _get(self, key: str, payload: bytes) -> Any:
        """The first reply to a query on key (a selector: key?parameters): TransportError when none came,
        saying whether the server was out of sight (no queryable matched: retried for DISCOVERY_S) or silent
        for the whole timeout."""

        import zenoh  # noqa: PLC0415

        start = time.monotonic()
        end = start + self.timeout
        while True:
            left = end - time.monotonic()
            try:
                replies = list(self._session.get(key, payload=payload, timeout=max(left, 0.001),
                                                 target=zenoh.QueryTarget.BEST_MATCHING,
                                                 attachment=self.attachment))
            except Exception as exc:  # the session is closed
                raise TransportError(f"zenoh {key}: {exc}") from None
            if replies and not _is_zenoh_timeout(replies[0]):
                return replies[0]
            now = time.monotonic()
            if replies:  # Zenoh's own error reply when the queryable did not answer in time
                raise TransportError(f"zenoh {key}: no reply within {self.timeout:g} s")
            self._keys = []  # an instance may have gone; rediscover next time
            if now >= end - 0.01:
                raise TransportError(f"zenoh {key}: no reply within {self.timeout:g} s")
            if now - start >= min(DISCOVERY_S, self.timeout):
                raise TransportError(f"zenoh {key}: no server reachable (no queryable matched for "
                                     f"{now - start:.1f} s; is a server up, and connect= right?)")
            time.sleep(min(0.05, max(0.0, end - now)))

    def query(self, payload: bytes, key: str | None = None) -> Any:
        """The decoded JSON reply to one raw query payload on key (default: detect; a selector may carry
        parameters, e.g. "graspd/detect?type=cloud_sources" for CDR gpd_ros CloudSources), retrying busy
        answers.  Errors as for GraspClient (TransportError when no reply came within timeout)."""

        fixed = key
        for attempt in range(self.retries + 1):
            key = fixed or self._target_key()
            reply = self._get(key, payload)
            if reply.ok is not None:
                try:
                    return json.loads(reply.ok.payload.to_bytes())
                except ValueError:
                    raise ServerError(f"zenoh {key}: reply is not JSON") from None
            try:
                err = json.loads(reply.err.payload.to_bytes())
            except ValueError:
                err = {"error": reply.err.payload.to_bytes().decode("utf-8", "replace"), "status": 500}
            status = int(err.get("status", 500)) if isinstance(err, dict) else 500
            if status == 503 and attempt < self.retries:
                time.sleep(min(float(err.get("retry_after", 0.5)), 5.0))
                continue
            if status == 503:
                raise ServerBusy(f"zenoh {key}: server busy after {self.retries + 1} attempts")
            if 400 <= status < 500:
                raise RequestRejected(status, str(err.get("error")), field=err.get("field"), body=err)
            raise ServerError(f"zenoh {key}: {err.get('error')}")
        raise AssertionError("unreachable")

    def detect(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
               camera_source: ArrayLike | None = None, **options: Any) -> Grasps:
        body = build_detect_request(points, viewpoints, camera_source, **options)
        return parse_grasps(self.query(json.dumps(body).encode()))

    def detect_file(self, data: bytes | str | PathLike[str], *, content_type: str | None = None,
                    **params: Any) -> Grasps:
        """Grasps for a capture file, as GraspClient.detect_file sends it over HTTP: its bytes (or a path's) as the
        query's payload, its options (viewpoint, camera_pose, intrinsics, workspace, topic, ...) as selector
        parameters, a repeated one's values joined by '|'."""
        upload = file_upload(data if isinstance(data, bytes | str) else str(data), content_type, params)
        options = {**upload["params"], "content_type": upload["headers"]["Content-Type"]}
        selector = ";".join(f"{k}={'|'.join(v) if isinstance(v, list) else v}" for k, v in options.items())
        return parse_grasps(self.query(upload["content"], f"{self._target_key()}?{selector}"))

    def add_demonstration(self, points: ArrayLike, hand_pose: ArrayLike,
                          viewpoints: ArrayLike = ((0.0, 0.0, 0.0),), camera_source: ArrayLike | None = None,
                          **options: Any) -> Any:
        """Teach the template library a grasp (as GraspClient.add_demonstration)."""
        body = build_demonstration_request(points, hand_pose, viewpoints, camera_source, **options)
        return self.query(json.dumps(body).encode(), f"{self.prefix}/{ZENOH_DEMONSTRATIONS_KEY}")

    def feedback(self, grasp_id: str, success: bool) -> Any:
        """Report a grasp's outcome (as GraspClient.feedback); a GPD grasp's must reach the server that
        detected it (balance=False, or one server)."""
        body = build_feedback_request(grasp_id, success)
        return self.query(json.dumps(body).encode(), f"{self.prefix}/{ZENOH_FEEDBACK_KEY}")

    def library(self) -> Any:
        """The template library summary (as GraspClient.library)."""
        return self.query(b"", f"{self.prefix}/{ZENOH_LIBRARY_KEY}")

    def publish(self, payload: bytes, key: str | None = None) -> None:
        """Stream one cloud, with the token: on <prefix>/cloud (JSON DetectRequest or CDR sensor_msgs/PointCloud2
        bytes) or on key (e.g. <prefix>/cloud_sources for CDR gpd_ros CloudSources); the server publishes its
        grasps (or an error body) on <prefix>/grasps and its ROS outputs on their keys."""
        target = key or f"{self.prefix}/{ZENOH_CLOUD_KEY}"
        try:
            if key is not None:
                self._session.put(target, payload, attachment=self.attachment)
                return
            if self._publisher is None:
                self._publisher = self._session.declare_publisher(target)
            self._publisher.put(payload, attachment=self.attachment)
        except Exception as exc:  # the session is closed
            raise TransportError(f"zenoh {target}: {exc}") from None

    def set_stream_options(self, **options: Any) -> Any:
        """Set the detection options of streamed clouds and CDR queries (DetectRequest fields but cloud and
        crops, plus viewpoints) on <prefix>/config; answers the options in force (RequestRejected names a bad
        field).  Names what differs from the server's settings (GRASPD_STREAM_OPTIONS).  For a camera-frame
        PointCloud2: camera_poses (one camera-to-robot pose: 4x4, 7 numbers or {position, quat_xyzw}),
        points_frame "camera", camera_frame_id (the cloud's frame_id, checked) and robot_frame_id (the outputs')."""
        if options.get("camera_poses") is not None:
            options["camera_poses"] = camera_poses_json(options["camera_poses"])
        return self.query(json.dumps(options).encode(), f"{self.prefix}/config")

    def stream_options(self) -> Any:
        """The detection options of streamed clouds and CDR queries in force on the server."""
        return self.query(b"", f"{self.prefix}/config")

    def publish_cloud(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                      camera_source: ArrayLike | None = None, **options: Any) -> None:
        """Stream a cloud as a JSON detect request (options as for detect) on <prefix>/cloud."""
        self.publish(json.dumps(build_detect_request(points, viewpoints, camera_source, **options)).encode())


class AsyncZenohGraspClient:
    """asyncio Zenoh client with the methods of ZenohGraspClient, awaitable (each runs the blocking Zenoh call
    on a thread); arguments as ZenohGraspClient (connect=, mode=, config=, timeout=, retries=, balance=,
    token=, session=).  `async with AsyncZenohGraspClient(connect=[...]) as zc: grasps = await zc.detect(...)`."""

    def __init__(self, **kwargs: Any) -> None:
        self.sync = ZenohGraspClient(**kwargs)

    async def __aenter__(self) -> AsyncZenohGraspClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await asyncio.to_thread(self.sync.close)

    async def detect(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                     camera_source: ArrayLike | None = None, **options: Any) -> Grasps:
        return await asyncio.to_thread(self.sync.detect, points, viewpoints, camera_source, **options)

    async def detect_file(self, data: bytes | str | PathLike[str], *, content_type: str | None = None,
                          **params: Any) -> Grasps:
        return await asyncio.to_thread(self.sync.detect_file, data, content_type=content_type, **params)

    async def query(self, payload: bytes, key: str | None = None) -> Any:
        return await asyncio.to_thread(self.sync.query, payload, key)

    async def instances(self) -> list[dict[str, Any]]:
        return await asyncio.to_thread(self.sync.instances)

    async def add_demonstration(self, points: ArrayLike, hand_pose: ArrayLike,
                                viewpoints: ArrayLike = ((0.0, 0.0, 0.0),), camera_source: ArrayLike | None = None,
                                **options: Any) -> Any:
        return await asyncio.to_thread(self.sync.add_demonstration, points, hand_pose, viewpoints, camera_source,
                                       **options)

    async def feedback(self, grasp_id: str, success: bool) -> Any:
        return await asyncio.to_thread(self.sync.feedback, grasp_id, success)

    async def library(self) -> Any:
        return await asyncio.to_thread(self.sync.library)

    async def publish(self, payload: bytes, key: str | None = None) -> None:
        await asyncio.to_thread(self.sync.publish, payload, key)

    async def publish_cloud(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                            camera_source: ArrayLike | None = None, **options: Any) -> None:
        await asyncio.to_thread(self.sync.publish_cloud, points, viewpoints, camera_source, **options)

    async def set_stream_options(self, **options: Any) -> Any:
        return await asyncio.to_thread(self.sync.set_stream_options, **options)

    async def stream_options(self) -> Any:
        return await asyncio.to_thread(self.sync.stream_options)
