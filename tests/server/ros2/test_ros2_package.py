"""The colcon package in ros2/ (we cannot build it here: no ROS): its msg and srv files are the ones the node
puts on the wire (the field lists of the node's typestore, and so of the DDS types it declares), its
CMakeLists generates every one of them, package.xml names the package the type names use, and the launch file
starts `graspd serve --ros2`."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import get_types_from_msg
from rosbags.typesys.base import Nodetype

from graspd.server.ros2.interfaces import dds_type_name, idl_type, ros_types

PACKAGE = Path(__file__).resolve().parents[3] / "ros2"
SHARED = Path(__file__).resolve().parents[4] / "shared" / "ros" / "gpd_ros"


def fields(text: str, name: str) -> list[tuple[str, object]]:
    return list(get_types_from_msg(text, name)[name][1])


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_the_package_messages_and_service_are_the_types_on_the_wire(distro: str) -> None:
    store = ros_types(distro)
    msgs = sorted(PACKAGE.glob("msg/*.msg"))
    assert {m.stem for m in msgs} == {"GraspConfig", "GraspConfigList", "CloudSources", "CloudIndexed",
                                      "CloudSamples"}
    for msg in msgs:
        name = f"gpd_ros/msg/{msg.stem}"
        assert fields(msg.read_text(), name) == list(store.fielddefs[name][1]), msg.name
        assert msg.read_text() == (SHARED / "msg" / msg.name).read_text()  # copied unchanged
        assert idl_type(name, distro).__idl_typename__ == dds_type_name(name)
    request, _, response = (PACKAGE / "srv" / "DetectGrasps.srv").read_text().partition("\n---")
    assert fields(request, "gpd_ros/msg/Req") == list(store.fielddefs["gpd_ros/srv/DetectGrasps_Request"][1])
    assert fields(response, "gpd_ros/msg/Res") == list(store.fielddefs["gpd_ros/srv/DetectGrasps_Response"][1])
    assert idl_type("gpd_ros/srv/DetectGrasps_Request", distro).__idl_typename__ == \
        "gpd_ros::srv::dds_::DetectGrasps_Request_"


def test_cmake_generates_every_interface_and_the_package_is_gpd_ros() -> None:
    cmake = (PACKAGE / "CMakeLists.txt").read_text()
    listed = set(re.findall(r'"((?:msg|srv)/\w+\.(?:msg|srv))"', cmake))
    assert listed == {str(p.relative_to(PACKAGE)) for p in [*PACKAGE.glob("msg/*.msg"), *PACKAGE.glob("srv/*.srv")]}
    assert "rosidl_generate_interfaces(${PROJECT_NAME}" in cmake and "project(gpd_ros)" in cmake
    root = ET.parse(PACKAGE / "package.xml").getroot()
    assert root.findtext("name") == "gpd_ros"
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    deps = {e.text for e in root if e.tag in ("depend", "buildtool_depend")}
    assert {"rosidl_default_generators", "std_msgs", "geometry_msgs", "sensor_msgs"} <= deps


def test_the_launch_file_starts_graspd_serve_ros2() -> None:
    text = (PACKAGE / "launch" / "graspd.launch.py").read_text()
    assert '"graspd", "serve", "--ros2"' in text and "def generate_launch_description" in text
    compile(text, "graspd.launch.py", "exec")


#: vision_msgs 4.1 (ROS 2 Humble to Kilted; Jazzy's): the fields of the messages of graspd/objects, in order.
VISION_MSGS = {
    "Detection3DArray": [("header", "std_msgs/msg/Header"), ("detections", "vision_msgs/msg/Detection3D[]")],
    "Detection3D": [("header", "std_msgs/msg/Header"), ("results", "vision_msgs/msg/ObjectHypothesisWithPose[]"),
                    ("bbox", "vision_msgs/msg/BoundingBox3D"), ("id", "string")],
    "ObjectHypothesisWithPose": [("hypothesis", "vision_msgs/msg/ObjectHypothesis"),
                                 ("pose", "geometry_msgs/msg/PoseWithCovariance")],
    "ObjectHypothesis": [("class_id", "string"), ("score", "float64")],
    "BoundingBox3D": [("center", "geometry_msgs/msg/Pose"), ("size", "geometry_msgs/msg/Vector3")],
}


def _type_of(desc: Any) -> str:
    kind, detail = desc
    if kind == Nodetype.BASE:
        return str(detail[0])
    if kind == Nodetype.NAME:
        return str(detail)
    return _type_of(detail[0]) + "[]"


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_the_objects_topic_speaks_vision_msgs_as_jazzy_defines_it(distro: str) -> None:
    store = ros_types(distro)
    for name, expected in VISION_MSGS.items():
        got = [(f, _type_of(d)) for f, d in store.fielddefs[f"vision_msgs/msg/{name}"][1]]
        assert got == expected, name
    assert idl_type("vision_msgs/msg/Detection3DArray", distro).__idl_typename__ == \
        "vision_msgs::msg::dds_::Detection3DArray_"
    root = ET.parse(PACKAGE / "package.xml").getroot()
    assert "vision_msgs" in {e.text for e in root if e.tag == "exec_depend"}  # the type comes with ROS
