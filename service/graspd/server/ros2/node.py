"""The ROS 2 node: one DDS participant that ROS 2 nodes see as /graspd (ros_discovery_info), its topics and its
two services, all fed through the server's one DetectionEngine (the same admission, queue, deadline, memory
budget and request checks as HTTP and Zenoh) and the Zenoh stream's ROS layer (graspd.server.services.ros_stream:
decoding, options, camera poses, outputs).

Clouds: the four input topics keep only the newest cloud (a robot wants grasps for what it sees now; a cloud
replaced before detection is counted in graspd_stream_dropped); one thread detects it and publishes, each with
the cloud's header: GraspConfigList, PoseArray, one moveit_msgs/Grasp per grasp with finger postures, the scene's
objects (vision_msgs/Detection3DArray on graspd/objects) and MarkerArray, then the JSON answer, all encoded from the
engine's Outcome.  A CloudIndexed's indices and a CloudSamples' samples are the request's target
(graspd.server.services.ros_stream.message_target), as target.indices and target.points are over HTTP.  A sample over
GRASPD_MAX_BODY_BYTES, malformed, lying about its sizes, with no finite point or beyond the coordinate bound is
dropped with a JSON error body (status, error, field, topic) on graspd/errors; the node keeps serving.

Services: each request takes a place in the engine's queue on arrival (a full queue answers at once); decoding
and detection run on a worker; the reply carries the request's rmw_cyclonedds header.  detect_grasps answers a
GraspConfigList (empty, with the error on graspd/errors, when the request is refused); plan_grasps answers
moveit_msgs/Grasp[] on its target's box (graspd.server.ros2.moveit) in the target's frame and a MoveItErrorCodes.
Both publish the detection's objects on graspd/objects.  A target that selects nothing is refused like other bad
input: the error on graspd/errors naming the ROS field (indices, samples, target) and an empty answer (plan_grasps:
PLANNING_FAILED with the reason).

Frames: a cloud is in its header.frame_id; with camera_poses and points_frame "camera" in the options (stream
options laid over by GRASPD_ROS2_OPTIONS) it is moved into the robot frame (robot_frame_id, default base_link)
and every output names that frame (graspd.core.frames, as the HTTP and Zenoh entrances do).
"""

from __future__ import annotations

import contextvars
import functools
import json
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.gpd.target import Target
from graspd.io.ros import CloudMessage, Header, RosDecodeError, encode_grasp_config_list
from graspd.io.ros.encode import moveit_grasp_messages
from graspd.io.ros.planning import decode_plan_target
from graspd.io.ros.types import MOVEIT_GRASP, typestore
from graspd.server.logs import begin_request
from graspd.server.metrics import Metrics
from graspd.server.problems import Problem, error_body, internal_error, invalid, too_large
from graspd.server.services.budget import message_cost
from graspd.server.services.engine import DetectionEngine
from graspd.server.services.lifecycle import Lifecycle
from graspd.server.services.mapping import response_json
from graspd.server.services.outcome import GraspResult, Outcome, Parsed
from graspd.server.services.ros_stream import (
    LatestFrame,
    StreamOptions,
    decode_input,
    parse_options,
    ros_header,
    ros_outputs,
    ros_problem,
    stream_request,
)
from graspd.server.settings import Settings

from . import moveit
from .admission import ServiceShare, service_share
from .dds import (
    DomainConfig,
    Participant,
    RawReader,
    RawWriter,
    Ros2SetupError,
    discovery_xml,
    latched_qos,
    participant_qos,
    reliable_qos,
    security_properties,
    sensor_qos,
)
from .interfaces import PARTICIPANT_ENTITIES_INFO, STRING, ros_types, service_topics, topic_name
from .names import INPUTS, OUTPUTS, SERVICES, resolve_names
from .objects import encode_objects
from .wire import (
    REQUEST_HEADER_BYTES,
    RequestId,
    frame_sample,
    participant_entities_info,
    request_id,
    service_id,
    split_request,
)

