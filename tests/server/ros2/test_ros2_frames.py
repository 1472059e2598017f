"""Frames on the ROS 2 node: with a camera pose configured (GRASPD_ROS2_OPTIONS: camera_poses, points_frame
"camera", camera_frame_id, robot_frame_id), table_mug sent in its camera's frame is answered in the robot frame
(base_link), on the mug there, every output naming base_link; a cloud from another frame is refused naming
header.frame_id; plan_grasps answers in the frame its target names (base_link, or the camera's frame)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from graspd.io.ros import Header, encode_pointcloud2

from .conftest import Collector, Decode, RosPeer, serve_ros2
from .test_ros2_node import GCL, STRING, collision_object, errors_of, mug_only, plan_request, send_cloud

ROT = Rotation.from_euler("xyz", [120, 10, -35], degrees=True)
T = np.array([0.6, -0.3, 0.8])
CAMERA = "camera_depth_optical_frame"


def pose() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = ROT.as_matrix(), T
    return m


@pytest.fixture(scope="module")
def ros2_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    options = {"camera_poses": [pose().tolist()], "points_frame": "camera", "camera_frame_id": CAMERA,
               "robot_frame_id": "base_link"}
    with serve_ros2(tmp_path_factory.mktemp("ros2-frames"), ros2_options=options) as served:
        yield served


@pytest.fixture(scope="module")
def outputs(peer: RosPeer) -> dict[str, Collector]:
    return {"gcl": peer.subscribe("/graspd/grasp_config_list", GCL),
            "json": peer.subscribe("/graspd/detections", STRING),
            "errors": peer.subscribe("/graspd/errors", STRING)}


def test_a_camera_frame_cloud_is_answered_in_the_robot_frame(peer: RosPeer, outputs: dict[str, Collector],
                                                             mug_points: np.ndarray, decode: Decode) -> None:
    writer = peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2")
    send_cloud(peer, writer, outputs, encode_pointcloud2(mug_points, Header(CAMERA, (3, 4))))
    gcl = decode(outputs["gcl"].got[0], GCL)
    answer = json.loads(decode(outputs["json"].got[0], STRING).data)
    assert gcl.header.frame_id == "base_link" and gcl.header.stamp.sec == 3 and answer["frame"] == "robot"
    robot = mug_points.astype(np.float64) @ ROT.as_matrix().T + T
    samples = np.array([[g.sample.x, g.sample.y, g.sample.z] for g in gcl.grasps])
    assert len(samples) and cKDTree(mug_only(robot, answer)).query(samples)[0].max() < 0.003
    # a cloud of another camera: its pose would be wrong
    send_cloud(peer, writer, outputs, encode_pointcloud2(mug_points, Header("other_camera", (3, 4))), "errors")
    error = errors_of(outputs["errors"], decode)[0]
    assert (error["status"], error["field"]) == (422, "header.frame_id")
    # plan_grasps: the same target in base_link or in the camera frame gives the same grasps, each in its frame
    send_cloud(peer, writer, outputs, encode_pointcloud2(mug_points, Header(CAMERA, (3, 4))))
    mug_robot = mug_only(robot, json.loads(decode(outputs["json"].got[0], STRING).data))
    lo, hi = mug_robot.min(axis=0), mug_robot.max(axis=0)
    client = peer.client("/graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning")
    client.wait_for_service()
    answers: dict[str, Any] = {}
    for frame in ("base_link", CAMERA):
        centre = (lo + hi) / 2 if frame == "base_link" else ROT.as_matrix().T @ ((lo + hi) / 2 - T)
        # an axis-aligned box in base_link, turned into the camera frame: the camera-frame box holds it
        size = hi - lo if frame == "base_link" else np.abs(ROT.as_matrix().T) @ (hi - lo)
        _, _, reply = client.call(plan_request(collision_object(frame, centre, size)))
        answers[frame] = decode(reply, "moveit_msgs/srv/GraspPlanning_Response")
        assert answers[frame].error_code.val == 1, answers[frame].error_code
        assert {g.grasp_pose.header.frame_id for g in answers[frame].grasps} == {frame}
    p_robot = np.array([[g.grasp_pose.pose.position.x, g.grasp_pose.pose.position.y, g.grasp_pose.pose.position.z]
                        for g in answers["base_link"].grasps])
    p_camera = np.array([[g.grasp_pose.pose.position.x, g.grasp_pose.pose.position.y, g.grasp_pose.pose.position.z]
                         for g in answers[CAMERA].grasps])
    assert cKDTree(mug_robot).query(p_robot)[0].max() < 0.1
    camera_mug = (mug_robot - T) @ ROT.as_matrix()
    assert cKDTree(camera_mug).query(p_camera)[0].max() < 0.1  # in camera coordinates, near the mug there
