"""The ROS 2 interfaces graspd speaks natively over DDS, as a ROS 2 node built with rmw_cyclonedds sees them.

One rosbags typestore per ROS distribution (the wire differs in two places: rmw_dds_common/Gid is 24 bytes in
Humble, 16 from Iron on; moveit_msgs/MoveItErrorCodes gained `message` and `source` in Jazzy) with gpd_ros,
moveit_msgs Grasp / CollisionObject / GraspPlanning, object_recognition_msgs/ObjectType and vision_msgs'
Detection3DArray (vision_msgs 4.1, as Humble to Kilted ship it: not in rosbags' stores) registered from the field
lists shipped beside this module (interfaces/) and graspd/ros/msg/.  Service parts are registered as
"pkg/srv/Name_Request" and "pkg/srv/Name_Response".

The DDS side: ROS names -> DDS names (type "pkg::msg::dds_::Name_", topic "rt/<name>", service topics
"rq/<name>Request" and "rr/<name>Reply"), and cyclonedds IdlStruct classes generated from the same field lists
(they give each DDS topic its type name and XTypes type information; the samples themselves travel as CDR bytes,
encoded and decoded by graspd.io.ros and rosbags).  A service sample is the rmw_cyclonedds request header (client
guid u64, sequence number i64) followed by the request or response fields; the generated classes say so.
"""

from __future__ import annotations

from functools import cache
from importlib.resources import files
from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct, types
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from graspd.io.ros.types import SHIPPED_MESSAGES, msg_text

#: The ROS 2 distributions the wire layouts are known for; "iron" and later share rmw_dds_common's 16-byte Gid,
#: "jazzy" and later moveit_msgs' MoveItErrorCodes with message and source.
DISTROS: dict[str, Stores] = {"humble": Stores.ROS2_HUMBLE, "iron": Stores.ROS2_IRON, "jazzy": Stores.ROS2_JAZZY,
                              "kilted": Stores.ROS2_KILTED, "rolling": Stores.ROS2_KILTED}
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
STRING = "std_msgs/msg/String"
PARTICIPANT_ENTITIES_INFO = "rmw_dds_common/msg/ParticipantEntitiesInfo"
DETECT_GRASPS = "gpd_ros/srv/DetectGrasps"
GRASP_PLANNING = "moveit_msgs/srv/GraspPlanning"
DETECTION3D_ARRAY = "vision_msgs/msg/Detection3DArray"
#: Field lists shipped beside this module: (package, kind, name), dependencies first.
EXTRA_MESSAGES: tuple[tuple[str, str], ...] = (("object_recognition_msgs", "ObjectType"),
                                               ("moveit_msgs", "CollisionObject"),
                                               ("moveit_msgs", "MoveItErrorCodes"),
                                               ("vision_msgs", "ObjectHypothesis"),
                                               ("vision_msgs", "ObjectHypothesisWithPose"),
                                               ("vision_msgs", "BoundingBox3D"),
                                               ("vision_msgs", "Detection3D"),
                                               ("vision_msgs", "Detection3DArray"))
SERVICES: tuple[str, ...] = (DETECT_GRASPS, GRASP_PLANNING)
#: The request header rmw_cyclonedds puts before the fields of every request and reply sample (serdata.hpp
#: cdds_request_header_t): the client's request-writer instance handle and the request's sequence number.
REQUEST_HEADER_FIELDS: dict[str, Any] = {"client_guid": types.uint64, "sequence_number": types.int64}

_BASE: dict[str, Any] = {"bool": bool, "byte": types.byte, "char": types.uint8, "int8": types.int8,
                         "uint8": types.uint8, "int16": types.int16, "uint16": types.uint16, "int32": types.int32,
                         "uint32": types.uint32, "int64": types.int64, "uint64": types.uint64,
                         "float32": types.float32, "float64": types.float64}


