"""The ROS 2 node's answers are the saved ones (tests/server/data/transport_cases/) and the JSON route's: a
detect_grasps call (CloudIndexed of table_mug's points, every 4th as one flat row, indices near the middle) gives
the grasps POST /detect gives with the same target and the node's options, and a PointCloud2 on /graspd/cloud the
JSON answer on /graspd/detections that POST /detect gives."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.io.ros import Header, encode_cloud_indexed, encode_pointcloud2
from server.transport_cases import SMALL, agree, check, json_body, mug_points

from .conftest import Collector, Decode, RosPeer

HEADER = Header("camera_depth_optical_frame", (1712345678, 123456789))
GCL, STRING = "gpd_ros/msg/GraspConfigList", "std_msgs/msg/String"


@pytest.fixture(scope="module")
def mug(real_data: Path) -> np.ndarray:
    return mug_points(real_data)


def _http(client: TestClient, body: dict[str, Any]) -> dict[str, Any]:
    r = client.post("/detect", json=body)
    assert r.status_code == 200, r.text
    answer: dict[str, Any] = r.json()
    return answer


def _gcl(msg: Any) -> list[dict[str, Any]]:
    """A GraspConfigList's grasps in the JSON answer's names (position, approach, ..., width, score, sample); an
    unscored grasp's score (NaN) as None, JSON's null."""
    def vec(v: Any) -> list[float]:
        return [float(v.x), float(v.y), float(v.z)]

    return [{"position": vec(g.position), "approach": vec(g.approach), "binormal": vec(g.binormal),
             "axis": vec(g.axis), "sample": vec(g.sample), "width": float(g.width.data),
             "score": None if np.isnan(g.score.data) else float(g.score.data)} for g in msg.grasps]


def test_detect_grasps_call_is_the_saved_answer_and_the_json_routes(
        ros2_server: tuple[TestClient, int], peer: RosPeer, mug: np.ndarray, decode: Decode) -> None:
    client = peer.client("/graspd/detect_grasps", "gpd_ros/srv/DetectGrasps")
    client.wait_for_service()
    centre = np.median(mug, axis=0)
    indices = np.flatnonzero(np.linalg.norm(mug - centre, axis=1) < 0.06)
    _, _, reply = client.call(encode_cloud_indexed(mug, [[0.0, 0.0, 0.0]], indices, header=HEADER))
    msg = decode(reply, GCL)
    assert msg.header.frame_id == HEADER.frame_id and len(msg.grasps) > 0
    got = _gcl(msg)
    reference = _http(ros2_server[0], json_body(mug, **SMALL, target={"indices": indices.tolist()}))
    check("ros2_detect_grasps", {"grasps": got})
    keys = got[0].keys()
    want = [{k: g[k] for k in keys} for g in reference["grasps"]]
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):  # GraspConfig carries float32 numbers
        for k in keys:
            assert (g[k] is None and w[k] is None) or np.allclose(g[k], w[k], rtol=1e-6, atol=1e-6), (k, g[k], w[k])


def test_pointcloud2_stream_answer_is_the_saved_answer_and_the_json_routes(
        ros2_server: tuple[TestClient, int], peer: RosPeer, mug: np.ndarray, decode: Decode) -> None:
    sink: Collector = peer.subscribe("/graspd/detections", STRING)
    peer.publish_until(peer.publisher("/graspd/cloud", "sensor_msgs/msg/PointCloud2"),
                       encode_pointcloud2(mug, HEADER), [sink])
    answer = json.loads(decode(sink.got[0], STRING).data)
    assert answer["header"]["frame_id"] == HEADER.frame_id and len(answer["grasps"]) > 0
    check("ros2_stream", answer)
    reference = _http(ros2_server[0], json_body(mug, **SMALL))
    agree({k: v for k, v in answer.items() if k != "header"}, reference, "ros2 PointCloud2 stream")
