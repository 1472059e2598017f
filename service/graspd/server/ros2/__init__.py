"""ROS 2 natively: `graspd serve --ros2` joins a DDS domain as the ROS 2 node /graspd (cyclonedds, the extra
graspd[ros2]; no ROS install, no bridge).  Topics and services carry ROS 2's names and DDS type names, with the
QoS ROS 2 users expect, and every request goes through the server's one detection engine.

names: topic and service names; interfaces: ROS types (rosbags) and DDS types (cyclonedds); wire: the
rmw_cyclonedds service framing and ros_discovery_info; dds: participant, QoS, security, raw readers and writers;
moveit: finger postures and GraspPlanning; node: the node.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .node import Ros2Node


def make_node(settings: Any, engine: Any, metrics: Any) -> Ros2Node:
    """A started Ros2Node for the server (graspd.server.app); Ros2SetupError when the extra graspd[ros2] is not
    installed or DDS refuses the configuration."""
    try:
        import cyclonedds  # noqa: F401, PLC0415 - the optional extra
    except ImportError:
        from .errors import Ros2SetupError  # noqa: PLC0415

        raise Ros2SetupError("graspd serve --ros2 needs the extra graspd[ros2] (pip install 'graspd[ros2]': "
                             "cyclonedds)") from None
    from .node import Ros2Node  # noqa: PLC0415

    node = Ros2Node(settings, engine, metrics)
    node.start()
    return node
