"""ROS 2 launch: zenoh-bridge-ros2dds for graspd's topics, the camera cloud relayed to /graspd/cloud, and RViz
showing the grippers.  graspd itself runs outside ROS (graspd serve, or its container) with graspd.env.

  ros2 launch ./graspd_bridge.launch.py cloud:=/camera/depth/color/points
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

HERE = Path(__file__).resolve().parent


def generate_launch_description() -> LaunchDescription:
    cloud = LaunchConfiguration("cloud")
    return LaunchDescription([
        DeclareLaunchArgument("cloud", default_value="/camera/depth/color/points",
                              description="the sensor_msgs/PointCloud2 topic to find grasps in"),
        ExecuteProcess(cmd=["zenoh-bridge-ros2dds", "-c", str(HERE / "zenoh-bridge-ros2dds.json5")],
                       output="screen"),
        # the camera's cloud onto /graspd/cloud (topic_tools relay; a remap in the driver's launch does the same)
        Node(package="topic_tools", executable="relay", arguments=[cloud, "/graspd/cloud"], output="screen"),
        Node(package="rviz2", executable="rviz2", arguments=["-d", str(HERE / "graspd.rviz")], output="screen"),
    ])
