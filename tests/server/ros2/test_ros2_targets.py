"""Targets over the ROS 2 node, on the rendered table of six objects: a detect_grasps CloudIndexed and a
plan_grasps CollisionObject give the grasps HTTP gives for the same indices and the same box (same seed, the same
server); the scene's objects go out on /graspd/objects as vision_msgs/Detection3DArray with the answer's ids,
centres and extents; a target that selects nothing is refused naming the ROS field, on /graspd/errors and in the
reply."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.core.grasp import rotation_to_quat_xyzw
from graspd.io.ros import Header, encode_cloud_indexed, encode_pointcloud2
from graspd.io.ros.encode import encode_grasp_planning
from graspd.server.problems import Problem
from graspd.server.ros2 import moveit
from graspd.server.services.ros_stream import parse_options, ros_problem
from graspd_client.wire import build_detect_request
from target_scene import CAMERA, OrganisedScene, render_table

from .conftest import NUM_SAMPLES, Collector, Decode, RosPeer, ServiceClient, serve_ros2

FRAME = "table"
HEADER = Header(FRAME, (7, 8))
GCL, STRING, OBJECTS = "gpd_ros/msg/GraspConfigList", "std_msgs/msg/String", "vision_msgs/msg/Detection3DArray"
PLAN_RESPONSE = "moveit_msgs/srv/GraspPlanning_Response"
#: The object the targets name (1-based, as in OrganisedScene.ids): the tall box in the middle of the back row.
K = 5


@pytest.fixture(scope="module")
def six() -> OrganisedScene:
    return render_table()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    """The node seeing PointCloud2 clouds from the rendered table's camera."""
    with serve_ros2(tmp_path_factory.mktemp("ros2-targets"), stream_viewpoint=CAMERA) as served:
        yield served


@pytest.fixture(scope="module")
def peer(server: tuple[TestClient, int]) -> Iterator[RosPeer]:
    p = RosPeer(server[1])
    yield p
    p.close()


@pytest.fixture(scope="module")
def sinks(peer: RosPeer) -> dict[str, Collector]:
    return {"json": peer.subscribe("/graspd/detections", STRING), "objects": peer.subscribe("/graspd/objects", OBJECTS),
            "errors": peer.subscribe("/graspd/errors", STRING)}


