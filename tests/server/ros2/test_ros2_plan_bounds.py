"""plan_grasps bounded like HTTP: a GraspPlanning target is read from its sequence lengths first (60k primitives or
1.7M vertices are refused by count, in milliseconds, without building anything), a mesh within the limits is
read as its vertex bounds on a view of the message, the target is one box (one shape's, or the union of its
shapes in the object's frame) built vectorised, a stale cloud is answered before the target is read, the message
counts against the memory budget, and service calls hold at most all but one detect worker.  The hostile payloads
are built by graspd.io.ros.encode.encode_grasp_planning (hostile_primitives, hostile_meshes below), as
bench/hostile.py can."""

from __future__ import annotations

import json
import time
import tracemalloc
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.core.limits import MAX_TARGET_PRIMITIVES, MAX_TARGET_VERTICES
from graspd.io.ros import Header, RosDecodeError, encode_pointcloud2
from graspd.io.ros.encode import encode_grasp_planning
from graspd.io.ros.planning import decode_plan_target
from graspd.server.ros2 import moveit
from graspd.server.ros2.admission import ServiceShare, service_share
from graspd.server.ros2.interfaces import ros_types
from graspd.server.services.budget import MemoryBudget, message_cost

from .conftest import Collector, Decode, RosPeer, ServiceClient, serve_ros2
from .peer import hostile_meshes, hostile_primitives

FRAME = "camera_depth_optical_frame"
HEADER = Header(FRAME, (5, 6))
RESPONSE = "moveit_msgs/srv/GraspPlanning_Response"


# ------------------------------------------------------------------------------------------------ the decoder
def test_the_target_decoder_reads_what_rosbags_reads() -> None:
    rng = np.random.default_rng(2)
    centres, sizes = rng.random((4, 3)), rng.random((4, 3))
    vertices, triangles = rng.random((9, 3)) - 0.5, rng.integers(0, 9, (5, 3))
    for frame in ("a", "ab", "abc", "abcd"):  # every alignment of what follows the strings
        payload = encode_grasp_planning(Header(frame, (1, 2)), (0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0),
                                        box_centres=centres, box_sizes=sizes, meshes=((vertices, triangles),),
                                        target_id=frame * 2, group_name=frame)
        ref = ros_types("jazzy").deserialize_cdr(payload, "moveit_msgs/srv/GraspPlanning_Request").target
        got = decode_plan_target(payload)
        assert (got.header.frame_id, got.id) == (ref.header.frame_id, ref.id) == (frame, frame * 2)
        assert np.allclose(got.pose[:3], [ref.pose.position.x, ref.pose.position.y, ref.pose.position.z])
        assert got.primitive_types.tolist() == [p.type for p in ref.primitives]
        assert np.allclose(got.primitive_dimensions, [p.dimensions for p in ref.primitives])
        assert np.allclose(got.primitive_poses[:, :3], [[p.position.x, p.position.y, p.position.z]
                                                        for p in ref.primitive_poses])
        v = np.array([[p.x, p.y, p.z] for p in ref.meshes[0].vertices])
        assert np.allclose(got.mesh_bounds[0], [v.min(axis=0), v.max(axis=0)]) and got.triangles == 5


@pytest.mark.parametrize(("payload", "field"), [(hostile_primitives, "target.primitives"),
                                                (hostile_meshes, "target.meshes[0].vertices")])
def test_a_target_over_the_limits_is_refused_from_its_counts_without_reading_it(payload: Any, field: str) -> None:
    sample = payload()
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(RosDecodeError) as err:
        decode_plan_target(sample)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert err.value.field == field and str(MAX_TARGET_PRIMITIVES if "primitives" in field
                                            else MAX_TARGET_VERTICES) in str(err.value)
    assert seconds < 0.05 and peak < 100_000, (seconds, peak)


def test_a_mesh_within_the_limits_is_read_as_its_bounds_on_a_view_of_the_message() -> None:
    sample = hostile_meshes(MAX_TARGET_VERTICES)  # 48 MB, every count at or within its limit
    tracemalloc.start()
    target = decode_plan_target(sample)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert target.vertices == MAX_TARGET_VERTICES and target.mesh_bounds.shape == (1, 2, 3)
    assert peak < 1 << 20, peak  # a rosbags decode built a Python object per vertex: ~600 bytes each


