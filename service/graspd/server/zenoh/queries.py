"""The Zenoh queryables: <prefix>/detect and <prefix>/instances/<id>/detect take what POST /detect takes (a
JSON request, or a capture file with its options as selector parameters) or a CDR ROS message detected with the
run-time options (sensor_msgs/PointCloud2 by default, gpd_ros CloudSources / CloudIndexed / CloudSamples with the
selector parameter type=cloud_sources|cloud_indexed|cloud_samples), and answer POST /detect's JSON;
<prefix>/instances/<id> answers this server's info; the grasp-template endpoints (<prefix>/demonstrations,
<prefix>/feedback, <prefix>/library) take and answer the JSON bodies of their HTTP twins."""

from __future__ import annotations

import contextvars
import json
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from graspd.server.logs import begin_request
from graspd.server.problems import Problem, internal_error, shutting_down
from graspd.server.requests import parse_request
from graspd.server.services.lifecycle import Lifecycle, Tracked
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import Outcome, Parsed
from graspd.server.services.ros_stream import INPUT_TYPES, StreamOptions, decode_input, ros_header, stream_request
from graspd.server.uploads import sniff, upload_request

from .gate import Gate, guarded_parse, payload_of, size_of

log = logging.getLogger("graspd.server")


def looks_like_cdr(payload: bytes) -> bool:
    """CDR encapsulation header: 0x00 0x00 (big-endian CDR) or 0x00 0x01 (little-endian), then options."""
    return len(payload) >= 4 and payload[0] == 0 and payload[1] in (0, 1)


#: Selector parameters that choose how a payload is read, not options of the request.
READING_PARAMETERS = ("type", "content_type")


@dataclass(frozen=True)
class Selector:
    """A query's selector parameters ("a=1;b=2", a repeated value as "viewpoint=0,0,0|1,0,0", as Zenoh writes
    them): by name (last value), and the repeatable viewpoint and camera_pose of a file upload."""

    values: dict[str, list[str]]

    @classmethod
    def parse(cls, parameters: str) -> Selector:
        out: dict[str, list[str]] = {}
        for part in parameters.split(";"):
            name, _, value = part.partition("=")
            if name.strip():
                out.setdefault(name.strip(), []).extend(v.strip() for v in value.split("|"))
        return cls(out)

    def get(self, name: str, default: str = "") -> str:
        found = self.values.get(name)
        return found[-1] if found else default

    def upload_query(self) -> tuple[dict[str, str], list[str], list[str]]:
        """(options by name, viewpoints, camera poses) of a file upload, as HTTP's query string gives them."""
        options = {k: v[-1] for k, v in self.values.items() if k not in READING_PARAMETERS and v}
        return options, self.values.get("viewpoint", []), self.values.get("camera_pose", [])


def input_name(selector: Selector) -> str:
    """The input of a CDR query from its selector parameters: type=pointcloud2 (default), cloud_sources,
    cloud_indexed, cloud_samples, or the ROS type name (gpd_ros/msg/CloudSources, gpd_ros/CloudSources)."""
    given = selector.get("type")
    if not given:
        return "pointcloud2"
    for name, ros_type in INPUT_TYPES.items():
        if given in (name, ros_type, ros_type.replace("/msg/", "/")):
            return name
    raise Problem(400, f"unknown message type {given!r}; known: {sorted(INPUT_TYPES)} or their ROS names",
                  "type")


def parse_payload(payload: bytes, name: str, options: StreamOptions, selector: Selector | None = None) -> Parsed:
    """A request from a query's payload: a CDR ROS message of input `name`, detected with the run-time options
    (its header the answer's "header" and the Outcome's context, a graspd.io.ros Header); else what HTTP's
    POST /detect takes (requests.parse_body, the same parser and limits): a JSON DetectRequest, or a capture file
    (PCD, PLY, NPY, NPZ, a 16-bit depth PNG, a ROS bag) with its options as selector parameters (content_type
    may name the file's type; else it is told by its first bytes)."""
    if looks_like_cdr(payload):
        msg = decode_input(payload, name, options)
        return stream_request(msg, options, header=ros_header(msg.header), context=msg.header)
    if name != "pointcloud2":
        raise Problem(400, f"payload is not a CDR {INPUT_TYPES[name]}", "payload")
    selector = selector or Selector({})
    try:
        kind = sniff(payload, selector.get("content_type"))
    except Problem:
        raise Problem(400, "payload is not a CDR PointCloud2, a JSON DetectRequest nor a capture file (PCD, PLY, "
                      "NPY, NPZ, a 16-bit depth PNG or a ROS bag)", "payload") from None
    if kind == "json":
        return Parsed(guarded_parse(parse_request, payload))
    query, viewpoints, poses = selector.upload_query()
    return Parsed(parse_request(upload_request(payload, kind, query, viewpoints, poses)))


