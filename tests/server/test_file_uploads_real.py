"""The PCL captures in ../shared/data/real as PCL wrote them (organised 640 x 480, binary_compressed, bytes after
the block), over HTTP and through the Python client: every point Open3D reads arrives (the NaN pixels dropped and
counted); a PCD's normals are the detector's; a depth image with its calibration YAML as the intrinsics."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd_client import GraspClient

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from bags import CLOUD_TOPIC, INTRINSICS, depth_image, write_rosbag2  # noqa: E402

CAPTURES = ["milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"]
OPTIONS = {"num_samples": 30, "max_grasps": 5, "seed": 1}


def _open3d_counts(path: Path) -> tuple[int, int]:
    """(NaN rows, all rows) of the cloud Open3D reads."""
    points = o3d.t.io.read_point_cloud(str(path)).point.positions.numpy()
    return int((~np.isfinite(points).all(axis=1)).sum()), len(points)


def _dropped(body: dict[str, Any]) -> tuple[int, int]:
    """(rows dropped, rows received) as the answer counts them; an organised capture's pixels without depth are
    counted, never warned of."""
    assert "non_finite_dropped" not in [w["code"] for w in body["warnings"]], body["warnings"]
    return int(body["num_points_dropped"]), int(body["num_points_received"])


@pytest.mark.parametrize("name", CAPTURES)
def test_pcl_captures_arrive_whole_over_http_and_the_client(client: TestClient, real_data: Path, name: str) -> None:
    path = real_data / name
    expected = _open3d_counts(path)
    response = client.post("/detect", params=OPTIONS, content=path.read_bytes(),
                           headers={"content-type": "application/x-pcd"})
    assert response.status_code == 200, response.text
    assert _dropped(response.json()) == expected
    python = GraspClient("http://testserver")
    python._http = client  # the client's requests go to the test app
    grasps = python.detect_file(path, **OPTIONS)
    assert _dropped(grasps.raw) == expected


def _binary_pcd(points: np.ndarray, normals: np.ndarray) -> bytes:
    head = ("VERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\n"
            f"COUNT 1 1 1 1 1 1\nWIDTH {len(points)}\nHEIGHT 1\nPOINTS {len(points)}\nDATA binary\n")
    return head.encode() + np.hstack([points, normals]).astype("<f4").tobytes()


def test_a_pcd_with_normals_is_detected_with_them(client: TestClient, real_data: Path) -> None:
    """Normals in the file reach the detector: the same points with other normals give other grasps, and the
    file's normals give the grasps of the same cloud sent as JSON with those normals."""
    points = o3d.io.read_point_cloud(str(real_data / "table_mug.pcd"))
    pts = np.asarray(points.points, np.float32)[::4]
    up = np.tile(np.float32([0, 0, -1]), (len(pts), 1))
    tilted = np.tile(np.float32([0, -0.6, -0.8]), (len(pts), 1))
    body = {**OPTIONS, "exclude_support_plane": "false"}
    a = client.post("/detect", params=body, content=_binary_pcd(pts, up), headers={"content-type": "application/x-pcd"})
    b = client.post("/detect", params=body, content=_binary_pcd(pts, tilted),
                    headers={"content-type": "application/x-pcd"})
    as_json = client.post("/detect", json={"cloud": {"points": pts.tolist(), "normals": up.tolist()},
                                           **{**OPTIONS, "exclude_support_plane": False}})
    for r in (a, b, as_json):
        assert r.status_code == 200, r.text
    pos = [np.array([g["position"] for g in r.json()["grasps"]]) for r in (a, b, as_json)]
    assert pos[0].shape == pos[2].shape and np.allclose(pos[0], pos[2])
    assert pos[0].shape != pos[1].shape or not np.allclose(pos[0], pos[1])


CALIBRATION = (f"image_width: 160\nimage_height: 120\ncamera_name: d\ncamera_matrix: {{rows: 3, cols: 3, data: "
               f"[{INTRINSICS.fx}, 0, {INTRINSICS.cx}, 0, {INTRINSICS.fy}, {INTRINSICS.cy}, 0, 0, 1]}}\n"
               "distortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n")


def test_a_depth_png_takes_its_calibration_yaml_as_intrinsics(client: TestClient) -> None:
    png = io.BytesIO()
    Image.fromarray(depth_image()).save(png, format="PNG")
    by_numbers = client.post("/detect", params={**OPTIONS, "intrinsics": ",".join(map(str, INTRINSICS))},
                             content=png.getvalue(), headers={"content-type": "image/png"})
    by_yaml = client.post("/detect", params={**OPTIONS, "intrinsics": CALIBRATION}, content=png.getvalue(),
                          headers={"content-type": "image/png"})
    assert by_numbers.status_code == by_yaml.status_code == 200, by_yaml.text
    assert by_yaml.json()["grasps"]
    assert [g["pose"] for g in by_numbers.json()["grasps"]] == [g["pose"] for g in by_yaml.json()["grasps"]]
    wrong = client.post("/detect", params={**OPTIONS, "intrinsics": CALIBRATION.replace("160", "640")},
                        content=png.getvalue(), headers={"content-type": "image/png"})
    assert wrong.status_code == 422 and wrong.json()["field"] == "intrinsics" and "640x120" in wrong.json()["error"]


def test_the_client_uploads_a_bag_by_its_suffix(client: TestClient, tmp_path: Path) -> None:
    bag = write_rosbag2(tmp_path / "bag")
    python = GraspClient("http://testserver")
    python._http = client
    direct = client.post("/detect", params={**OPTIONS, "topic": CLOUD_TOPIC, "index": 2}, content=bag.read_bytes(),
                         headers={"content-type": "application/x-mcap"})
    grasps = python.detect_file(bag, topic=CLOUD_TOPIC, index=2, **OPTIONS)
    assert direct.status_code == 200 and len(grasps) == len(direct.json()["grasps"]) > 0
