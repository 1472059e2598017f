"""The ROS 2 message types graspd speaks: one rosbags typestore (ROS 2 Humble definitions, wire-compatible
with Iron, Jazzy and Kilted) plus gpd_ros and moveit_msgs Grasp registered from the .msg text shipped in
graspd/ros/msg/."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib.resources import files
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
CLOUD_SOURCES = "gpd_ros/msg/CloudSources"
CLOUD_INDEXED = "gpd_ros/msg/CloudIndexed"
CLOUD_SAMPLES = "gpd_ros/msg/CloudSamples"
GRASP_CONFIG = "gpd_ros/msg/GraspConfig"
GRASP_CONFIG_LIST = "gpd_ros/msg/GraspConfigList"
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
MARKER = "visualization_msgs/msg/Marker"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
MOVEIT_GRASP = "moveit_msgs/msg/Grasp"

#: The .msg files registered on top of the ROS 2 Humble store, (package, message name), dependencies first.
SHIPPED_MESSAGES: tuple[tuple[str, str], ...] = (
    ("gpd_ros", "CloudSources"),
    ("gpd_ros", "CloudIndexed"),
    ("gpd_ros", "CloudSamples"),
    ("gpd_ros", "GraspConfig"),
    ("gpd_ros", "GraspConfigList"),
    ("moveit_msgs", "GripperTranslation"),
    ("moveit_msgs", "Grasp"),
)

_NUMPY_TYPES = {"bool": np.bool_, "int8": np.int8, "uint8": np.uint8, "byte": np.uint8, "char": np.uint8,
                "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
                "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


@dataclass(frozen=True)
class Header:
    """A std_msgs/Header: frame_id of the data, stamp (sec, nanosec) of acquisition, carried from input to output."""

    frame_id: str = ""
    stamp: tuple[int, int] = (0, 0)


def msg_text(package: str, name: str) -> str:
    """The shipped .msg text of package/msg/name (graspd/ros/msg/PACKAGE/NAME.msg)."""
    return files("graspd.io.ros").joinpath("msg", package, f"{name}.msg").read_text(encoding="utf-8")


@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """The ROS 2 Humble typestore with gpd_ros and moveit_msgs Grasp registered (built once)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for package, name in SHIPPED_MESSAGES:
        types.update(get_types_from_msg(msg_text(package, name), f"{package}/msg/{name}"))
    store.register(types)
    return store


def default_message(msgtype: str, **fields: Any) -> Any:
    """An instance of msgtype with every field not given set to its ROS default (zeros, empty strings and
    sequences, nested defaults)."""
    store = typestore()
    _, defs = store.fielddefs[msgtype]
    values: dict[str, Any] = {}
    for fname, desc in defs:
        values[fname] = fields.pop(fname) if fname in fields else _default_value(desc)
    if fields:
        raise TypeError(f"{msgtype} has no fields {sorted(fields)}")
    return store.types[msgtype](**values)


def _default_value(desc: Any) -> Any:
    kind, detail = desc
    if kind == Nodetype.BASE:
        base = detail[0]
        if base == "string":
            return ""
        if base == "bool":
            return False
        return 0.0 if base.startswith("float") else 0
    if kind == Nodetype.NAME:
        return default_message(detail)
    (sub_kind, sub_detail), length = detail
    if sub_kind == Nodetype.BASE and sub_detail[0] in _NUMPY_TYPES:
        return np.zeros(length if kind == Nodetype.ARRAY else 0, _NUMPY_TYPES[sub_detail[0]])
    if kind == Nodetype.ARRAY:
        return [_default_value((sub_kind, sub_detail)) for _ in range(length)]
    return []


def header_message(header: Header) -> Any:
    """A std_msgs/msg/Header instance for header."""
    t = typestore().types
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=int(header.stamp[0]),
                                                                            nanosec=int(header.stamp[1])),
                                    frame_id=header.frame_id)
