"""An organised cloud's [height, width] on the wire: checked against the points as sent (422 naming cloud.shape),
and carried with the cloud to the detector as its grid."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from graspd.io.pcd import read_pcd
from graspd.server.schemas import Cloud
from graspd.server.uploads import upload_request
from graspd_client import encode_array


def organised_points(height: int = 12, width: int = 16) -> np.ndarray:
    """A plane 0.6 m in front of a camera at the origin, one point per pixel, the first row with no depth (NaN)."""
    v, u = np.mgrid[0:height, 0:width]
    z = np.full(u.shape, 0.6)
    pts = np.stack([(u - width / 2) * 0.004, (v - height / 2) * 0.004, z], axis=-1).reshape(-1, 3)
    pts[:width] = np.nan
    return pts


@pytest.mark.parametrize(("shape", "why"), [([12, 15], "too few pixels"), ([13, 16], "too many pixels"),
                                            ([0, 192], "zero height"), ([12], "one number"),
                                            ([12, 16, 1], "three numbers")])
def test_wrong_shape_is_a_422_naming_cloud_shape(client: TestClient, shape: list[int], why: str) -> None:
    pts = organised_points()
    payload: dict[str, Any] = {"cloud": {"points": np.nan_to_num(pts, nan=0.0).tolist(), "shape": shape}}
    r = client.post("/detect", content=json.dumps(payload), headers={"Content-Type": "application/json"})
    assert r.status_code == 422, (why, r.text)
    assert r.json()["field"].startswith("cloud.shape"), (why, r.json())


def test_shape_counts_the_points_as_sent_before_non_finite_rows_are_dropped() -> None:
    pts = organised_points()
    cloud = Cloud.model_validate({"points": pts.astype(np.float32), "shape": [12, 16]})
    got = cloud.to_input()
    assert got.dropped == 16 and len(got.cloud) == 12 * 16 - 16
    grid = got.cloud.grid
    assert grid is not None and (grid.height, grid.width) == (12, 16)
    # each kept point's pixel index is its row as sent: the first image row (no depth) is gone
    assert np.array_equal(grid.pixel, np.arange(16, 12 * 16))
    assert np.array_equal(got.cloud.points, pts[16:].astype(np.float32))


def test_no_shape_is_an_unorganised_cloud() -> None:
    cloud = Cloud.model_validate({"points": organised_points()[16:].astype(np.float32)})
    assert cloud.to_input().cloud.grid is None


def test_camera_poses_keep_the_grid(client: TestClient) -> None:
    pose = np.eye(4)
    pose[:3, 3] = [0.1, 0.2, 0.3]
    cloud = Cloud.model_validate({"points": organised_points().astype(np.float32), "shape": [12, 16],
                                  "camera_poses": [pose.tolist()], "points_frame": "camera"})
    got = cloud.to_input().cloud
    assert got.grid is not None and np.array_equal(got.grid.pixel, np.arange(16, 12 * 16))
    assert np.allclose(got.points, organised_points()[16:] + [0.1, 0.2, 0.3], atol=1e-6)


def test_an_organised_request_detects(client: TestClient) -> None:
    """A sent shape with NaN pixels (binary wire array) reaches detection and the answer is a normal one."""
    pts = organised_points(40, 50).astype(np.float32)
    r = client.post("/detect", json={"cloud": {"points": encode_array(pts), "shape": [40, 50]}, "num_samples": 20})
    assert r.status_code == 200, r.text
    assert "non_finite_dropped" in [w["code"] for w in r.json()["warnings"]]


def test_an_organised_pcd_upload_carries_its_shape_to_the_detector(client: TestClient, real_data: Path) -> None:
    """The Kinect capture (640x480, NaN holes) uploaded as the file is: the request's cloud has the file's shape,
    and detection runs on the grid (mixed pixels dropped: fewer points after preprocessing than the same points
    sent unorganised, as many as the same points sent as JSON with cloud.shape)."""
    path = real_data / "milk_cartoon_all_small_clorox.pcd"
    body = upload_request(path.read_bytes(), "pcd", {}, [])
    assert tuple(body["cloud"]["shape"]) == (480, 640)
    grid = Cloud.model_validate(body["cloud"]).to_input().cloud.grid
    assert grid is not None and (grid.height, grid.width) == (480, 640)
    options = {"num_samples": 20, "workspace": "-0.45,0.45,-0.4,0.25,0.5,1.2"}
    upload = client.post("/detect", params=options, content=path.read_bytes(),
                         headers={"content-type": "application/x-pcd"})
    assert upload.status_code == 200, upload.text
    pts = read_pcd(path.read_bytes()).points
    json_options = {"num_samples": 20, "workspace": [-0.45, 0.45, -0.4, 0.25, 0.5, 1.2]}
    flat = client.post("/detect", json={"cloud": {"points": encode_array(pts)}, **json_options})
    shaped = client.post("/detect", json={"cloud": {"points": encode_array(pts), "shape": [480, 640]},
                                          **json_options})
    assert flat.status_code == 200 and shaped.status_code == 200, (flat.text, shaped.text)
    assert upload.json()["num_points"] == shaped.json()["num_points"] < flat.json()["num_points"]
