"""ROS 2 messages on the Zenoh stream (zenoh-bridge-ros2dds maps a ROS topic /graspd/cloud_sources to the key
graspd/cloud_sources): which CDR message comes in on which key, the per-stream detection options (settings,
changed at run time on <prefix>/config), and the ROS outputs of a detection.

Inputs (settings.stream_inputs, name -> key under the prefix): pointcloud2 sensor_msgs/PointCloud2 (that key also
takes a JSON DetectRequest), cloud_sources / cloud_indexed / cloud_samples gpd_ros CloudSources / CloudIndexed /
CloudSamples.  Outputs (settings.stream_outputs): json (the /detect answer), grasp_config_list gpd_ros
GraspConfigList, pose_array geometry_msgs PoseArray, moveit_grasps one moveit_msgs Grasp per grasp best first,
marker_array visualization_msgs MarkerArray (last: the slowest), errors (JSON error bodies).  A key "" turns one
off; a key starting with "/" is absolute (the prefix is not added).  Decoding is graspd.io.ros; only the mapping of
messages to requests is here.

Targets (graspd.gpd.target): a CloudIndexed's indices are a target of rows (as DetectRequest.target.indices: hands
are sampled on them only and close on no other object's points), a CloudSamples' samples a target of points (as
target.points: hands at the cloud points nearest them); a target error names the ROS field (indices, samples).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.frames import camera_positions, check_camera_source, frame_name, to_robot
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.limits import MAX_COORDINATE
from graspd.gpd.target import Target
from graspd.io.inputs import CloudInput, apply_frames, no_finite_point
from graspd.io.ros import (
    CloudMessage,
    Header,
    RosDecodeError,
    decode_cloud_indexed,
    decode_cloud_samples,
    decode_cloud_sources,
    decode_pointcloud2,
    encode_grasp_config_list,
    encode_marker_array,
    encode_moveit_grasps,
    encode_pose_array,
)
from graspd.io.ros.types import POINTCLOUD2
from graspd.server.problems import CALLER_ERRORS, Problem, too_large
from graspd.server.requests import json_object, parse_model
from graspd.server.services.outcome import Parsed
from graspd.server.wire.detect import Cloud, DetectRequest

#: Input name -> default key under the prefix, and the ROS message type it carries.
INPUT_TYPES: dict[str, str] = {"pointcloud2": "sensor_msgs/msg/PointCloud2",
                               "cloud_sources": "gpd_ros/msg/CloudSources",
                               "cloud_indexed": "gpd_ros/msg/CloudIndexed",
                               "cloud_samples": "gpd_ros/msg/CloudSamples"}
DEFAULT_INPUT_KEYS: dict[str, str] = {"pointcloud2": "cloud", "cloud_sources": "cloud_sources",
                                      "cloud_indexed": "cloud_indexed", "cloud_samples": "cloud_samples"}
#: Output name -> default key under the prefix (published in this order for each cloud).
DEFAULT_OUTPUT_KEYS: dict[str, str] = {"json": "grasps", "grasp_config_list": "grasp_config_list",
                                       "pose_array": "grasp_poses", "moveit_grasps": "moveit_grasps",
                                       "marker_array": "grasp_markers", "errors": "errors"}
#: Most bytes a config put or query may carry (a DetectRequest's options are a few hundred bytes).
MAX_CONFIG_BYTES = 64 << 10
#: DetectRequest fields that are not stream options and why: the cloud (and what to grasp in it) comes with each
#: message, crops need an image.
NOT_OPTIONS = {"cloud": "the cloud comes in the message",
               "crops": "the cloud comes in the message",
               "target": "a target names rows of one cloud: send a gpd_ros CloudIndexed or CloudSamples"}
#: The request's target fields -> the ROS fields that carry them (a target error names the field the sender set).
TARGET_FIELDS = {"target.indices": "indices", "target.points": "samples"}
_PLACEHOLDER_POINTS = [[0.0, 0.0, 1.0]]
_DECODERS: dict[str, Callable[[bytes], CloudMessage]] = {
    "cloud_sources": decode_cloud_sources, "cloud_indexed": decode_cloud_indexed,
    "cloud_samples": decode_cloud_samples}
#: Where each input message keeps its point data (the field an empty or out-of-range cloud is reported under).
_DATA_FIELD = {"pointcloud2": "data", "cloud_sources": "cloud.data", "cloud_indexed": "cloud_sources.cloud.data",
               "cloud_samples": "cloud_sources.cloud.data"}


class LatestFrame:
    """The one-slot mailbox of a streamed transport (Zenoh, the ROS 2 node): a cloud not yet taken is replaced
    by a newer one (a robot wants grasps for the scene as it is now), and the stream thread takes them one at a
    time.  Thread-safe; put() comes from the transport's listener thread."""

    def __init__(self) -> None:
        self._item: tuple[bytes, str] | None = None
        self._wake = threading.Condition()
        self.closed = False

    def put(self, payload: bytes, name: str) -> bool:
        """Make (payload, input name) the newest frame; True when it replaced one never taken (a dropped frame)."""
        with self._wake:
            dropped = self._item is not None
            self._item = (payload, name)
            self._wake.notify()
        return dropped

    def take(self) -> tuple[bytes, str] | None:
        """Wait for the next frame; None once closed (a frame put before close() is not taken)."""
        with self._wake:
            while self._item is None and not self.closed:
                self._wake.wait()
            if self.closed:
                return None
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        """Wake the stream thread to stop, after the frame in progress."""
        with self._wake:
            self.closed = True
            self._wake.notify_all()



