"""An organised cloud's [height, width] on the wire: checked against the points as sent (422 naming cloud.shape),
and carried with the cloud to the detector as its grid (seen in the points left after preprocessing: the grid's
mixed-pixel filter drops some).  The pixel-level mapping is tested at graspd.io's entrance
(tests/io/test_organised_inputs.py)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd.core.camera import Intrinsics
from graspd.io.depth import depth_pixels, depth_points
from graspd.io.pcd import read_pcd
from graspd_client import encode_array


def organised_points(height: int = 12, width: int = 16) -> np.ndarray:
    """A wall 0.6 m in front of a camera at the origin with its right half 0.3 m farther back, one column of mixed
    pixels half way between at the step, one point per pixel (optical frame, m), the first row with no depth
    (NaN)."""
    v, u = np.mgrid[0:height, 0:width]
    z = np.where(u < width // 2, 0.6, 0.9)
    z[:, width // 2] = 0.75
    pts = np.stack([(u - width / 2) * 0.004 * z / 0.6, (v - height / 2) * 0.004 * z / 0.6, z], axis=-1)
    pts = pts.reshape(-1, 3)
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


def test_shape_counts_the_points_as_sent_before_non_finite_rows_are_dropped(client: TestClient) -> None:
    """12x16 pixels, the first row without depth (NaN): [12, 16] is right (the NaN rows count), [11, 16] (the
    finite rows only) is a 422."""
    pts = encode_array(organised_points().astype(np.float32))
    good = client.post("/detect", json={"cloud": {"points": pts, "shape": [12, 16]}, "num_samples": 5})
    assert good.status_code == 200, good.text
    bad = client.post("/detect", json={"cloud": {"points": pts, "shape": [11, 16]}, "num_samples": 5})
    assert bad.status_code == 422 and bad.json()["field"] == "cloud.shape", bad.text


def test_camera_poses_keep_the_grid(client: TestClient) -> None:
    """With a camera pose the points move into the robot frame and the grid still applies: the same points after
    preprocessing as the cloud sent already moved, with its shape, and fewer than without it (the mixed column)."""
    pose = np.eye(4)
    pose[:3, 3] = [0.125, 0.25, 0.5]
    pts = organised_points(40, 50).astype(np.float32)
    posed = client.post("/detect", json={"cloud": {
        "points": encode_array(pts), "shape": [40, 50], "camera_poses": [pose.tolist()],
        "points_frame": "camera"}, "num_samples": 5})
    moved = client.post("/detect", json={"cloud": {
        "points": encode_array((pts.astype(np.float64) + pose[:3, 3]).astype(np.float32)), "shape": [40, 50],
        "viewpoints": [pose[:3, 3].tolist()]}, "num_samples": 5})
    flat = client.post("/detect", json={"cloud": {
        "points": encode_array(pts), "camera_poses": [pose.tolist()], "points_frame": "camera"}, "num_samples": 5})
    assert posed.status_code == 200 and moved.status_code == 200 and flat.status_code == 200
    assert 0 < posed.json()["num_points"] == moved.json()["num_points"] < flat.json()["num_points"]


def test_an_organised_request_detects(client: TestClient) -> None:
    """A sent shape with NaN pixels (binary wire array) reaches detection and the answer is a normal one."""
    pts = organised_points(40, 50).astype(np.float32)
    r = client.post("/detect", json={"cloud": {"points": encode_array(pts), "shape": [40, 50]}, "num_samples": 20})
    assert r.status_code == 200, r.text
    assert "non_finite_dropped" not in [w["code"] for w in r.json()["warnings"]]  # pixels without depth: normal
    assert r.json()["num_points_received"] == len(pts) == r.json()["num_points_dropped"] + np.isfinite(pts).all(1).sum()


def test_an_organised_pcd_upload_carries_its_shape_to_the_detector(client: TestClient, real_data: Path) -> None:
    """The Kinect capture (640x480, NaN holes) uploaded as the file is: detection runs on its grid (mixed pixels
    dropped: fewer points after preprocessing than the same points sent unorganised, as many as the same points
    sent as JSON with cloud.shape [480, 640])."""
    path = real_data / "milk_cartoon_all_small_clorox.pcd"
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


@pytest.mark.parametrize(("pixels", "shape", "why"), [
    ([0, 1, 2], [12, 16], "fewer indices than points"),
    (None, None, "indices without a shape"),
    ("decreasing", [12, 16], "not increasing"),
    ("outside", [12, 16], "past the image"),
])
def test_wrong_pixels_are_a_422_naming_cloud_pixels(client: TestClient, pixels: Any, shape: list[int] | None,
                                                    why: str) -> None:
    pts = organised_points()
    finite = np.isfinite(pts).all(axis=1)
    sparse, rows = pts[finite], np.flatnonzero(finite)
    index = {"decreasing": rows[::-1], "outside": rows + 16}.get(pixels, rows) if isinstance(pixels, str | None) \
        else np.asarray(pixels)
    cloud: dict[str, Any] = {"points": encode_array(sparse.astype(np.float32)), "pixels": index.tolist()}
    if shape is not None:
        cloud["shape"] = shape
    r = client.post("/detect", json={"cloud": cloud, "num_samples": 5})
    assert r.status_code == 422, (why, r.text)
    assert r.json()["field"].startswith("cloud.pixels"), (why, r.json())


def test_a_depth_image_upload_keeps_its_grid_without_counting_pixels_with_no_depth(client: TestClient) -> None:
    """A depth image's points are only its pixels with depth: uploaded, they reach detection on the image's grid (as
    the same points sent as JSON with their shape and pixel indices, fewer than sent unorganised after the mixed
    pixels are dropped), and the pixels with no depth are not reported as dropped points."""
    pts = organised_points(40, 50)
    depth = np.nan_to_num(pts[:, 2], nan=0.0).reshape(40, 50)
    fx = 0.6 / 0.004
    png = client.post("/detect", params={"intrinsics": f"{fx},{fx},25,20", "depth_scale": "0.0001",
                                         "num_samples": "5"},
                      content=_png16(np.round(depth * 1e4).astype(np.uint16)), headers={"content-type": "image/png"})
    assert png.status_code == 200, png.text
    assert "non_finite_dropped" not in [w["code"] for w in png.json()["warnings"]], png.json()["warnings"]
    d = np.round(depth * 1e4) * 1e-4
    sparse = depth_points(d.astype(np.float32), Intrinsics(fx, fx, 25, 20))
    shaped = client.post("/detect", json={"cloud": {"points": encode_array(sparse), "shape": [40, 50],
                                                    "pixels": depth_pixels(d).tolist()}, "num_samples": 5})
    flat = client.post("/detect", json={"cloud": {"points": encode_array(sparse)}, "num_samples": 5})
    assert shaped.status_code == 200 and flat.status_code == 200, (shaped.text, flat.text)
    assert png.json()["num_points"] == shaped.json()["num_points"] < flat.json()["num_points"]


def _png16(image: np.ndarray) -> bytes:
    """A 16-bit greyscale PNG of image (H, W) uint16, as depth cameras' drivers save them."""
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()