log = logging.getLogger("graspd.server")
#: Depth of the moveit_grasps writer's history: a burst of one message per grasp (at most max_grasps) is kept
#: whole for a reliable reader that takes them a little late.
MOVEIT_DEPTH = 256
#: Headroom of DDS's own sample-size cap over GRASPD_MAX_BODY_BYTES: samples up to it arrive and are refused
#: with a 413 on graspd/errors; larger ones DDS drops itself (with a warning in its log).
DDS_SIZE_HEADROOM = 2
#: MiB of work a GraspPlanning request holds while it is read, beyond the message (its target's bounds and the
#: newest cloud's decode).
PLAN_WORK_MB = 64.0
#: Request fields -> the GraspPlanning request's (a target error names the CollisionObject).
PLAN_FIELDS = {"target.box": "target"}


def domain_config(settings: Settings) -> DomainConfig:
    """The participant's DDS configuration from the settings: discovery range and peers, the sample-size cap,
    the user's CycloneDDS XML last (its settings win), DDS Security from the SROS2 enclave.  Ros2SetupError when
    the node would be reachable beyond this machine without DDS Security and without GRASPD_ROS2_ALLOW_ANONYMOUS,
    or a file is missing."""
    xml = discovery_xml(settings.ros2_discovery, settings.ros2_peers, settings.ros2_interfaces,
                        DDS_SIZE_HEADROOM * settings.max_body_bytes, settings.ros2_socket_buffer_bytes)
    if settings.ros2_config is not None:
        if not settings.ros2_config.is_file():
            raise Ros2SetupError(f"GRASPD_ROS2_CONFIG: {settings.ros2_config} is not a file")
        xml += f",file://{settings.ros2_config.resolve()}"
    props: dict[str, str] = {}
    if settings.ros2_security_enclave is not None:
        props = security_properties(settings.ros2_security_enclave, settings.ros2_security_plugins)
    reach = settings.ros2_discovery != "localhost" or bool(settings.ros2_peers) or settings.ros2_config is not None
    if reach and not props and not settings.ros2_allow_anonymous:
        raise Ros2SetupError(
            "the ROS 2 node would be reachable from other machines (GRASPD_ROS2_DISCOVERY="
            f"{settings.ros2_discovery}, peers {settings.ros2_peers}, config {settings.ros2_config}) with no DDS "
            "Security, so anyone there could run detections.  Set GRASPD_ROS2_SECURITY_ENCLAVE (an SROS2 enclave), "
            "or keep GRASPD_ROS2_DISCOVERY=localhost; on a trusted network only, GRASPD_ROS2_ALLOW_ANONYMOUS=true")
    loopback = settings.ros2_discovery == "localhost" and settings.ros2_config is None
    return DomainConfig(settings.ros2_domain_id, xml, participant_qos("/", props), loopback_only=loopback,
                        loopback_strict=not settings.ros2_allow_anonymous)