def resolve_keys(prefix: str, given: Mapping[str, str], defaults: Mapping[str, str], setting: str) -> dict[str, str]:
    """Full Zenoh keys by name: the defaults overridden by given (unknown names and wildcards refused with
    ValueError naming the setting); "" drops a name, a leading "/" makes a key absolute."""
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise ValueError(f"{setting}: unknown names {unknown}; known: {sorted(defaults)}")
    out = {}
    for name, key in {**defaults, **given}.items():
        if not key:
            continue
        if any(c in key for c in "*$?#") or "//" in key or key.endswith("/"):
            raise ValueError(f"{setting}.{name}: {key!r} is not a plain key expression (no wildcards)")
        out[name] = key[1:] if key.startswith("/") else f"{prefix}/{key}"
    return out


#: Stream options that are not DetectRequest fields: where a PointCloud2's camera is (viewpoints, or camera_poses
#: with points_frame, as in a request's cloud) and the ROS frame names (camera_frame_id: the frame_id a
#: camera-frame cloud must carry, none: any; robot_frame_id: the frame the camera poses map into, which the ROS
#: outputs and the JSON answer's header name).
CLOUD_OPTIONS = ("viewpoints", "camera_poses", "points_frame")
FRAME_ID_OPTIONS = ("camera_frame_id", "robot_frame_id")
DEFAULT_ROBOT_FRAME_ID = "base_link"


@dataclass(frozen=True)
class StreamOptions:
    """The detection options of streamed clouds and CDR queries: a validated DetectRequest (its cloud a
    placeholder), the camera positions a PointCloud2 is seen from (or the camera poses, graspd.core.frames), the ROS
    frame names, and the JSON they were set from."""

    request: DetectRequest
    viewpoints: NDArray[np.float64]
    source: dict[str, Any]
    camera_poses: NDArray[np.float64] | None = None
    points_frame: str | None = None
    camera_frame_id: str | None = None
    robot_frame_id: str | None = None

    @property
    def output_frame_id(self) -> str:
        """The frame_id of the outputs of a camera-frame cloud moved into the robot frame."""
        return self.robot_frame_id or DEFAULT_ROBOT_FRAME_ID

    def to_json(self) -> bytes:
        """What GET <prefix>/config answers: the options in force (settings, then the last accepted put)."""
        return json.dumps({**self.source, "viewpoints": self.viewpoints.tolist()}).encode()


