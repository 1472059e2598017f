"""graspd serve --ros2 as a ROS 2 node on rmw_cyclonedds sees it (no ROS install): table_mug as a PointCloud2 on
/graspd/cloud gets a GraspConfigList with the same header and grasps on the mug, plus PoseArray, moveit_msgs Grasp
(finger postures filled) and MarkerArray with that header; both services answer rmw_cyclonedds-framed requests;
a lying, empty or oversized cloud is dropped with an error on /graspd/errors and the next cloud is still
answered; the graph (ros_discovery_info), the DDS type names and the QoS are what ROS 2 tools expect."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import pytest
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import Policy
from scipy.spatial import cKDTree

from graspd.io.ros import Header, encode_cloud_indexed, encode_pointcloud2
from graspd.server.ros2.dds import latched_qos

from .conftest import Collector, Decode, RosPeer, peer_types

HEADER = Header("camera_depth_optical_frame", (1712345678, 123456789))
GCL, STRING = "gpd_ros/msg/GraspConfigList", "std_msgs/msg/String"


def errors_of(sink: Collector, decode: Decode) -> list[dict[str, Any]]:
    with sink.cond:
        return [json.loads(decode(d, STRING).data) for d in sink.got]


def mug_only(points: np.ndarray, answer: dict[str, Any]) -> np.ndarray:
    """The points more than 1.5 cm above the support the detection found (the mug)."""
    support = answer["environment"]["support"]
    height = points @ np.asarray(support["normal"]) + support["offset"]
    return points[height > 0.015]


@pytest.fixture(scope="module")
def outputs(peer: RosPeer) -> dict[str, Collector]:
    return {"gcl": peer.subscribe("/graspd/grasp_config_list", GCL),
            "poses": peer.subscribe("/graspd/grasp_poses", "geometry_msgs/msg/PoseArray"),
            "moveit": peer.subscribe("/graspd/moveit_grasps", "moveit_msgs/msg/Grasp"),
            "markers": peer.subscribe("/graspd/grasp_markers", "visualization_msgs/msg/MarkerArray"),
            "json": peer.subscribe("/graspd/detections", STRING),
            "errors": peer.subscribe("/graspd/errors", STRING)}


@pytest.fixture(scope="module")
def cloud_writer(peer: RosPeer) -> Any:
    return peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2")


def send_cloud(peer: RosPeer, writer: Any, outputs: dict[str, Collector], payload: bytes, wait_for: str = "json"
               ) -> None:
    for sink in outputs.values():
        sink.clear()
    peer.publish_until(writer, payload, [outputs[wait_for]])


def test_table_mug_pointcloud2_gets_grasps_on_the_mug_with_its_header(
        peer: RosPeer, outputs: dict[str, Collector], cloud_writer: Any, mug_points: np.ndarray,
        decode: Decode) -> None:
    send_cloud(peer, cloud_writer, outputs, encode_pointcloud2(mug_points, HEADER))
    answer = json.loads(decode(outputs["json"].got[0], STRING).data)
    gcl = decode(outputs["gcl"].got[0], GCL)
    assert (gcl.header.frame_id, gcl.header.stamp.sec, gcl.header.stamp.nanosec) == (HEADER.frame_id, *HEADER.stamp)
    assert 0 < len(gcl.grasps) <= 6 and len(gcl.grasps) == len(answer["grasps"])
    assert answer["header"]["frame_id"] == HEADER.frame_id and answer["frame"] == "cloud"
    samples = np.array([[g.sample.x, g.sample.y, g.sample.z] for g in gcl.grasps])
    positions = np.array([[g.position.x, g.position.y, g.position.z] for g in gcl.grasps])
    assert np.allclose(positions, [g["position"] for g in answer["grasps"]], atol=1e-6)
    on_mug = cKDTree(mug_only(mug_points, answer)).query(samples)[0]
    assert on_mug.max() < 0.003, on_mug  # every grasp was found at a mug point
    assert outputs["moveit"].wait(len(gcl.grasps)) and outputs["poses"].wait() and outputs["markers"].wait()
    poses = decode(outputs["poses"].got[0], "geometry_msgs/msg/PoseArray")
    markers = decode(outputs["markers"].got[0], "visualization_msgs/msg/MarkerArray")
    assert poses.header.frame_id == HEADER.frame_id and len(poses.poses) == len(gcl.grasps)
    assert all(m.header.frame_id == HEADER.frame_id for m in markers.markers)
    first = decode(outputs["moveit"].got[0], "moveit_msgs/msg/Grasp")
    assert first.grasp_pose.header.frame_id == HEADER.frame_id and first.grasp_pose.header.stamp.sec == HEADER.stamp[0]
    assert list(first.grasp_posture.joint_names) == ["panda_finger_joint1", "panda_finger_joint2"]
    width = gcl.grasps[0].width.data
    assert np.allclose(first.grasp_posture.points[0].positions, max(0.0, width - 0.01) / 2, atol=1e-6)
    assert np.allclose(first.pre_grasp_posture.points[0].positions, (0.12 - 2 * 0.01) / 2)
    a = gcl.grasps[0].approach
    d = first.pre_grasp_approach.direction.vector
    assert np.allclose([d.x, d.y, d.z], [a.x, a.y, a.z], atol=1e-6) and first.pre_grasp_approach.desired_distance > 0


def test_a_lying_empty_or_oversized_cloud_is_refused_on_errors_and_the_node_keeps_serving(
        peer: RosPeer, outputs: dict[str, Collector], cloud_writer: Any, mug_points: np.ndarray,
        decode: Decode) -> None:
    t = peer_types().types
    hdr = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="cam")
    fields = [t["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate("xyz")]
    lying = t["sensor_msgs/msg/PointCloud2"](header=hdr, height=1, width=100_000, fields=fields, is_bigendian=False,
                                             point_step=12, row_step=1_200_000, data=np.zeros(24, np.uint8),
                                             is_dense=True)
    cases = [(bytes(peer_types().serialize_cdr(lying, "sensor_msgs/msg/PointCloud2")), 422, "data"),
             (encode_pointcloud2(np.full((50, 3), np.nan, np.float32)), 422, "data"),
             (encode_pointcloud2(np.random.default_rng(0).random((300_000, 3), np.float32)), 413, "payload")]
    for payload, status, field in cases:
        send_cloud(peer, cloud_writer, outputs, payload, wait_for="errors")
        error = errors_of(outputs["errors"], decode)[0]
        assert (error["status"], error["field"], error["topic"]) == (status, field, "/graspd/cloud"), error
        assert error["error"] and not outputs["gcl"].got
    send_cloud(peer, cloud_writer, outputs, encode_pointcloud2(mug_points, HEADER), wait_for="gcl")
    assert len(decode(outputs["gcl"].got[0], GCL).grasps) > 0


def test_detect_grasps_answers_an_rmw_cyclonedds_request(peer: RosPeer, outputs: dict[str, Collector],
                                                         mug_points: np.ndarray, decode: Decode) -> None:
    client = peer.client("/graspd/detect_grasps", "gpd_ros/srv/DetectGrasps")
    client.wait_for_service()
    centre = np.median(mug_points, axis=0)  # the indices name the points within 6 cm of the scene's middle
    indices = np.flatnonzero(np.linalg.norm(mug_points - centre, axis=1) < 0.06)
    request = encode_cloud_indexed(mug_points, [[0.0, 0.0, 0.0]], indices, header=HEADER)
    guid, seq, reply = client.call(request)
    assert guid == client.guid and seq >= 1
    gcl = decode(reply, GCL)  # DetectGrasps_Response is one GraspConfigList
    assert gcl.header.frame_id == HEADER.frame_id and gcl.header.stamp.nanosec == HEADER.stamp[1]
    assert 0 < len(gcl.grasps) <= 6
    samples = np.array([[g.sample.x, g.sample.y, g.sample.z] for g in gcl.grasps])
    assert cKDTree(mug_points[indices]).query(samples)[0].max() < 0.005  # sampled on the indexed points
    # a request lying about its indices: an empty answer to the same request, and the error on /graspd/errors
    outputs["errors"].clear()
    bad = encode_cloud_indexed(mug_points[:10], [[0.0, 0.0, 0.0]], [3, 99], header=HEADER)
    guid, seq2, reply = client.call(bad)
    assert seq2 == seq + 1 and len(decode(reply, GCL).grasps) == 0
    assert outputs["errors"].wait()
    error = errors_of(outputs["errors"], decode)[0]
    assert (error["field"], error["topic"]) == ("indices", "/graspd/detect_grasps")


def collision_object(frame: str, centre: np.ndarray, size: np.ndarray) -> Any:
    """A moveit_msgs/CollisionObject: one BOX of size (m) at centre, in frame."""
    t = peer_types().types
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=centre[0], y=centre[1], z=centre[2]),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    identity = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                           orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    box = t["shape_msgs/msg/SolidPrimitive"](type=1, dimensions=np.asarray(size, np.float64),
                                             polygon=t["geometry_msgs/msg/Polygon"](points=[]))
    hdr = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame)
    return t["moveit_msgs/msg/CollisionObject"](
        header=hdr, pose=pose, id="mug", type=t["object_recognition_msgs/msg/ObjectType"](key="", db=""),
        primitives=[box], primitive_poses=[identity], meshes=[], mesh_poses=[], planes=[], plane_poses=[],
        subframe_names=[], subframe_poses=[], operation=0)


def plan_request(target: Any) -> bytes:
    t = peer_types()
    name = "moveit_msgs/srv/GraspPlanning_Request"
    msg = t.types[name](group_name="arm", target=target, support_surfaces=["table"], candidate_grasps=[],
                        movable_obstacles=[])
    return bytes(t.serialize_cdr(msg, name))


def test_plan_grasps_answers_moveit_grasps_on_the_target_in_its_frame(
        peer: RosPeer, outputs: dict[str, Collector], cloud_writer: Any, mug_points: np.ndarray,
        decode: Decode) -> None:
    send_cloud(peer, cloud_writer, outputs, encode_pointcloud2(mug_points, HEADER))
    mug = mug_only(mug_points, json.loads(decode(outputs["json"].got[0], STRING).data))
    lo, hi = mug.min(axis=0), mug.max(axis=0)
    client = peer.client("/graspd/plan_grasps", "moveit_msgs/srv/GraspPlanning")
    client.wait_for_service()
    _, _, reply = client.call(plan_request(collision_object(HEADER.frame_id, (lo + hi) / 2, hi - lo)))
    response = decode(reply, "moveit_msgs/srv/GraspPlanning_Response")
    assert response.error_code.val == 1, response.error_code
    assert 0 < len(response.grasps) <= 6
    fingertips = []
    for g in response.grasps:
        assert g.grasp_pose.header.frame_id == HEADER.frame_id
        assert g.pre_grasp_approach.desired_distance > 0 and g.post_grasp_retreat.desired_distance > 0
        assert len(g.grasp_posture.points[0].positions) == 2 and len(g.pre_grasp_posture.points[0].positions) == 2
        p, d = g.grasp_pose.pose.position, g.pre_grasp_approach.direction.vector
        fingertips.append(np.array([p.x, p.y, p.z]) + 0.06 * np.array([d.x, d.y, d.z]))
    assert cKDTree(mug).query(np.array(fingertips))[0].max() < 0.05  # the hands close on the mug
    # a frame graspd cannot reach: FRAME_TRANSFORM_FAILURE, no grasps
    _, _, reply = client.call(plan_request(collision_object("map", (lo + hi) / 2, hi - lo)))
    response = decode(reply, "moveit_msgs/srv/GraspPlanning_Response")
    assert response.error_code.val == -21 and len(response.grasps) == 0
    assert "map" in response.error_code.message


def endpoints(peer: RosPeer, kind: Any) -> dict[str, Any]:
    """The DDS endpoints of the domain (DCPSPublication or DCPSSubscription) by topic name, after discovery."""
    reader = BuiltinDataReader(peer.dp, kind)
    found: dict[str, Any] = {}
    for _ in range(50):
        for s in reader.take(N=200):
            found.setdefault(s.topic_name, s)
        if "rt/graspd/cloud" in found or "rt/graspd/grasp_config_list" in found:
            break
        time.sleep(0.1)
    return found


def test_the_graph_sees_the_node_its_type_names_and_qos(peer: RosPeer, decode: Decode) -> None:
    subs = endpoints(peer, BuiltinTopicDcpsSubscription)
    pubs = endpoints(peer, BuiltinTopicDcpsPublication)
    cloud = subs["rt/graspd/cloud"]
    assert cloud.type_name == "sensor_msgs::msg::dds_::PointCloud2_"
    assert cloud.qos[Policy.Reliability] == Policy.Reliability.BestEffort
    assert cloud.qos[Policy.History].depth <= 10
    assert subs["rt/graspd/cloud_sources"].type_name == "gpd_ros::msg::dds_::CloudSources_"
    gcl = pubs["rt/graspd/grasp_config_list"]
    assert gcl.type_name == "gpd_ros::msg::dds_::GraspConfigList_"
    assert isinstance(gcl.qos[Policy.Reliability], Policy.Reliability.Reliable)
    request, reply = subs["rq/graspd/detect_graspsRequest"], pubs["rr/graspd/detect_graspsReply"]
    assert request.type_name == "gpd_ros::srv::dds_::DetectGrasps_Request_"
    assert reply.type_name == "gpd_ros::srv::dds_::DetectGrasps_Response_"
    assert subs["rq/graspd/plan_graspsRequest"].type_name == "moveit_msgs::srv::dds_::GraspPlanning_Request_"
    sid = request.qos[Policy.Userdata].data
    assert sid.startswith(b"serviceid=") and reply.qos[Policy.Userdata].data == sid  # clients pair them by it
    # ros_discovery_info: the node /graspd with exactly its readers and writers (ros2 node list / node info)
    sink = Collector()  # ros_discovery_info has no rt/ prefix
    peer.reader("ros_discovery_info", "rmw_dds_common/msg/ParticipantEntitiesInfo", latched_qos(), sink)
    assert sink.wait()
    info = decode(sink.got[-1], "rmw_dds_common/msg/ParticipantEntitiesInfo")
    (node,) = info.node_entities_info_seq
    assert (node.node_name, node.node_namespace) == ("graspd", "/")
    ours = {bytes(s.key.bytes) for s in subs.values() if s.participant_key.bytes == bytes(info.gid.data[:16])}
    assert {bytes(g.data[:16]) for g in node.reader_gid_seq} == ours
    assert len(node.writer_gid_seq) == 9  # 7 outputs + 2 service replies
    assert pubs["rt/graspd/objects"].type_name == "vision_msgs::msg::dds_::Detection3DArray_"