class Ros2Node:
    """Owns the DDS participant; start() declares everything, close() takes it down (running work finishes in
    the engine, whose shutdown follows)."""

    def __init__(self, settings: Settings, engine: DetectionEngine, metrics: Metrics) -> None:
        self.settings = settings
        self.engine = engine
        self.metrics = metrics
        self.lifecycle = Lifecycle(engine, metrics)
        self.distro = settings.ros2_distro
        self.store = ros_types(self.distro)
        try:
            self.names = resolve_names(settings.ros2_topics, settings.ros2_namespace)
        except ValueError as exc:
            raise Ros2SetupError(str(exc)) from None
        base = {"num_samples": settings.stream_num_samples, **settings.stream_options, **settings.ros2_options}
        try:
            self.options: StreamOptions = parse_options(base, {}, (settings.stream_viewpoint,))
        except Problem as exc:
            raise Ros2SetupError(f"GRASPD_ROS2_OPTIONS / GRASPD_STREAM_OPTIONS: {exc.field}: {exc.message}") from None
        hand = self.options.request.hand_geometry()
        self.postures = moveit.FingerPostures(tuple(settings.ros2_finger_joints),
                                              (hand or HandGeometry()).max_aperture,
                                              settings.ros2_finger_squeeze_m, settings.ros2_finger_effort)
        self.config = domain_config(settings)
        self.participant: Participant | None = None
        self.readers: list[RawReader] = []
        self.writers: dict[str, RawWriter] = {}
        self._discovery: RawWriter | None = None
        self._frames = LatestFrame()
        self._last_cloud: tuple[bytes, str, float] | None = None  # for plan_grasps: payload, input, arrival
        #: service calls admitted at once (queued or running): the engine's other workers stay free for HTTP
        self.share = ServiceShare(service_share(engine.workers))
        self._thread: threading.Thread | None = None

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Create the participant (Ros2SetupError when DDS refuses it) and declare the topics, the services and
        the node on ros_discovery_info; start the stream thread."""
        p = self.participant = Participant(self.config)
        d = self.distro
        for entry, (_, ros_type) in INPUTS.items():
            if entry in self.names:
                self.readers.append(RawReader(p, topic_name(self.names[entry]), ros_type, d, sensor_qos(),
                                              functools.partial(self._on_cloud, entry=entry)))
        for entry, (_, ros_type) in OUTPUTS.items():
            if entry in self.names:
                depth = MOVEIT_DEPTH if entry == "moveit_grasps" else 10
                self.writers[entry] = RawWriter(p, topic_name(self.names[entry]), ros_type, d, reliable_qos(depth))
        handlers: dict[str, Callable[[bytes], None]] = {"detect_grasps": self._on_detect_request,
                                                        "plan_grasps": self._on_plan_request}
        for counter, (entry, (_, srv_type)) in enumerate(SERVICES.items(), start=1):
            if entry not in self.names:
                continue
            requests, replies = service_topics(self.names[entry])
            user_data = service_id(p.guid, counter)
            self.writers[entry] = RawWriter(p, replies, f"{srv_type}_Response", d, reliable_qos(10, user_data))
            self.readers.append(RawReader(p, requests, f"{srv_type}_Request", d, reliable_qos(10, user_data),
                                          handlers[entry]))
        self._discovery = RawWriter(p, "ros_discovery_info", PARTICIPANT_ENTITIES_INFO, d, latched_qos())
        self._discovery.write(participant_entities_info(
            p.guid, self.settings.ros2_node_name, self.settings.ros2_namespace, [r.guid for r in self.readers],
            [w.guid for w in self.writers.values()], d))
        self._thread = threading.Thread(target=self._stream_loop, name="graspd-ros2-stream", daemon=True)
        self._thread.start()
        log.info("ros2 node up", extra={"domain_id": self.config.domain_id, "node": self.settings.ros2_node_name,
                                        "namespace": self.settings.ros2_namespace, "distro": d,
                                        "discovery": self.settings.ros2_discovery,
                                        "security": self.settings.ros2_security_enclave is not None,
                                        "topics": self.names})

    def close(self) -> None:
        """Stop the stream thread (after the frame in progress) and delete the participant."""
        self._frames.close()
        if self._thread is not None:
            self._thread.join(timeout=self.settings.deadline_s)
        if self.participant is not None:
            endpoints: list[Any] = [*self.readers, *self.writers.values()]
            if self._discovery is not None:
                endpoints.append(self._discovery)
            self.participant.close(endpoints)
            self.participant = None
            self.readers.clear()
            self.writers.clear()

    @property
    def ready(self) -> bool:
        return self.participant is not None and not self._frames.closed

    # ---- errors ----------------------------------------------------------------------------------------------
    def _string(self, text: str) -> bytes:
        return bytes(self.store.serialize_cdr(self.store.types[STRING](data=text), STRING))

    def publish_error(self, problem: Problem, where: str, request_id: str | None = None) -> None:
        """A JSON error body (HTTP's, plus status, the topic or service it concerns and the request id) on
        graspd/errors, and a log line."""
        body = error_body(problem, with_status=True, request_id=request_id, topic=where)
        log.warning("ros2 input refused", extra={"transport": "ros2", "topic": where, "status": problem.status,
                                                  "field": problem.field, "error": problem.message})
        self._write("errors", self._string(json.dumps(body)))

    def _write(self, entry: str, payload: bytes) -> None:
        writer = self.writers.get(entry)
        if writer is None:
            return
        try:
            writer.write(payload)
        except Exception:  # a failed write never stops the node
            log.exception("ros2 write failed", extra={"topic": writer.name})

    # ---- clouds ----------------------------------------------------------------------------------------------
    def _too_large(self, size: int) -> Problem | None:
        limit = self.settings.max_body_bytes
        return too_large("message", size, limit, "payload") if size > limit else None

    def _on_cloud(self, data: bytes, entry: str) -> None:
        """On Cyclone's listener thread: refuse an oversized sample, else make it the newest cloud."""
        try:
            problem = self._too_large(len(data))
            if problem is not None:
                self.metrics.requests.labels("ros2-stream", "too_large").inc()
                self.publish_error(problem, self.names[entry])
                return
            self._last_cloud = (data, entry, time.monotonic())
            if self._frames.put(data, entry):
                self.metrics.stream_dropped.inc()
        except Exception:  # never let an exception into Cyclone's thread
            log.exception("ros2 cloud refused")

    def _stream_loop(self) -> None:
        while (frame := self._frames.take()) is not None:
            data, entry = frame
            contextvars.Context().run(self._stream_frame, data, entry)

    def decode(self, data: bytes, entry: str) -> CloudMessage:
        """A CDR input (INPUTS entry) as detection sees it (graspd.server.services.ros_stream.decode_input: bounded
        decoding, coordinate checks, camera poses); Problem 422 naming the ROS field otherwise."""
        return decode_input(data, entry, self.options)

    def _stream_frame(self, data: bytes, entry: str) -> None:
        """Detect on one cloud and publish its outputs with its header, then the JSON answer; an error on
        graspd/errors instead."""
        t0 = time.perf_counter()
        ctx = begin_request()
        tracked = self.lifecycle.track("ros2", label="ros2-stream", log_success=False, timed=False)
        try:
            msg = self.decode(data, entry)
            parsed = stream_request(msg, self.options, header=ros_header(msg.header), context=msg.header)
            outcome = self.lifecycle.detect_sync(lambda: parsed, {"decode": time.perf_counter() - t0})
            self._publish_outputs(outcome, msg.header)
            self._write("json", self._string(response_json(outcome).decode()))
            tracked.finish()
        except Problem as exc:
            self.publish_error(ros_problem(exc), self.names[entry], ctx.id)
            tracked.finish(exc)
        except Exception:  # keep serving whatever one frame did
            log.exception("ros2 detect failed", extra={"request_id": ctx.id})
            problem = internal_error(ctx.id)
            self.publish_error(problem, self.names[entry], ctx.id)
            tracked.finish(problem)

    def _publish_outputs(self, outcome: Outcome, header: Header) -> None:
        """The ROS outputs of one detection with the cloud's header, GraspConfigList first, MarkerArray last."""
        try:
            result, approach = outcome.result, outcome.request.approach_distance
            for entry, message in ros_outputs(result.grasps, header, result.hand, approach,
                                              {"grasp_config_list", "pose_array"} & set(self.writers)):
                self._write(entry, message)
            if "moveit_grasps" in self.writers:
                store = typestore()
                for msg in self.moveit_messages(result, header, approach, np.eye(4)):
                    self._write("moveit_grasps", bytes(store.serialize_cdr(msg, MOVEIT_GRASP)))
            self.publish_objects(result, header)
            for entry, message in ros_outputs(result.grasps, header, result.hand, approach,
                                              {"marker_array"} & set(self.writers)):
                self._write(entry, message)
        except Exception:  # the outputs failed; the detection and its JSON answer still stand
            log.exception("ros2 outputs failed")

    def publish_objects(self, result: GraspResult, header: Header) -> None:
        """The detection's objects as a vision_msgs/Detection3DArray with header (the detection's frame) on
        graspd/objects."""
        if "objects" in self.writers:
            self._write("objects", encode_objects(self.store, result.objects, header))

    def moveit_messages(self, result: GraspResult, header: Header, approach_distance: float,
                        to_output: np.ndarray, id_prefix: str = "graspd") -> list[Any]:
        """moveit_msgs/Grasp messages of a detection, moved by to_output (4x4, detection frame -> header's
        frame), ids "<id_prefix>/<rank>": finger postures from each grasp's width, retreat along "up" when the
        detection found it, else back along the approach."""
        grasps = result.grasps
        rot, shift = to_output[:3, :3], to_output[:3, 3]
        moved = grasps.transformed(rot, shift)
        up = None if result.up is None else rot @ result.up
        widths = grasps.widths.tolist()
        store = typestore()
        options: dict[str, Any] = {"approach_distance": approach_distance, "id_prefix": id_prefix,
                                   "postures": lambda i: self.postures.messages(store, widths[i])}
        if up is not None:
            options["retreat_direction"] = up
        messages = moveit_grasp_messages(moved, header, **options)
        if up is None:  # no "up": retreat the way the hand came
            vec = store.types["geometry_msgs/msg/Vector3"]
            for msg, a in zip(messages, moved.approach.tolist(), strict=True):
                msg.post_grasp_retreat.direction.vector = vec(x=-a[0], y=-a[1], z=-a[2])
        return messages

    # ---- services --------------------------------------------------------------------------------------------
    def _service_call(self, data: bytes, entry: str, prepare: Callable[[bytes, float], Parsed],
                      finish: Callable[[RequestId, Outcome], bytes], refuse: Callable[[RequestId, Problem], bytes],
                      fields: dict[str, str] | None = None) -> None:
        """On Cyclone's listener thread: read the request header, take a place in the engine's queue (a refusal
        is answered at once), and queue the work: prepare(sample, deadline) decodes the request on a worker (the
        Parsed's context keeps what finish needs), the engine detects, finish(request id, outcome) builds the
        reply, written from the worker, and the objects go out on graspd/objects; a refusal or failure is
        answered by refuse(), its field named as the request names it (fields: request field -> ROS field,
        ros_stream.ros_problem)."""
        ctx = begin_request()
        where = self.names[entry]
        try:
            rid = request_id(data)
        except RosDecodeError as exc:  # no header: nobody to answer
            self.publish_error(invalid(str(exc), exc.field), where, ctx.id)
            return
        tracked = self.lifecycle.track("ros2", label="ros2-service")
        try:
            problem = self._too_large(len(data))
            if problem is not None:
                raise problem
            self.share.take(self.engine.retry_after())
            try:
                self.lifecycle.admit()
            except Problem:
                self.share.give()
                raise
        except Problem as exc:
            self.publish_error(exc, where, ctx.id)
            self._write(entry, refuse(rid, exc))
            tracked.finish(exc, outcome="refused")
            return
        deadline = time.perf_counter() + self.settings.deadline_s
        held = [data]  # the sample, dropped once parsed (a message of megabytes is not kept through detection)

        def answer(outcome: Outcome | None, problem: Problem | None) -> None:  # on the worker, or at the deadline
            if outcome is not None:
                self._write(entry, finish(rid, outcome))
                self.publish_objects(outcome.result, outcome.context["msg"].header)
                tracked.finish()
                return
            assert problem is not None
            if not isinstance(problem, moveit.PlanningError):
                problem = ros_problem(problem, fields) if fields is not None else ros_problem(problem)
                self.publish_error(problem, where, ctx.id)
            self._write(entry, refuse(rid, problem))
            tracked.finish(problem)

        try:
            work = self.lifecycle.start(lambda: prepare(held.pop(), deadline), {"read": 0.0}, answer, "ros2 service")
            work.add_done_callback(lambda _: self.share.give())  # the service share is held until the work ends
        except Problem as exc:  # shutting down (the place was given back)
            self.share.give()
            self._write(entry, refuse(rid, exc))
            tracked.finish(exc)

    # detect_grasps: gpd_ros/srv/DetectGrasps (CloudIndexed -> GraspConfigList with the cloud's header)
    def _on_detect_request(self, data: bytes) -> None:
        self._service_call(data, "detect_grasps", self._detect_prepare, self._detect_finish, self._detect_refused)

    def _detect_prepare(self, data: bytes, _deadline: float) -> Parsed:
        _, body = split_request(data)
        msg = self.decode(body, "cloud_indexed")
        return stream_request(msg, self.options, header=ros_header(msg.header), context={"msg": msg})

    def _detect_finish(self, rid: RequestId, outcome: Outcome) -> bytes:
        return frame_sample(rid, encode_grasp_config_list(outcome.result.grasps, outcome.context["msg"].header))

    def _detect_refused(self, rid: RequestId, _error: Problem) -> bytes:
        return frame_sample(rid, encode_grasp_config_list(GraspSet(), Header()))

    # plan_grasps: moveit_msgs/srv/GraspPlanning (CollisionObject target -> Grasp[] in its frame)
    def _on_plan_request(self, data: bytes) -> None:
        self._service_call(data, "plan_grasps", self._plan_prepare, self._plan_finish, self._plan_refused,
                           PLAN_FIELDS)

    def _plan_prepare(self, data: bytes, deadline: float) -> Parsed:
        """The newest cloud with the GraspPlanning request's target as a box (moveit.target_box, in the detection
        frame) and the map from the target's frame into the detection frame (moveit.frame_transform);
        PlanningError when that cannot be.  In that order, each before any cost of the next: the newest cloud's
        age, the message's memory (the engine's budget), the target's counts (core.limits, read from the
        message's sequence lengths), the cloud, the box."""
        last = self._last_cloud
        if last is None:
            raise moveit.PlanningError(moveit.UNABLE_TO_ACQUIRE_SENSOR_DATA, "no cloud received yet on "
                                       f"{', '.join(self.names[e] for e in INPUTS if e in self.names)}")
        cloud, entry, arrived = last
        age = time.monotonic() - arrived
        if age > self.settings.ros2_plan_cloud_age_s:
            raise moveit.PlanningError(moveit.SENSOR_INFO_STALE, f"the newest cloud is {age:.1f} s old (more than "
                                       f"GRASPD_ROS2_PLAN_CLOUD_AGE_S = {self.settings.ros2_plan_cloud_age_s:g})")
        budget = self.engine.budget
        wait = min(self.settings.detect_memory_wait_s, max(0.0, deadline - time.perf_counter()))
        held = budget.take(message_cost(len(data), PLAN_WORK_MB), self.engine.retry_after(), wait)
        try:
            try:
                target = decode_plan_target(data, REQUEST_HEADER_BYTES)
            except RosDecodeError as exc:
                raise Problem(422, f"not a usable moveit_msgs/srv/GraspPlanning request: {exc}", exc.field) from None
            del data
            msg = self.decode(cloud, entry)
            opts = self.options
            to_detection = moveit.frame_transform(target.header.frame_id, msg.header.frame_id,
                                                  opts.camera_frame_id or "", opts.camera_poses, opts.points_frame)
            box = moveit.target_box(target, to_detection)
        finally:
            budget.give(held)
        state = {"msg": msg, "frame": target.header.frame_id or msg.header.frame_id, "to_detection": to_detection,
                 "target_id": target.id}
        return stream_request(msg, opts, Target("box", box=box), header=ros_header(msg.header), context=state)

    def _plan_finish(self, rid: RequestId, outcome: Outcome) -> bytes:
        state, result = outcome.context, outcome.result
        header = Header(state["frame"], state["msg"].header.stamp)
        grasps = self.moveit_messages(result, header, self.options.request.approach_distance,
                                      np.linalg.inv(state["to_detection"]), state["target_id"] or "graspd")
        if not grasps:
            why = "; ".join(w.message for w in result.warnings if w.code == "target_too_small")
            return self._plan_reply(rid, [], moveit.PLANNING_FAILED,
                                    "no grasp found on the target" + (f" ({why})" if why else ""))
        return self._plan_reply(rid, grasps, moveit.SUCCESS, "")

    def _plan_reply(self, rid: RequestId, grasps: list[Any], code: int, message: str) -> bytes:
        name = "moveit_msgs/srv/GraspPlanning_Response"
        response = self.store.types[name](grasps=grasps, error_code=moveit.error_code(self.store, code, message))
        return frame_sample(rid, bytes(self.store.serialize_cdr(response, name)))

    def _plan_refused(self, rid: RequestId, error: Problem) -> bytes:
        if isinstance(error, moveit.PlanningError):
            return self._plan_reply(rid, [], error.code, error.message)
        code = moveit.TIMED_OUT if error.status == 504 else (
            moveit.PLANNING_FAILED if error.status < 500 else moveit.FAILURE)
        return self._plan_reply(rid, [], code, f"{error.status}: {error}")
