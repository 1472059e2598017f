"""Start graspd's native ROS 2 node: `ros2 launch gpd_ros graspd.launch.py [domain_id:=N] [port:=8000]`.

graspd is not a ROS executable: this runs `graspd serve --ros2` (pip install 'graspd[ros2]' into the Python that
`graspd` resolves to).  The node joins ROS_DOMAIN_ID (or domain_id) as /graspd; its HTTP API stays on 127.0.0.1.
Every GRASPD_* variable of the environment reaches it (GRASPD_ROS2_OPTIONS for camera poses and frames,
GRASPD_ROS2_SECURITY_ENCLAVE for DDS Security, GRASPD_ROS2_TOPICS for names, GRASPD_DEFAULT_MODEL)."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import EnvironmentVariable, LaunchConfiguration


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("domain_id", default_value=EnvironmentVariable("ROS_DOMAIN_ID", default_value="0"),
                              description="DDS domain of the node"),
        DeclareLaunchArgument("port", default_value="8000", description="HTTP port of the same server"),
        ExecuteProcess(cmd=["graspd", "serve", "--ros2", "--ros2-domain-id", LaunchConfiguration("domain_id"),
                            "--port", LaunchConfiguration("port")], output="screen", name="graspd"),
    ])