def test_a_truncated_target_names_the_field() -> None:
    sample = hostile_primitives(10)
    with pytest.raises(RosDecodeError, match="bytes are left|truncated") as err:
        decode_plan_target(sample[:200])
    assert err.value.field.startswith("target.primitive")


# ------------------------------------------------------------------------------------------------ the geometry
def _target(pose: Any = (0, 0, 0, 0, 0, 0, 1), centres: Any = (), sizes: Any = (), meshes: Any = ()) -> Any:
    return decode_plan_target(encode_grasp_planning(HEADER, pose, box_centres=centres, box_sizes=sizes,
                                                    meshes=meshes))


def test_one_shape_is_its_own_box_moved_into_the_detection_frame() -> None:
    yaw = np.pi / 6  # the object turned 30 degrees about z, at (0.1, 0.2, 0.3)
    pose = (0.1, 0.2, 0.3, 0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    to_detection = moveit.pose_matrices(np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]))[0]  # a half turn about x
    box = moveit.target_box(_target(pose, [[0.02, 0.0, 0.0]], [[0.04, 0.06, 0.08]]), to_detection, margin=0.0)
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    flip = np.diag([1.0, -1.0, -1.0])
    assert np.allclose(box.rotation, flip @ rz) and np.allclose(box.half_extents, [0.02, 0.03, 0.04])
    assert np.allclose(box.centre, flip @ (np.array([0.1, 0.2, 0.3]) + rz @ [0.02, 0.0, 0.0]) + [0, 0, 1])
    inside = box.centre + box.rotation @ [0.019, -0.029, 0.039]
    outside = box.centre + box.rotation @ [0.021, 0.0, 0.0]
    assert box.contains(np.array([inside, outside])).tolist() == [True, False]
    sized = moveit.target_box(_target(pose, [[0.0, 0.0, 0.0]], [[0.04, 0.06, 0.08]]), np.eye(4))
    assert np.allclose(sized.half_extents, [0.02 + moveit.TARGET_MARGIN_M, 0.03 + moveit.TARGET_MARGIN_M,
                                            0.04 + moveit.TARGET_MARGIN_M])


def test_several_shapes_are_their_union_in_the_object_frame() -> None:
    yaw = np.pi / 2
    pose = (1.0, 0.0, 0.0, 0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))
    mesh = (np.array([[0.0, 0.0, 0.1], [0.01, 0.02, 0.15]]), np.zeros((1, 3), int))  # a handle above the boxes
    box = moveit.target_box(_target(pose, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], [[0.02, 0.02, 0.02]] * 2, (mesh,)),
                            np.eye(4), margin=0.0)
    # in the object frame: x from -0.01 to 0.11, y from -0.01 to 0.02, z from -0.01 to 0.15
    assert np.allclose(box.half_extents, [0.06, 0.015, 0.08])
    assert np.allclose(box.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert np.allclose(box.centre, [1.0 - 0.005, 0.05, 0.07])


def test_a_target_without_geometry_is_refused() -> None:
    with pytest.raises(moveit.PlanningError) as err:
        moveit.target_box(_target(), np.eye(4))
    assert err.value.code == moveit.INVALID_OBJECT_NAME


def test_a_message_over_the_memory_budget_is_refused_naming_it() -> None:
    budget = MemoryBudget(100)
    with pytest.raises(Exception) as err:
        budget.take(message_cost(61 << 20), retry_after=1.0)
    assert (getattr(err.value, "status", None), getattr(err.value, "field", None)) == (413, "message")
    held = budget.take(message_cost(1 << 20, 10.0), retry_after=1.0)
    assert held == pytest.approx(12.0) and budget.used_mb == pytest.approx(12.0)


def test_service_calls_leave_a_detect_worker_to_http() -> None:
    assert [service_share(w) for w in (1, 2, 4)] == [1, 1, 3]
    share = ServiceShare(service_share(2))
    share.take(2.0)
    with pytest.raises(Exception) as err:
        share.take(2.0)
    assert getattr(err.value, "status", None) == 503 and getattr(err.value, "retry_after", None) == 2.0
    share.give()
    share.take(2.0)


# ------------------------------------------------------------------------------------------------ the node
@pytest.fixture(scope="module")
def big_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, int]]:
    """A node that takes messages up to 64 MiB (the server's default cap), so the 61 MB request reaches it."""
    with serve_ros2(tmp_path_factory.mktemp("ros2-plan"), max_body_bytes=64 << 20) as served:
        yield served


