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
