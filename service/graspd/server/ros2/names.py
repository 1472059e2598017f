"""ROS 2 names of the node's topics and services: the defaults, the settings' overrides, and fully qualified
names (a relative name goes under the node's namespace, as rclcpp resolves it; "" turns an entry off).

Inputs (sensor-data QoS): pointcloud2 sensor_msgs/PointCloud2 on graspd/cloud, cloud_sources / cloud_indexed /
cloud_samples the gpd_ros messages.  Outputs (reliable): grasp_config_list gpd_ros/GraspConfigList, pose_array
geometry_msgs/PoseArray, moveit_grasps one moveit_msgs/Grasp per grasp (best first), marker_array
visualization_msgs/MarkerArray, objects vision_msgs/Detection3DArray (the scene's objects, ids as the answer's),
json std_msgs/String (the /detect answer: timings, warnings, frame), errors std_msgs/String (a JSON error body
naming the field).  Services: detect_grasps gpd_ros/srv/DetectGrasps,
plan_grasps moveit_msgs/srv/GraspPlanning.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

#: Input name -> (default topic, ROS type).
INPUTS: dict[str, tuple[str, str]] = {
    "pointcloud2": ("graspd/cloud", "sensor_msgs/msg/PointCloud2"),
    "cloud_sources": ("graspd/cloud_sources", "gpd_ros/msg/CloudSources"),
    "cloud_indexed": ("graspd/cloud_indexed", "gpd_ros/msg/CloudIndexed"),
    "cloud_samples": ("graspd/cloud_samples", "gpd_ros/msg/CloudSamples"),
}
#: Output name -> (default topic, ROS type), in publication order for each cloud.
OUTPUTS: dict[str, tuple[str, str]] = {
    "grasp_config_list": ("graspd/grasp_config_list", "gpd_ros/msg/GraspConfigList"),
    "pose_array": ("graspd/grasp_poses", "geometry_msgs/msg/PoseArray"),
    "moveit_grasps": ("graspd/moveit_grasps", "moveit_msgs/msg/Grasp"),
    "marker_array": ("graspd/grasp_markers", "visualization_msgs/msg/MarkerArray"),
    "objects": ("graspd/objects", "vision_msgs/msg/Detection3DArray"),
    "json": ("graspd/detections", "std_msgs/msg/String"),
    "errors": ("graspd/errors", "std_msgs/msg/String"),
}
#: Service name -> (default name, ROS service type).
SERVICES: dict[str, tuple[str, str]] = {
    "detect_grasps": ("graspd/detect_grasps", "gpd_ros/srv/DetectGrasps"),
    "plan_grasps": ("graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning"),
}
DEFAULTS: dict[str, str] = {k: v[0] for k, v in {**INPUTS, **OUTPUTS, **SERVICES}.items()}
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_NAME = re.compile(rf"^/?{_TOKEN}(/{_TOKEN})*$")


def qualify(name: str, namespace: str) -> str:
    """A fully qualified ROS name: absolute names as given, relative ones under namespace ("/" or "/robot")."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


def resolve_names(given: Mapping[str, str], namespace: str) -> dict[str, str]:
    """Fully qualified names by entry: DEFAULTS overridden by given ("" drops one); ValueError naming
    GRASPD_ROS2_TOPICS for an unknown entry or a name ROS 2 would refuse."""
    unknown = sorted(set(given) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"GRASPD_ROS2_TOPICS: unknown names {unknown}; known: {sorted(DEFAULTS)}")
    out: dict[str, str] = {}
    for entry, name in {**DEFAULTS, **given}.items():
        if not name:
            continue
        if not _NAME.fullmatch(name) or "__" in name:
            raise ValueError(f"GRASPD_ROS2_TOPICS.{entry}: {name!r} is not a ROS 2 topic name (tokens of letters, "
                             "digits and _ separated by /, no __)")
        out[entry] = qualify(name, namespace)
    return out