@pytest.fixture(scope="module")
def big_peer(big_server: tuple[TestClient, int]) -> Iterator[RosPeer]:
    p = RosPeer(big_server[1])
    yield p
    p.close()


@pytest.fixture(scope="module")
def planner(big_peer: RosPeer) -> ServiceClient:
    client = big_peer.client("/graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning")
    client.wait_for_service()
    return client


@pytest.fixture(scope="module")
def errors(big_peer: RosPeer) -> Collector:
    return big_peer.subscribe("/graspd/errors", "std_msgs/msg/String")


def node_of(server: tuple[TestClient, int]) -> Any:
    return server[0].app.state.ros2


def send_cloud(peer: RosPeer, points: np.ndarray) -> None:
    """The mug cloud, and wait until the node took it as the newest."""
    json_sink = peer.subscribe("/graspd/detections", "std_msgs/msg/String")
    peer.publish_until(peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2"),
                       encode_pointcloud2(points, HEADER), [json_sink])


def error_bodies(sink: Collector, decode: Decode) -> list[dict[str, Any]]:
    with sink.cond:
        return [json.loads(decode(d, "std_msgs/msg/String").data) for d in sink.got]


def test_hostile_plan_requests_are_refused_in_time_and_the_next_one_is_served(
        big_server: tuple[TestClient, int], big_peer: RosPeer, planner: ServiceClient, errors: Collector,
        mug_points: np.ndarray, decode: Decode) -> None:
    send_cloud(big_peer, mug_points)
    for payload, field in ((hostile_primitives(), "target.primitives"),
                           (hostile_meshes(), "target.meshes[0].vertices")):
        errors.clear()
        t0 = time.perf_counter()
        _, _, reply = planner.call(payload)
        seconds = time.perf_counter() - t0
        response = decode(reply, RESPONSE)
        assert response.error_code.val == moveit.PLANNING_FAILED and not response.grasps
        assert field in response.error_code.message and seconds < 5, seconds
        assert errors.wait()
        body = error_bodies(errors, decode)[0]
        assert (body["status"], body["field"], body["topic"]) == (422, field, "/graspd/plan_grasps")
    assert node_of(big_server).engine.budget.used_mb == 0  # the message's share was given back
    lo, hi = np.percentile(mug_points, 30, axis=0), np.percentile(mug_points, 70, axis=0)
    good = encode_grasp_planning(HEADER, box_centres=[(lo + hi) / 2], box_sizes=[hi - lo])
    response = decode(planner.call(good)[2], RESPONSE)
    assert response.error_code.val == moveit.SUCCESS and len(response.grasps) > 0


def test_a_stale_cloud_is_answered_before_the_target_is_read(
        big_server: tuple[TestClient, int], planner: ServiceClient, decode: Decode) -> None:
    node = node_of(big_server)
    cloud, entry, _ = node._last_cloud
    node._last_cloud = (cloud, entry, time.monotonic() - 3600)
    try:
        response = decode(planner.call(hostile_primitives())[2], RESPONSE)
    finally:
        node._last_cloud = (cloud, entry, time.monotonic())
    assert response.error_code.val == moveit.SENSOR_INFO_STALE, response.error_code


def test_a_plan_call_over_the_services_share_is_refused_at_once(
        big_server: tuple[TestClient, int], planner: ServiceClient, errors: Collector, decode: Decode) -> None:
    share = node_of(big_server).share
    errors.clear()
    for _ in range(share.limit):
        share.take(1.0)
    try:
        t0 = time.perf_counter()
        response = decode(planner.call(hostile_primitives(10))[2], RESPONSE)
        seconds = time.perf_counter() - t0
    finally:
        for _ in range(share.limit):
            share.give()
    assert response.error_code.val == moveit.FAILURE and "503" in response.error_code.message
    assert seconds < 1.0 and errors.wait() and error_bodies(errors, decode)[0]["status"] == 503
