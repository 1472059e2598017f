"""ROS bags as the body of POST /detect (MCAP and ROS 1 .bag, written in the test with rosbags' writers): the
topic's message with the camera pose of the bag's /tf_static chain gives the grasps the same cloud and pose
sent directly give; what cannot be read gets a 4xx naming the field, fast."""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from bags import (  # noqa: E402
    CLOUD_TOPIC,
    IMAGE_TOPIC,
    INTRINSICS,
    chain_pose,
    depth_cloud,
    depth_image,
    mcap_with_chunk_size,
    write_rosbag1,
    write_rosbag2,
)

OPTIONS = "num_samples=60&seed=3"


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("bags")
    return {"mcap": write_rosbag2(folder / "r2").read_bytes(), "ros1": write_rosbag1(folder / "r1.bag").read_bytes(),
            "db3": write_rosbag2(folder / "r3", "sqlite3").read_bytes()}


def _pose_query() -> str:
    return "camera_pose=" + ",".join(f"{v:.17g}" for v in chain_pose().reshape(-1)) + "&points_frame=camera"


def _grasps(response: Any) -> np.ndarray:
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["grasps"], "no grasps: the comparison would prove nothing"
    return np.array([g["position"] + g["approach"] for g in body["grasps"]])


def _npy(points: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, points)
    return buf.getvalue()


@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_a_bag_cloud_gives_the_grasps_of_the_same_cloud_sent_directly(client: TestClient, bags: dict[str, bytes],
                                                                      kind: str) -> None:
    """PointCloud2 message 1 of the bag, posed by the two-step /tf_static chain (world <- camera_link <- optical):
    the grasps of the .npy of the same points with the composed pose as camera_pose, in the world frame."""
    content_type = "application/x-mcap" if kind == "mcap" else "application/x-rosbag"
    got = client.post(f"/detect?{OPTIONS}&topic={CLOUD_TOPIC}&index=1", content=bags[kind],
                      headers={"content-type": content_type})
    direct = client.post(f"/detect?{OPTIONS}&{_pose_query()}", content=_npy(depth_cloud() + np.float32(0.01)),
                         headers={"content-type": "application/x-npy"})
    assert np.allclose(_grasps(got), _grasps(direct), atol=1e-5)
    sniffed = client.post(f"/detect?{OPTIONS}&topic={CLOUD_TOPIC}&index=1", content=bags[kind],
                          headers={"content-type": "application/octet-stream"})  # the magic bytes say what it is
    assert np.allclose(_grasps(sniffed), _grasps(got))


def test_a_bag_depth_image_gives_the_grasps_of_the_same_png(client: TestClient, bags: dict[str, bytes]) -> None:
    """A depth Image with the CameraInfo found as its sibling camera_info topic: the grasps of the depth PNG
    with those intrinsics and the chain's pose."""
    png = io.BytesIO()
    Image.fromarray(depth_image()).save(png, format="PNG")
    intrinsics = ",".join(str(v) for v in INTRINSICS)
    got = client.post(f"/detect?{OPTIONS}&topic={IMAGE_TOPIC}", content=bags["mcap"],
                      headers={"content-type": "application/x-mcap"})
    direct = client.post(f"/detect?{OPTIONS}&intrinsics={intrinsics}&{_pose_query()}", content=png.getvalue(),
                         headers={"content-type": "image/png"})
    assert np.allclose(_grasps(got), _grasps(direct), atol=1e-5)


@pytest.mark.parametrize(("query", "field", "words"), [
    ("topic=/nothing", "topic", "no topic '/nothing'"),
    ("topic=/tf_static", "topic", "TFMessage"),
    (f"topic={CLOUD_TOPIC}&index=3", "index", "fewer than 4 messages"),
    (f"topic={CLOUD_TOPIC}&index=-1", "index", "index"),
    (f"topic={CLOUD_TOPIC}&frame=base_link", "frame", "not in the bag's /tf_static"),
    (f"topic={IMAGE_TOPIC}&info_topic=/camera/color/camera_info", "info_topic", "no CameraInfo topic"),
])
def test_what_is_not_in_the_bag_is_named(client: TestClient, bags: dict[str, bytes], query: str, field: str,
                                         words: str) -> None:
    response = client.post(f"/detect?{OPTIONS}&{query}", content=bags["mcap"],
                           headers={"content-type": "application/x-mcap"})
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field and words in response.json()["error"], response.json()


def test_the_default_topic_is_the_only_pointcloud2(client: TestClient, bags: dict[str, bytes]) -> None:
    got = client.post(f"/detect?{OPTIONS}", content=bags["mcap"], headers={"content-type": "application/x-mcap"})
    first = client.post(f"/detect?{OPTIONS}&topic={CLOUD_TOPIC}&index=0", content=bags["mcap"],
                        headers={"content-type": "application/x-mcap"})
    assert np.allclose(_grasps(got), _grasps(first))


@pytest.mark.parametrize(("declared", "words"), [(1 << 40, "declares 1099511627776 bytes uncompressed"),
                                                  (100, "inflates past its declared 100 bytes")])
def test_a_hostile_chunk_is_refused_before_it_inflates(client: TestClient, bags: dict[str, bytes], declared: int,
                                                       words: str) -> None:
    """A zstd chunk declaring a terabyte is refused before anything inflates; one declaring less than its data
    holds is stopped at the declared size.  Both within a second, and the next upload is served."""
    start = time.perf_counter()
    response = client.post(f"/detect?{OPTIONS}&topic={CLOUD_TOPIC}", content=mcap_with_chunk_size(bags["mcap"],
                                                                                                   declared),
                           headers={"content-type": "application/x-mcap"})
    assert time.perf_counter() - start < 1.0
    assert response.status_code == 422 and response.json()["field"] == "body", response.text
    assert words in response.json()["error"]
    ok = client.post(f"/detect?{OPTIONS}&topic={CLOUD_TOPIC}", content=bags["mcap"],
                     headers={"content-type": "application/x-mcap"})
    assert ok.status_code == 200


def test_sqlite_uploads_and_garbage_are_refused_clearly(client: TestClient, bags: dict[str, bytes]) -> None:
    db3 = client.post(f"/detect?{OPTIONS}", content=bags["db3"], headers={"content-type": "application/x-sqlite3"})
    assert db3.status_code == 422 and db3.json()["field"] == "body" and "upload MCAP" in db3.json()["error"]
    truncated = client.post(f"/detect?{OPTIONS}", content=bags["mcap"][: len(bags["mcap"]) // 2],
                            headers={"content-type": "application/x-mcap"})
    assert truncated.status_code == 422 and truncated.json()["field"] == "body", truncated.text
    junk = client.post(f"/detect?{OPTIONS}", content=b"not a bag at all",
                       headers={"content-type": "application/x-mcap"})
    assert junk.status_code == 422 and junk.json()["field"] == "body", junk.text
