"""ZenohGraspClient: the detect request as a Zenoh query on `<prefix>/detect` (needs the zenoh extra), and the
grasp-template requests on `<prefix>/demonstrations`, `<prefix>/feedback`, `<prefix>/library`.

Connects in peer mode to the given endpoints (default: the server's loopback listener), or as a Zenoh JSON5
config file says (config=: TLS certificates, user/password).  token= is sent as the attachment
b"Bearer <token>" of every query and streamed cloud (a server with GRASPD_TOKEN set refuses others: 401).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from os import PathLike
from typing import Any

from numpy.typing import ArrayLike

from .errors import RequestRejected, ServerBusy, ServerError, TransportError
from .grasps import Grasps
from .http import parse_grasps
from .wire import (
    ZENOH_CLOUD_KEY,
    ZENOH_DEMONSTRATIONS_KEY,
    ZENOH_DETECT_KEY,
    ZENOH_FEEDBACK_KEY,
    ZENOH_LIBRARY_KEY,
    build_demonstration_request,
    build_detect_request,
    build_feedback_request,
    zenoh_token_attachment,
)

DEFAULT_ENDPOINTS = ("tcp/127.0.0.1:7447",)


def zenoh_config(mode: str = "peer", connect: Sequence[str] = DEFAULT_ENDPOINTS,
                 listen: Sequence[str] = (), multicast: bool = False,
                 config_file: str | PathLike[str] | None = None) -> Any:
    """A zenoh.Config for mode/endpoints; multicast scouting off unless asked (loopback default).  With
    config_file (Zenoh JSON5: TLS, user/password...), a key the file sets wins; the arguments fill in the rest."""
    import zenoh

    conf = zenoh.Config() if config_file is None else zenoh.Config.from_file(str(config_file))
    default = zenoh.Config()
    ours = {"mode": mode, "connect/endpoints": list(connect), "listen/endpoints": list(listen),
            "scouting/multicast/enabled": multicast}
    for key, value in ours.items():
        if conf.get_json(key) == default.get_json(key):
            conf.insert_json5(key, json.dumps(value))
    return conf


class ZenohGraspClient:
    """Blocking Zenoh client: `.detect(points, viewpoints)` → Grasps; errors as for GraspClient."""

    def __init__(self, *, prefix: str = "graspd", connect: Sequence[str] = DEFAULT_ENDPOINTS,
                 mode: str = "peer", timeout: float = 30.0, retries: int = 3, session: Any = None,
                 balance: bool = False, token: str | None = None,
                 config: str | PathLike[str] | None = None) -> None:
        import zenoh

        self.prefix = prefix.rstrip("/")
        self.key = f"{self.prefix}/{ZENOH_DETECT_KEY}"
        self.timeout = timeout
        self.retries = retries
        self.balance = balance
        self._keys: list[str] = []
        self._next = 0
        self._own = session is None
        self._session = session if session is not None else zenoh.open(zenoh_config(mode, connect,
                                                                                     config_file=config))
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
        import zenoh

        out = []
        for reply in self._session.get(f"{self.prefix}/instances/*", target=zenoh.QueryTarget.ALL,
                                       consolidation=zenoh.ConsolidationMode.NONE,
                                       timeout=min(self.timeout, 5.0), attachment=self.attachment):
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

    def query(self, payload: bytes, key: str | None = None) -> Any:
        """The decoded JSON reply to one raw query payload on key (default: detect; retrying busy answers)."""
        import time

        import zenoh

        fixed = key
        for attempt in range(self.retries + 1):
            key = fixed or self._target_key()
            replies = list(self._session.get(key, payload=payload, timeout=self.timeout,
                                             target=zenoh.QueryTarget.BEST_MATCHING, attachment=self.attachment))
            if not replies:
                self._keys = []  # an instance may have gone; rediscover next time
                raise TransportError(f"zenoh {key}: no reply within {self.timeout} s (is a server up?)")
            reply = replies[0]
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

    def publish(self, payload: bytes) -> None:
        """Stream one cloud (JSON DetectRequest or CDR sensor_msgs/PointCloud2 bytes) on <prefix>/cloud, with
        the token; the server publishes its grasps (or an error body) on <prefix>/grasps."""
        if self._publisher is None:
            self._publisher = self._session.declare_publisher(f"{self.prefix}/{ZENOH_CLOUD_KEY}")
        self._publisher.put(payload, attachment=self.attachment)

    def publish_cloud(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                      camera_source: ArrayLike | None = None, **options: Any) -> None:
        """Stream a cloud as a JSON detect request (options as for detect) on <prefix>/cloud."""
        self.publish(json.dumps(build_detect_request(points, viewpoints, camera_source, **options)).encode())
