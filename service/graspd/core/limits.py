"""The limits every entrance enforces alike (HTTP JSON and uploads, Zenoh, ROS CDR, files, the CLI): one table.
The robot-side client keeps its own copy for checks before sending (graspd_client.wire); a test holds the two
equal."""

from __future__ import annotations

#: Most points in one cloud (and pixels in one depth image: a point per pixel).
MAX_POINTS = 5_000_000
#: Most points sampled for grasp candidates in one request.
MAX_NUM_SAMPLES = 20_000
#: Most grasps returned by one request.
MAX_GRASPS = 1_000
#: Most camera positions (viewpoints or camera poses) of one JSON request.
MAX_VIEWPOINTS = 64
#: Largest |coordinate| of a point or translation (m): nothing a robot sees is farther; more is a unit mistake.
MAX_COORDINATE = 1e4
#: Most solid primitives, meshes, and mesh vertices and triangles (all meshes together) of one grasp-planning
#: target (moveit_msgs/CollisionObject): a graspable object is a handful of shapes; more is refused from the
#: message's sequence lengths, before any of it is read.
MAX_TARGET_PRIMITIVES = 256
MAX_TARGET_MESHES = 64
MAX_TARGET_VERTICES = 1_000_000
MAX_TARGET_TRIANGLES = 2_000_000