def parse_options(payload: bytes | str | dict[str, Any], base: Mapping[str, Any],
                  viewpoints: NDArray[np.float64] | tuple[tuple[float, float, float], ...]) -> StreamOptions:
    """Stream options from JSON: DetectRequest fields other than cloud and crops (validated exactly like a
    DetectRequest's; Problem 400/422 naming the field), plus "viewpoints" [[x, y, z], ...] for PointCloud2
    input, or "camera_poses" and "points_frame" (as a request's cloud has them: the clouds are moved into the
    robot frame) with "camera_frame_id" and "robot_frame_id" (CLOUD_OPTIONS, FRAME_ID_OPTIONS).  They are laid
    over base (the settings' stream options): a put names what differs from the settings (null clears a frame
    option)."""
    if isinstance(payload, bytes | str):
        size = len(payload)
        if size > MAX_CONFIG_BYTES:
            raise too_large("config", size, MAX_CONFIG_BYTES, "payload")
    obj = json_object(payload)
    for name, why in NOT_OPTIONS.items():
        if name in obj:
            raise Problem(422, f"{name!r} is not a stream option ({why})", name)
    merged = {k: v for k, v in {**base, **obj}.items() if not (k in CLOUD_OPTIONS[1:] and v is None)}
    source = dict(merged)
    ids: dict[str, str] = {}
    for name in FRAME_ID_OPTIONS:
        value = merged.pop(name, None)
        if value is not None and (not isinstance(value, str) or not 0 < len(value) <= 256):
            raise Problem(422, "a ROS frame name (1 to 256 characters) expected", name)
        if value is not None:
            ids[name] = value
    cloud: dict[str, Any] = {"points": _PLACEHOLDER_POINTS}
    for name in CLOUD_OPTIONS[1:]:
        if name in merged:
            cloud[name] = merged.pop(name)
    if "camera_poses" in cloud:
        cloud["camera_source"] = [0]  # a placeholder: each message says which camera saw its points
    vps = merged.pop("viewpoints", None)
    if vps is not None or "camera_poses" not in cloud:  # camera poses replace the settings' viewpoint
        cloud["viewpoints"] = np.asarray(viewpoints, np.float64).tolist() if vps is None else vps
    try:
        req = parse_model(DetectRequest, {**merged, "cloud": cloud})
    except Problem as exc:
        if exc.field is not None and exc.field.startswith("cloud."):  # the stream option is named without cloud.
            raise Problem(exc.status, exc.message, exc.field[len("cloud."):]) from None
        raise
    poses = req.cloud.poses()  # with them, the viewpoints are the cameras' positions in the robot frame
    viewpoints = np.asarray(req.cloud.viewpoints, np.float64) if poses is None else camera_positions(poses)
    return StreamOptions(req, viewpoints, source, poses, req.cloud.points_frame, ids.get("camera_frame_id"),
                         ids.get("robot_frame_id"))


def decode_input(payload: bytes, name: str, options: StreamOptions) -> CloudMessage:
    """The CloudMessage of a CDR payload arriving as input name (INPUT_TYPES); Problem 422 naming the ROS field
    of a malformed message (a PointCloud2 is seen from the options' viewpoints, all its points from the first)."""
    try:
        if name == "pointcloud2":
            msg = decode_pointcloud2(payload, options.viewpoints[:1])
        else:
            msg = _DECODERS[name](payload)
    except RosDecodeError as exc:
        raise Problem(422, f"not a usable {INPUT_TYPES[name]}: {exc}", exc.field) from None
    pts = msg.cloud.points
    if len(pts) == 0:
        raise Problem(422, no_finite_point(msg.received) if msg.received else
                      "empty cloud (0 points); send at least one point", _DATA_FIELD[name])
    if max(float(pts.max()), -float(pts.min())) > MAX_COORDINATE:  # no |pts| temporary
        raise Problem(422, f"coordinates beyond +-{MAX_COORDINATE:g} m; send metres in a local frame",
                      _DATA_FIELD[name])
    return in_robot_frame(msg, options)


def in_robot_frame(msg: CloudMessage, options: StreamOptions) -> CloudMessage:
    """The message as detection sees it: unchanged without camera poses in the options; with them, its cloud in
    the robot frame (graspd.io.inputs.apply_frames: a camera-frame cloud is moved by the poses, camera_source picking
    the pose; samples of a CloudSamples by the first pose) and its header naming the frame the grasps will be in
    (robot_frame_id, default base_link, for a camera-frame cloud).  Problem 422 naming header.frame_id when the
    cloud's frame is not the one the options say (camera_frame_id for points_frame camera, robot_frame_id for
    robot; either checked only when set): the pose would be applied to the wrong cloud."""
    poses = options.camera_poses
    if poses is None:
        return msg
    camera = options.points_frame == "camera"
    try:  # a PointCloud2 says nothing of which camera saw a point: one pose only
        check_camera_source(options.points_frame, len(poses), msg.msg_type != POINTCLOUD2, "camera_poses")
    except CALLER_ERRORS as exc:
        raise Problem(422, f"a {POINTCLOUD2} of points in the camera's frame takes one camera pose, "
                      f"{len(poses)} are set: send a gpd_ros CloudSources (camera_source per point)",
                      exc.field) from None
    expected = options.camera_frame_id if camera else options.robot_frame_id
    got = msg.header.frame_id
    if expected is not None and got and got.lstrip("/") != expected.lstrip("/"):
        setting = "camera_frame_id" if camera else "robot_frame_id"
        raise Problem(422, f"the cloud is in frame {got!r}, the stream's camera pose is for {expected!r} "
                      f"(points_frame {options.points_frame!r}); set {setting} and camera_poses on the config key "
                      "to match the camera", "header.frame_id")
    try:
        cloud, _frame = apply_frames(msg.cloud, poses, options.points_frame)
    except CloudError as exc:
        field = "camera_source" if exc.field.endswith("camera_source") else exc.field
        raise Problem(422, exc.message, field) from None
    samples = msg.samples
    if camera and samples is not None and len(samples):
        samples = to_robot(samples, np.zeros(len(samples), np.int64), poses[:1])[0].astype(np.float64)
    header = Header(options.output_frame_id, msg.header.stamp) if camera else msg.header
    return replace(msg, cloud=cloud, samples=samples, header=header)