def interface_text(package: str, name: str, kind: str = "msg", distro: str = "jazzy") -> str:
    """The shipped field list of package/kind/name (.msg or .srv text); MoveItErrorCodes as of distro."""
    if package in ("gpd_ros", "moveit_msgs") and kind == "msg" and (package, name) in SHIPPED_MESSAGES:
        return msg_text(package, name)
    stem = f"{name}.humble" if (package, name) == ("moveit_msgs", "MoveItErrorCodes") and distro in (
        "humble", "iron") else name
    return files("graspd.server.ros2").joinpath("interfaces", package, f"{stem}.{kind}").read_text(encoding="utf-8")


def _msg_defs(text: str, name: str) -> Any:
    """rosbags field definitions of one message text registered under name (any "pkg/kind/Name")."""
    package = name.split("/", 1)[0]
    parsed = get_types_from_msg(text, f"{package}/msg/_Graspd")
    return parsed[f"{package}/msg/_Graspd"]


@cache
def ros_types(distro: str = "jazzy") -> Typestore:
    """The typestore of distro (a DISTROS key) with every interface graspd speaks registered (built once)."""
    if distro not in DISTROS:
        raise ValueError(f"unknown ROS 2 distribution {distro!r}; known: {sorted(DISTROS)}")
    store = get_typestore(DISTROS[distro])
    registered: dict[str, Any] = {}
    for package, name in (*SHIPPED_MESSAGES, *EXTRA_MESSAGES):
        registered.update(get_types_from_msg(interface_text(package, name, distro=distro), f"{package}/msg/{name}"))
    store.register(registered)
    parts: dict[str, Any] = {}
    for service in SERVICES:
        package, _, name = service.split("/")
        request, _, response = interface_text(package, name, "srv", distro).partition("\n---")
        parts[f"{service}_Request"] = _msg_defs(request, service)
        parts[f"{service}_Response"] = _msg_defs(response, service)
    store.register(parts)
    return store


def dds_type_name(ros_type: str) -> str:
    """The DDS type name of a ROS type: "sensor_msgs/msg/PointCloud2" -> "sensor_msgs::msg::dds_::PointCloud2_",
    "gpd_ros/srv/DetectGrasps_Request" -> "gpd_ros::srv::dds_::DetectGrasps_Request_" (rmw_cyclonedds)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_name(ros_name: str) -> str:
    """The DDS topic of a fully qualified ROS topic: "/graspd/cloud" -> "rt/graspd/cloud"."""
    return "rt" + ros_name


def service_topics(ros_name: str) -> tuple[str, str]:
    """The DDS topics of a fully qualified ROS service (requests, replies):
    "/graspd/detect_grasps" -> ("rq/graspd/detect_graspsRequest", "rr/graspd/detect_graspsReply")."""
    return f"rq{ros_name}Request", f"rr{ros_name}Reply"


def _idl_field(store: Typestore, desc: Any, distro: str) -> Any:
    kind, detail = desc
    if kind == Nodetype.BASE:
        base, bound = detail
        if base == "string":
            return types.bounded_str[bound] if bound else str  # type: ignore[misc]
        return _BASE[base]
    if kind == Nodetype.NAME:
        return idl_type(detail, distro)
    sub, length = detail
    if kind == Nodetype.ARRAY:
        return types.array[_idl_field(store, sub, distro), length]  # type: ignore[misc]
    item = _idl_field(store, sub, distro)
    return types.sequence[item, length] if length else types.sequence[item]  # type: ignore[misc]


@cache
def idl_type(ros_type: str, distro: str = "jazzy") -> type[IdlStruct]:
    """A cyclonedds IdlStruct with the DDS type name and fields of ros_type (a name of ros_types(distro)); for a
    service part ("pkg/srv/Name_Request" or "_Response") the rmw_cyclonedds request header comes first."""
    store = ros_types(distro)
    _, fields = store.fielddefs[ros_type]
    members: dict[str, Any] = dict(REQUEST_HEADER_FIELDS) if "/srv/" in ros_type else {}
    for name, desc in fields:
        members[name] = _idl_field(store, desc, distro)
    if not members:  # an empty ROS message is a struct with one uint8 on the wire
        members["structure_needs_at_least_one_member"] = types.uint8
    class_name = ros_type.replace("/", "__")
    return make_idl_struct(class_name, dds_type_name(ros_type), members)
