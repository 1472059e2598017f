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
#: Most rows one target names (target.indices; a mask has one pixel per cloud row, so MAX_POINTS bounds it too),
#: sample points one target gives (target.points) and characters of a compressed COCO RLE mask (its counts
#: string): checked from the lengths sent, before any array is built.
MAX_TARGET_INDICES = MAX_POINTS
MAX_TARGET_POINTS = MAX_NUM_SAMPLES
MAX_TARGET_RLE_CHARS = 1 << 22
#: Largest object id a target may name (ids count the scene's objects from 0).
MAX_OBJECT_ID = 100_000
#: Most grasps per object before every other graspable object has one (max_per_object; 0 = off).
MAX_PER_OBJECT = MAX_GRASPS
#: Most moved copies of each of the first grasps that the ranking scores (robust_copies; graspd.gpd.robustness).
MAX_ROBUST_COPIES = 16
#: The default of robust_copies: the detector's (graspd.gpd.robustness.ROBUST_COPIES; a test keeps them equal).
DEFAULT_ROBUST_COPIES = 0
