"""The error of a ROS 2 node that cannot start, importable without cyclonedds."""


class Ros2SetupError(RuntimeError):
    """The ROS 2 node cannot start as configured (names the setting); the server refuses to start."""
