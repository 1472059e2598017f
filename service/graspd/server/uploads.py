"""Raw file uploads to POST /detect: PCD, PLY, NPY, NPZ or a depth image (16-bit PNG, or an .npy of metres, with
intrinsics), its points plus options from query parameters, turned into the same request object as the JSON body
(so NaN rows, camera poses and every limit are handled as for JSON: graspd.io.inputs, graspd.core.frames)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

import numpy as np
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from graspd.core.camera import Intrinsics
from graspd.core.cloud import CloudError
from graspd.core.frames import POINTS_FRAMES, pose_matrix
from graspd.core.limits import MAX_TARGET_INDICES, MAX_VIEWPOINTS
from graspd.io.bag import BagQuery, bag_kind, read_bag
from graspd.io.calibration import CameraCalibration, looks_like_calibration, parse_calibration
from graspd.io.cloud_files import (
    NPY_MAGIC,
    NPZ_ARRAYS,
    ZIP_MAGIC,
    file_arrays,
    image_arrays,
    nearest_camera,
    parse_npz,
    read_pcd,
    read_ply,
)
from graspd.io.depth import DEFAULT_DEPTH_SCALE, PNG_MAGIC
from graspd.server.problems import CALLER_ERRORS, Problem, from_error, from_wire
from graspd.server.wire.detect import DetectRequest

PCD_TYPES = ("application/x-pcd", "application/pcd", "image/x-pcd")
PLY_TYPES = ("application/ply", "application/x-ply", "model/ply", "text/ply")
NPY_TYPES = ("application/x-npy", "application/npy")
NPZ_TYPES = ("application/x-npz", "application/npz", "application/zip")
PNG_TYPES = ("image/png",)
BAG_TYPES = ("application/x-mcap", "application/mcap", "application/x-rosbag", "application/x-ros-bag",
             "application/vnd.sqlite3", "application/x-sqlite3")
#: What a file upload may be, and how it is recognised (content type, else its first bytes).
UPLOAD_KINDS = ("pcd", "ply", "npy", "npz", "png", "bag")


def sniff(data: bytes, content_type: str) -> str:
    """'json', 'pcd', 'ply', 'npy', 'npz' or 'png' (a depth image) from the content type, else from the first
    bytes."""
    ct = content_type.split(";")[0].strip().lower()
    if ct == "application/json" or ct.endswith("+json"):
        return "json"
    for kind, types in (("pcd", PCD_TYPES), ("ply", PLY_TYPES), ("npy", NPY_TYPES), ("npz", NPZ_TYPES),
                        ("png", PNG_TYPES), ("bag", BAG_TYPES)):
        if ct in types:
            return kind
    for kind, magic in (("npy", NPY_MAGIC), ("npz", ZIP_MAGIC), ("png", PNG_MAGIC)):
        if data.startswith(magic):
            return kind
    if bag_kind(data) is not None:
        return "bag"
    head = data[:512].lstrip()
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith((b"# .PCD", b"VERSION", b"FIELDS")) or b"\nFIELDS " in head:
        return "pcd"
    if head.startswith(b"{"):
        return "json"
    raise Problem(415, "not JSON, PCD, PLY, NPY, NPZ, a depth PNG or a ROS bag; send a DetectRequest as "
                  "application/json or a .pcd/.ply/.npy/.npz file, a 16-bit depth PNG with intrinsics, or an MCAP or "
                  "ROS 1 bag with topic", "body")


@dataclass(frozen=True)
class QueryParam:
    """One upload query parameter: a DetectRequest field (or viewpoint) and how its text is read.  kind: "bool"
    (true/false/1/0), "vector" (n comma-separated numbers), "text" (the string itself; pydantic converts numbers
    and checks it as it checks the JSON field)."""

    name: str
    kind: Literal["bool", "vector", "text"]
    schema: dict[str, Any]
    description: str
    length: int = 0


def _unwrap(annotation: Any) -> Any:
    """T from T | None."""
    args = [a for a in get_args(annotation) if a is not type(None)]
    return args[0] if get_origin(annotation) in (Union, UnionType) and len(args) == 1 else annotation


def _query_param(name: str, info: FieldInfo, schema: dict[str, Any]) -> QueryParam | None:
    """The query form of a DetectRequest field, None when it has none (objects: cloud, approach, crops)."""
    kind = _unwrap(info.annotation)
    description = info.description or ""
    if isinstance(kind, type) and issubclass(kind, BaseModel):  # a model with a string shorthand (hand, environment)
        form = getattr(kind, "STRING_FORM", None)
        if form is None:
            return None
        inner = kind.model_json_schema()["properties"][form]
        sub = {k: v for k, v in inner.items() if k in ("type", "enum")} or {"type": "string"}
        sub["type"] = "string"
        return QueryParam(name, "text", sub, f"the {form} (a plain string of the JSON field): "
                          f"{inner.get('description', description)}")
    if get_origin(kind) is list:
        n = next((m.min_length for m in info.metadata if getattr(m, "min_length", None)), 0)
        return QueryParam(name, "vector", {"type": "string"}, f"{n} comma-separated numbers: {description}", n)
    sub = {k: v for k, v in schema.items() if k not in ("anyOf", "default", "title", "description")}
    if "anyOf" in schema:  # T | None: the query form is T
        sub.update(next(s for s in schema["anyOf"] if s.get("type") != "null"))
    return QueryParam(name, "bool" if sub.get("type") == "boolean" else "text", sub, description)


#: The query forms of a request's target (DetectRequest.target; at most one of them).  A mask has no query form.
TARGET_PARAMS: dict[str, QueryParam] = {
    "target_indices": QueryParam(
        "target_indices", "text", {"type": "string"}, "target.indices: comma-separated rows of the file's cloud "
        f"(0-based; NaN rows count; at most {MAX_TARGET_INDICES})"),
    "target_box": QueryParam(
        "target_box", "vector", {"type": "string"}, "target.box: 'cx,cy,cz,qx,qy,qz,qw,hx,hy,hz', the centre (m), "
        "the rotation as a unit quaternion x, y, z, w and the half extents (m), in the request's frame", 10),
    "target_object": QueryParam(
        "target_object", "text", {"type": "integer", "minimum": 0}, "target.object: an object id of an earlier "
        "answer for the same cloud"),
}


def _target(query: Mapping[str, str]) -> dict[str, Any] | None:
    """The request's target from its query form (TARGET_PARAMS), None without one; Problem naming the parameter."""
    given = [name for name in TARGET_PARAMS if name in query]
    if len(given) > 1:
        raise Problem(422, f"at most one target parameter, got {given}", given[1])
    if not given:
        return None
    name, text = given[0], query[given[0]]
    if name == "target_box":
        v = _floats(text, 10, name)
        return {"box": {"centre": v[:3], "quat_xyzw": v[3:7], "half_extents": v[7:]}}
    if name == "target_indices" and text.count(",") >= MAX_TARGET_INDICES:  # counted before any number is read
        raise Problem(422, f"{text.count(',') + 1} rows exceeds the limit of {MAX_TARGET_INDICES}", name)
    try:
        numbers = [int(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise Problem(422, f"comma-separated integers expected, got {text[:40]!r}", name) from None
    if name == "target_object":
        if len(numbers) != 1:
            raise Problem(422, f"one object id expected, got {text[:40]!r}", name)
        return {"object": numbers[0]}
    return {"indices": numbers}


#: Query parameters of a bag upload (graspd.io.bag.BagQuery).
BAG_PARAMS = {
    "topic": QueryParam("topic", "text", {"type": "string"}, "bags (MCAP or ROS 1 .bag as the body): the "
                        "PointCloud2 or depth Image topic; default the bag's only PointCloud2 topic, else its only "
                        "Image topic"),
    "index": QueryParam("index", "text", {"type": "integer", "minimum": 0}, "bags: the message of the topic "
                        "(0-based, default 0)"),
    "info_topic": QueryParam("info_topic", "text", {"type": "string"}, "bags: the CameraInfo topic of a depth "
                             "Image topic (default: its sibling camera_info)"),
    "frame": QueryParam("frame", "text", {"type": "string"}, "bags: the frame grasps are given in, through the "
                        "bag's /tf_static chain from the cloud's frame (default: the chain's root; without "
                        "/tf_static, the cloud's own frame)"),
}


def _bag_arrays(data: bytes, query: Mapping[str, str]) -> dict[str, Any]:
    """The cloud arrays of one message of an uploaded bag (graspd.io.bag: read from memory, every chunk
    decompressed under a bound), with the camera pose its /tf_static gives."""
    index = query.get("index", "0")
    if not index.isdigit() or len(index) > 9:
        raise Problem(422, f"a message index 0 or more expected, got {index!r}", "index")
    bag_query = BagQuery(topic=query.get("topic"), info_topic=query.get("info_topic"), index=int(index),
                         frame=query.get("frame"),
                         depth_scale=_floats(query["depth_scale"], 1, "depth_scale")[0] if "depth_scale" in query
                         else DEFAULT_DEPTH_SCALE)
    message = next(read_bag(data, bag_query))
    arrays: dict[str, Any] = {"points": message.points, "normals": message.normals}
    if message.shape is not None:  # an organised PointCloud2 or a depth image: the grid goes with the points
        arrays["shape"] = message.shape
        if message.pixel is not None:
            arrays["pixel"] = message.pixel
    if message.camera_pose is not None:
        arrays.update(camera_poses=[message.camera_pose.tolist()], depth=True)  # points in the camera's frame
    return arrays


def _query_params() -> dict[str, QueryParam]:
    """The upload query parameters: those of the file's cloud (viewpoint, camera_pose, points_frame, intrinsics,
    depth_scale), then every DetectRequest field that has a query form."""
    props = DetectRequest.model_json_schema()["properties"]
    out = {"viewpoint": QueryParam(
        "viewpoint", "vector", {"type": "string"}, "camera position 'x,y,z' (m) in the file's frame; may repeat; "
        "default: the PCD VIEWPOINT header or the NPZ viewpoints, else the origin", 3),
        "camera_pose": QueryParam(
        "camera_pose", "vector", {"type": "string"}, "camera-to-robot transform of a camera (cloud.camera_poses): "
        "'x,y,z,qx,qy,qz,qw' (m; quaternion x, y, z, w as ROS TF gives it) or 16 numbers (4x4, row-major); may "
        "repeat, one per camera; instead of viewpoint.  Needs points_frame, except for a depth image (always "
        "'camera').  Grasps then come back in the robot frame", 0),
        "points_frame": QueryParam(
        "points_frame", "text", {"type": "string", "enum": ["camera", "robot"]}, "with camera_pose: the frame of "
        "the file's points, 'camera' (the camera's, as a driver gives them) or 'robot'"),
        "intrinsics": QueryParam(
        "intrinsics", "vector", {"type": "string"}, "depth images (a 16-bit PNG, or an .npy of metres): the "
        "camera's pinhole intrinsics 'fx,fy,cx,cy' (pixels; ROS CameraInfo K), or its calibration YAML as ROS "
        "camera drivers write it (camera_calibration_parsers: image_width, image_height, camera_matrix, "
        "projection_matrix, ...; P's intrinsics are used, as depth_image_proc does)", 4),
        "depth_scale": QueryParam(
        "depth_scale", "text", {"type": "number", "exclusiveMinimum": 0}, "depth PNG or integer .npy: metres per "
        f"unit (default {DEFAULT_DEPTH_SCALE:g}: millimetres)"), **BAG_PARAMS}
    for name, info in DetectRequest.model_fields.items():
        param = _query_param(name, info, props[name])
        if param is not None:
            out[name] = param
    return {**out, **TARGET_PARAMS}


#: Query parameters of a raw PCD/PLY upload to POST /detect, generated from DetectRequest.
QUERY_PARAMS: dict[str, QueryParam] = _query_params()


def openapi_parameters() -> list[dict[str, Any]]:
    """The OpenAPI parameter objects of QUERY_PARAMS."""
    return [{"name": p.name, "in": "query", "required": False, "schema": p.schema, "description": p.description}
            for p in QUERY_PARAMS.values()]


def _floats(text: str, n: int, field: str) -> list[float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise Problem(422, f"{n} comma-separated numbers expected, got {text!r}", field) from None
    if len(values) != n or not np.isfinite(values).all():
        raise Problem(422, f"{n} comma-separated finite numbers expected, got {text!r}", field)
    return values


#: The query parameters that describe the file's cloud (the others are DetectRequest fields).
CLOUD_PARAMS = ("viewpoint", "camera_pose", "points_frame", "intrinsics", "depth_scale", *BAG_PARAMS)


def _camera_pose(text: str) -> list[list[float]]:
    """The 4x4 of a camera_pose parameter: 7 numbers (x, y, z, qx, qy, qz, qw) or 16 (a 4x4 row-major), checked
    (graspd.core.frames.pose_matrix); Problem naming camera_pose otherwise."""
    n = len([v for v in text.replace(" ", "").split(",") if v != ""])
    try:
        return pose_matrix(_floats(text, 16 if n == 16 else 7, "camera_pose"), "camera_pose").tolist()
    except CALLER_ERRORS as exc:
        raise from_wire(exc) from None


def _file_arrays(data: bytes, kind: str, query: Mapping[str, str]) -> dict[str, Any]:
    """The cloud arrays of an uploaded file (points, and what the file says of its cameras), as CloudError or
    Problem naming what is wrong."""
    if kind in ("pcd", "ply"):
        return file_arrays(read_pcd(data) if kind == "pcd" else read_ply(data))
    if kind == "bag":
        return _bag_arrays(data, query)
    if kind == "npz":
        arrays: dict[str, Any] = dict(parse_npz(data))
        if "camera_poses" in arrays:
            arrays["camera_poses"] = np.asarray(arrays["camera_poses"], np.float64).reshape(-1, 4, 4).tolist()
        return arrays
    if kind == "png" and "intrinsics" not in query:
        raise Problem(422, "a depth PNG needs the camera's intrinsics 'fx,fy,cx,cy' (pixels)", "intrinsics")
    intrinsics = _intrinsics(query["intrinsics"]) if "intrinsics" in query else None
    scale = _floats(query["depth_scale"], 1, "depth_scale")[0] if "depth_scale" in query else DEFAULT_DEPTH_SCALE
    return image_arrays(data, kind, intrinsics, scale)


def _intrinsics(text: str) -> list[float] | CameraCalibration:
    """The intrinsics parameter: 'fx,fy,cx,cy' (pixels), or the camera's calibration YAML as ROS drivers write
    it (graspd.io.calibration; its size must be the depth image's)."""
    if looks_like_calibration(text):
        return parse_calibration(text)
    return list(Intrinsics.parse(_floats(text, 4, "intrinsics")))


def check_camera_counts(viewpoints: list[str], camera_poses: list[str] | None) -> None:
    """At most MAX_VIEWPOINTS viewpoint and camera_pose parameters (one per camera): counted before the file is
    read or any array is built from them; Problem 422 naming the parameter otherwise."""
    for name, values in (("viewpoint", viewpoints), ("camera_pose", camera_poses or [])):
        if len(values) > MAX_VIEWPOINTS:
            raise Problem(422, f"at most {MAX_VIEWPOINTS} {name} parameters (one per camera), got {len(values)}",
                          name)


def upload_request(data: bytes, kind: str, query: Mapping[str, str], viewpoints: list[str],
                   camera_poses: list[str] | None = None) -> dict[str, Any]:
    """A DetectRequest-shaped dict from file bytes and query parameters (viewpoint and camera_pose may repeat).
    The cloud is validated by the request as a JSON one is: NaN rows dropped and counted, poses checked.  The
    camera counts are checked first (check_camera_counts), then the file is decoded under its caps."""
    check_camera_counts(viewpoints, camera_poses)
    unknown = sorted(set(query) - set(QUERY_PARAMS))
    try:
        arrays = _file_arrays(data, kind, query)
    except CloudError as exc:
        raise from_error(exc, ("cloud", "intrinsics", "depth_scale", *BAG_PARAMS)) from None
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise Problem(422, f"unreadable {kind.upper()} file ({type(exc).__name__}: {exc})", "body") from None
    points = np.asarray(arrays["points"])
    cloud: dict[str, Any] = {"points": points}
    for name in NPZ_ARRAYS[2:]:  # camera_source, normals, camera_poses, shape (an .npz may carry them)
        if arrays.get(name) is not None:
            cloud[name] = arrays[name]
    if arrays.get("pixel") is not None:  # a depth image's points are its pixels with depth
        cloud["pixels"] = arrays["pixel"]
    poses = camera_poses if camera_poses is not None else ([query["camera_pose"]] if "camera_pose" in query else [])
    if poses:
        cloud["camera_poses"] = [_camera_pose(p) for p in poses]
    if "points_frame" in query:
        if query["points_frame"] not in POINTS_FRAMES:
            raise Problem(422, f"one of {list(POINTS_FRAMES)} expected, got {query['points_frame']!r}", "points_frame")
        cloud["points_frame"] = query["points_frame"]
    elif arrays.get("depth") and "camera_poses" in cloud:
        cloud["points_frame"] = "camera"  # a depth image's points are in its camera's frame
    if viewpoints:
        cloud["viewpoints"] = [_floats(v, 3, "viewpoint") for v in viewpoints]
    elif arrays.get("viewpoints") is not None and "camera_poses" not in cloud:
        cloud["viewpoints"] = np.asarray(arrays["viewpoints"], np.float64).reshape(-1, 3).tolist()
    vps = cloud.get("viewpoints")
    if vps is not None and len(vps) > 1 and "camera_source" not in cloud and len(points) and points.ndim == 2:
        finite = np.where(np.isfinite(points).all(axis=1, keepdims=True), points, 0.0)  # NaN rows: dropped later
        cloud["camera_source"] = nearest_camera(finite, np.asarray(vps))
    body: dict[str, Any] = {"cloud": cloud}
    target = _target(query)
    if target is not None:
        body["target"] = target
    for name, param in QUERY_PARAMS.items():
        if name not in query or name in CLOUD_PARAMS or name in TARGET_PARAMS:
            continue
        text = query[name]
        if param.kind == "bool":
            if text.lower() not in ("true", "false", "1", "0"):
                raise Problem(422, f"true or false expected, got {text!r}", name)
            body[name] = text.lower() in ("true", "1")
        elif param.kind == "vector":
            body[name] = _floats(text, param.length, name)
        else:
            body[name] = text
    if unknown:
        raise Problem(422, f"unknown query parameter(s) {unknown}", unknown[0])
    return body
