"""ROS 2 messages over Zenoh (zenoh-bridge-ros2dds): CDR decoding of clouds and encoding of grasps, no ROS
install needed.  types: the rosbags typestore with gpd_ros and moveit_msgs Grasp; decode: inputs; encode: outputs
(and fast input builders).  Frames: everything in the input cloud's header.frame_id, metres."""

from graspd.io.ros.decode import (
    CloudMessage,
    RosDecodeError,
    decode_cloud_indexed,
    decode_cloud_message,
    decode_cloud_samples,
    decode_cloud_sources,
    decode_pointcloud2,
)
from graspd.io.ros.encode import (
    encode_cloud_indexed,
    encode_cloud_samples,
    encode_cloud_sources,
    encode_grasp_config_list,
    encode_marker_array,
    encode_moveit_grasps,
    encode_pointcloud2,
    encode_pose_array,
)
from graspd.io.ros.types import Header, typestore

__all__ = [
    "CloudMessage",
    "Header",
    "RosDecodeError",
    "decode_cloud_indexed",
    "decode_cloud_message",
    "decode_cloud_samples",
    "decode_cloud_sources",
    "decode_pointcloud2",
    "encode_cloud_indexed",
    "encode_cloud_samples",
    "encode_cloud_sources",
    "encode_grasp_config_list",
    "encode_marker_array",
    "encode_moveit_grasps",
    "encode_pointcloud2",
    "encode_pose_array",
    "typestore",
]