class Queries:
    """The queryables' callbacks (each run in a fresh context: one request id per query).  options() gives the
    run-time options; info() this server's instance info, answered on instance_key."""

    def __init__(self, gate: Gate, lifecycle: Lifecycle, options: Callable[[], StreamOptions],
                 info: Callable[[], dict[str, Any]], instance_key: str) -> None:
        self.gate = gate
        self.lifecycle = lifecycle
        self.options = options
        self.info = info
        self.instance_key = instance_key
        self._templates_pool = ThreadPoolExecutor(1, thread_name_prefix="graspd-zenoh-templates")

    def close(self) -> None:
        self._templates_pool.shutdown(wait=True, cancel_futures=True)

    def on_detect(self, query: Any, key: str) -> None:
        """Check the query (token, key, size), take a place in the engine's queue (503 when full, before the
        payload is even copied), then parse and detect on a worker; the reply is sent from the worker when done
        (the Zenoh thread is never blocked, nor the payload parsed on it)."""
        t0 = time.perf_counter()
        begin_request()
        tracked = self.lifecycle.track("zenoh")
        try:
            self.gate.check(query, key)
            selector = Selector.parse(str(query.parameters))
            name = input_name(selector)
            self.lifecycle.admit()
        except Problem as exc:
            self.gate.reply(query, tracked, exc)
            return
        except Exception:  # a server fault before admission: still an answer
            self._fault(query, tracked, "zenoh detect failed")
            return

        def answer(outcome: Outcome | None, problem: Problem | None) -> None:
            body = None if outcome is None else response_json(outcome)
            self.gate.reply(query, tracked, problem, body, key)

        try:
            self.lifecycle.start(lambda: parse_payload(payload_of(query), name, self.options(), selector),
                                 {"read": time.perf_counter() - t0}, answer, "zenoh detect", size_of(query.payload))
        except Problem as exc:  # shutting down (the place was given back)
            self.gate.reply(query, tracked, exc)
        except Exception:
            self._fault(query, tracked, "zenoh detect failed")

    def on_info(self, query: Any) -> None:
        begin_request()
        tracked = self.lifecycle.track("zenoh", "instance")
        try:
            self.gate.check(query)
            self.gate.reply(query, tracked, None, json.dumps(self.info()).encode(), self.instance_key)
        except Problem as exc:
            self.gate.reply(query, tracked, exc)
        except Exception:
            self._fault(query, tracked, "zenoh instance info failed")

    def on_templates(self, query: Any, name: str, key: str, work: Callable[[bytes], Any]) -> None:
        """A demonstrations/feedback/library query: checked here (token, exact key, size); the payload is
        copied, parsed and worked on by a small pool, not the Zenoh thread."""
        begin_request()
        tracked = self.lifecycle.track("zenoh", name)
        try:
            self.gate.check(query, key)
        except Problem as exc:
            self.gate.reply(query, tracked, exc)
            return
        except Exception:
            self._fault(query, tracked, f"zenoh {name} failed")
            return

        def run() -> None:
            try:
                out = work(payload_of(query))
                self.gate.reply(query, tracked, None, json.dumps(out).encode(), key)
            except Problem as exc:
                self.gate.reply(query, tracked, exc)
            except Exception:
                self._fault(query, tracked, f"zenoh {name} failed")

        try:  # the work's own log lines carry the request id too
            self._templates_pool.submit(contextvars.copy_context().run, run)
        except RuntimeError:  # shutting down
            self.gate.reply(query, tracked, shutting_down())

    def _fault(self, query: Any, tracked: Tracked, what: str) -> None:
        """A server fault: the traceback in the log, a 500 that says nothing internal in the reply."""
        rid = "-" if tracked.ctx is None else tracked.ctx.id
        log.exception(what, extra={"request_id": rid})
        self.gate.reply(query, tracked, internal_error(rid))