def http(server: tuple[TestClient, int], scene: OrganisedScene, **options: Any) -> dict[str, Any]:
    """The /detect answer of the same server for the scene's cloud with the node's options."""
    body = build_detect_request(scene.cloud.points, scene.cloud.viewpoints, num_samples=NUM_SAMPLES, max_grasps=6,
                                **options)
    r = server[0].post("/detect", json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


def errors_of(sink: Collector, decode: Decode) -> list[dict[str, Any]]:
    with sink.cond:
        return [json.loads(decode(d, STRING).data) for d in sink.got]


def test_cloud_indexed_is_the_indices_target(server: tuple[TestClient, int], peer: RosPeer,
                                             sinks: dict[str, Collector], six: OrganisedScene,
                                             decode: Decode) -> None:
    client: ServiceClient = peer.client("/graspd/detect_grasps", "gpd_ros/srv/DetectGrasps")
    client.wait_for_service()
    rows = six.rows(K)
    sinks["objects"].clear()
    request = encode_cloud_indexed(six.cloud.points, six.cloud.viewpoints, rows, header=HEADER)
    gcl = decode(client.call(request)[2], GCL)
    expected = http(server, six, target={"indices": rows})
    assert len(expected["grasps"]) >= 3 and {g["object"] for g in expected["grasps"]} == {
        expected["grasps"][0]["object"]}  # every grasp on the one object
    got = np.array([[g.position.x, g.position.y, g.position.z] for g in gcl.grasps])
    assert got.shape == (len(expected["grasps"]), 3)
    assert np.allclose(got, [g["position"] for g in expected["grasps"]], atol=1e-6)
    # the call's objects on /graspd/objects, in its frame
    assert sinks["objects"].wait()
    array = decode(sinks["objects"].got[-1], OBJECTS)
    assert array.header.frame_id == FRAME and (array.header.stamp.sec, array.header.stamp.nanosec) == HEADER.stamp
    assert [d.id for d in array.detections] == [str(o["id"]) for o in expected["objects"]]
    # indices naming only rows without a point: a 422 naming indices, on /graspd/errors and an empty reply
    sinks["errors"].clear()
    nan_rows = np.flatnonzero(~np.isfinite(six.cloud.points).all(axis=1))[:5]
    bad = encode_cloud_indexed(six.cloud.points, six.cloud.viewpoints, nan_rows, header=HEADER)
    assert len(decode(client.call(bad)[2], GCL).grasps) == 0
    assert sinks["errors"].wait()
    error = errors_of(sinks["errors"], decode)[0]
    assert (error["status"], error["field"], error["topic"]) == (422, "indices", "/graspd/detect_grasps"), error


def test_objects_are_published_as_detection3d_array(server: tuple[TestClient, int], peer: RosPeer,
                                                    sinks: dict[str, Collector], six: OrganisedScene,
                                                    decode: Decode) -> None:
    for sink in sinks.values():
        sink.clear()
    peer.publish_until(peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2"),
                       encode_pointcloud2(six.cloud.points, HEADER), [sinks["json"]])
    answer = json.loads(decode(sinks["json"].got[0], STRING).data)
    assert sinks["objects"].wait()
    array = decode(sinks["objects"].got[0], OBJECTS)
    assert array.header.frame_id == FRAME and len(answer["objects"]) == 6
    assert len(array.detections) == len(answer["objects"])
    for det, obj in zip(array.detections, answer["objects"], strict=True):
        assert det.id == str(obj["id"]) and det.header.frame_id == FRAME
        c, s = det.bbox.center.position, det.bbox.size
        assert np.allclose([c.x, c.y, c.z], obj["centre"]) and np.allclose([s.x, s.y, s.z], obj["extent"])
        (result,) = det.results
        assert result.hypothesis.class_id == "object" and result.pose.pose.position.z == c.z
    assert answer["objects"] == http(server, six)["objects"]  # the same segmentation as over HTTP


def collision_object_request(scene: OrganisedScene, k: int, target_id: str = "box5", **shape: Any) -> bytes:
    """A GraspPlanning request whose target is object k's box: posed at its centre with its rotation, one BOX of
    its size at the target's origin (unless shape overrides encode_grasp_planning's shapes)."""
    centre, rotation, half = scene.boxes[k - 1]
    pose = np.concatenate([centre, rotation_to_quat_xyzw(rotation[None])[0]])
    shapes = shape or {"box_centres": [[0.0, 0.0, 0.0]], "box_sizes": [2 * half]}
    return encode_grasp_planning(HEADER, pose, target_id=target_id, **shapes)


def test_grasp_planning_is_the_box_target(server: tuple[TestClient, int], peer: RosPeer,
                                          sinks: dict[str, Collector], six: OrganisedScene, decode: Decode) -> None:
    peer.publish_until(peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2"),
                       encode_pointcloud2(six.cloud.points, HEADER), [sinks["json"]])
    planner = peer.client("/graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning")
    planner.wait_for_service()
    response = decode(planner.call(collision_object_request(six, K))[2], PLAN_RESPONSE)
    assert response.error_code.val == moveit.SUCCESS, response.error_code
    centre, rotation, half = six.boxes[K - 1]
    box = {"centre": centre, "rotation": rotation, "half_extents": half + moveit.TARGET_MARGIN_M}
    expected = http(server, six, target={"box": box})
    assert len(expected["grasps"]) >= 3 and len({g["object"] for g in expected["grasps"]}) == 1
    got = np.array([[g.grasp_pose.pose.position.x, g.grasp_pose.pose.position.y, g.grasp_pose.pose.position.z]
                    for g in response.grasps])
    assert got.shape == (len(expected["grasps"]), 3)
    assert np.allclose(got, [g["position"] for g in expected["grasps"]], atol=1e-6)
    assert [g.id for g in response.grasps] == [f"box5/{i}" for i in range(len(got))]  # keyed by target.id
    assert all(g.grasp_pose.header.frame_id == FRAME for g in response.grasps)


def test_a_grasp_planning_target_that_selects_nothing_is_refused(peer: RosPeer, sinks: dict[str, Collector],
                                                                 six: OrganisedScene, decode: Decode) -> None:
    planner = peer.client("/graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning")
    planner.wait_for_service()
    sinks["errors"].clear()
    far = encode_grasp_planning(HEADER, box_centres=[[2.0, 2.0, 2.0]], box_sizes=[[0.05, 0.05, 0.05]])
    response = decode(planner.call(far)[2], PLAN_RESPONSE)
    assert response.error_code.val == moveit.PLANNING_FAILED and not response.grasps
    assert "422" in response.error_code.message and "target" in response.error_code.message
    assert sinks["errors"].wait()
    error = errors_of(sinks["errors"], decode)[0]
    assert (error["status"], error["field"], error["topic"]) == (422, "target", "/graspd/plan_grasps"), error
    bare = encode_grasp_planning(HEADER, target_id="mug")  # an id, no geometry: graspd has no planning scene
    response = decode(planner.call(bare)[2], PLAN_RESPONSE)
    assert response.error_code.val == moveit.INVALID_OBJECT_NAME and "'mug'" in response.error_code.message


def test_a_target_is_not_a_stream_option_and_target_errors_name_the_ros_field() -> None:
    with pytest.raises(Problem) as err:
        parse_options({"target": {"object": 0}}, {}, ((0.0, 0.0, 0.0),))
    assert (err.value.status, err.value.field) == (422, "target") and "CloudIndexed" in err.value.message
    named = ros_problem(Problem(422, "selects nothing", "target.points"))
    assert (named.status, named.field, named.message) == (422, "samples", "selects nothing")
    assert ros_problem(Problem(422, "x", "num_samples")).field == "num_samples"