def message_target(msg: CloudMessage) -> Target | None:
    """The target a message names (None: grasps anywhere): a CloudIndexed's indices as rows of its decoded cloud,
    a CloudSamples' samples as points (header frame, m).  Problem 422 naming indices or samples when they select
    nothing (none given, or only rows dropped for a non-finite coordinate)."""
    if msg.sample_indices is not None:
        if not len(msg.sample_indices):
            raise Problem(422, "selects no row of the cloud with finite coordinates" if msg.dropped else
                          "selects no row (empty): name the target's rows, or send a CloudSources", "indices")
        rows = np.zeros(len(msg.cloud), bool)
        rows[msg.sample_indices] = True
        return Target("indices", rows=rows)
    if msg.samples is not None:
        if not len(msg.samples):
            raise Problem(422, "no sample point given (empty): give points, or send a CloudSources", "samples")
        return Target("points", points=np.asarray(msg.samples, np.float64))
    return None


def stream_request(msg: CloudMessage, options: StreamOptions, target: Target | None = None, *,
                   header: dict[str, Any] | None = None, context: Any = None) -> Parsed:
    """The engine request for a decoded message under the stream options: the options' request with the
    message's cloud, which the engine runs on as decoded (no revalidation of the points: the decoder bounded
    them, decode_input checked them as the JSON cloud is checked; normals kept; in the robot frame with camera
    poses), with target, else the message's own (message_target: its rows or sample points).  header and
    context: the Parsed's (the answer's ROS header, what the transport keeps for its answer)."""
    cloud = msg.cloud
    fields = {name: getattr(options.request, name) for name in DetectRequest.model_fields}
    fields["cloud"] = Cloud.model_construct(points=cloud.points, viewpoints=cloud.viewpoints.astype(np.float64),
                                            camera_source=cloud.camera_source)
    req = DetectRequest.model_construct(_fields_set=options.request.model_fields_set, **fields)
    given = CloudInput(cloud, frame_name(options.camera_poses), msg.dropped, msg.received)
    return Parsed(req, given, target if target is not None else message_target(msg), header, context)


def ros_problem(problem: Problem, fields: Mapping[str, str] = TARGET_FIELDS) -> Problem:
    """problem naming the ROS field a request field came from (fields: request field -> ROS field), e.g. a
    detector's target error on target.indices as one on the CloudIndexed's indices; others unchanged."""
    field = problem.field
    if field is None or field not in fields:
        return problem
    return Problem(problem.status, problem.message, fields[field], problem.retry_after)


def ros_header(header: Header) -> dict[str, Any]:
    """The JSON answer's "header" of a ROS input."""
    return {"frame_id": header.frame_id, "stamp": {"sec": header.stamp[0], "nanosec": header.stamp[1]}}


def ros_outputs(grasps: GraspSet, header: Header, hand: HandGeometry, approach_distance: float,
                names: Collection[str]) -> Iterator[tuple[str, bytes]]:
    """(output name, CDR), encoded one by one in publication order, for the outputs in names: GraspConfigList,
    PoseArray, one moveit_msgs/Grasp per grasp (best first; pre-grasp approach of approach_distance m along
    the approach), and last the MarkerArray (its encoding is the slowest)."""
    if "grasp_config_list" in names:
        yield "grasp_config_list", encode_grasp_config_list(grasps, header)
    if "pose_array" in names:
        yield "pose_array", encode_pose_array(grasps, header)
    if "moveit_grasps" in names:
        for message in encode_moveit_grasps(grasps, header, approach_distance=approach_distance):
            yield "moveit_grasps", message
    if "marker_array" in names:
        yield "marker_array", encode_marker_array(grasps, header, hand)
