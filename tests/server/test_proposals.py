"""Object-proposal crops: projection geometry, window cutting, and crops in detect responses."""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from PIL import Image

from graspd.core.camera import Intrinsics, project_points
from graspd.core.cloud import ViewpointCloud
from graspd.server.services import proposals
from graspd_client import Grasps, build_detect_request

CAM = Intrinsics(fx=500.0, fy=400.0, cx=320.0, cy=240.0)


def coordinate_image(h: int = 480, w: int = 640) -> np.ndarray:
    """R = column mod 256, G = row mod 256, B = 7: every pixel says where it is."""
    v, u = np.mgrid[0:h, 0:w]
    return np.stack([u % 256, v % 256, np.full_like(u, 7)], axis=-1).astype(np.uint8)


def test_projection_of_known_points() -> None:
    pose = np.eye(4)
    pts = np.array([[0.0, 0.0, 1.0], [0.1, -0.2, 2.0], [0.0, 0.0, -1.0]])
    px, front = project_points(pts, pose, CAM)
    assert np.allclose(px[0], [320, 240]) and np.allclose(px[1], [320 + 500 * 0.05, 240 - 400 * 0.1])
    assert front.tolist() == [True, True, False] and np.isnan(px[2]).all()
    # a camera 1 m along +x of the cloud frame, looking back along -x: p_cam = R^T (p - t)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    pose[:3, 3] = [1.0, 0.0, 0.0]
    px, front = project_points(np.array([[0.0, 0.0, 0.0]]), pose, CAM)
    assert front[0] and np.allclose(px[0], [320, 240])


def test_finger_centre_is_half_depth_along_approach() -> None:
    c = proposals.finger_centres(np.array([[1.0, 2.0, 3.0]]), np.array([[0.0, 0.0, 1.0]]), 0.06)
    assert np.allclose(c, [[1.0, 2.0, 3.03]])


def test_crop_windows_centre_and_border() -> None:
    img = coordinate_image()
    pixels = np.array([[100.0, 50.0], [2.0, 3.0], [np.nan, np.nan]])
    crops = proposals.crop_windows(img, pixels, 21)
    assert crops.shape == (3, 21, 21, 3)
    assert tuple(crops[0, 10, 10]) == (100, 50, 7) and tuple(crops[0, 0, 0]) == (90, 40, 7)
    assert tuple(crops[1, 10, 10]) == (2, 3, 7) and (crops[1, :7, :] == 0).all()  # rows above the image
    assert (crops[2] == 0).all()
    inside = proposals.inside_image(np.array([[0.0, 0.0], [639.4, 479.4], [640.0, 10.0], [np.nan, 1.0]]), 480, 640)
    assert inside.tolist() == [True, True, False, False]


def _png_array(b: bytes) -> np.ndarray:
    return np.array(Image.open(io.BytesIO(b)))


def camera_behind(dx: float = 0.0) -> np.ndarray:
    """Camera-to-cloud pose of a camera 0.5 m along -z of the (origin-centred) krylon can, looking along +z."""
    pose = np.eye(4)
    pose[:3, 3] = [dx, 0.0, -0.5]
    return pose


def test_crops_in_detect_response(client: TestClient, krylon: ViewpointCloud) -> None:
    img = coordinate_image()
    body = build_detect_request(krylon.points, krylon.viewpoints, num_samples=60, image=img,
                                intrinsics=(CAM.fx, CAM.fy, CAM.cx, CAM.cy), camera_pose=camera_behind(), crop_size=64)
    r = client.post("/detect", json=body)
    assert r.status_code == 200, r.text
    g = Grasps.from_response(r.json())
    assert len(g) > 0 and g.in_image.all() and "crops" in g.timings
    centres = proposals.finger_centres(g.positions, g.approach, r.json()["hand"]["hand_depth"])
    expected, _ = project_points(centres, camera_behind(), CAM)
    assert np.allclose(g.crop_pixels, expected)
    for crop, (u, v) in zip(g.crops, np.round(expected).astype(int), strict=True):
        assert crop is not None
        a = _png_array(crop)
        assert a.shape == (64, 64, 3) and tuple(a[32, 32]) == (u % 256, v % 256, 7)
    # the same image as PNG gives the same crops

    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    body2 = build_detect_request(krylon.points, krylon.viewpoints, num_samples=60, image=buf.getvalue(),
                                 intrinsics=(CAM.fx, CAM.fy, CAM.cx, CAM.cy), camera_pose=camera_behind(), crop_size=64)
    g2 = Grasps.from_response(client.post("/detect", json=body2).json())
    assert [_png_array(c).tolist() for c in g2.crops if c] == [_png_array(c).tolist() for c in g.crops if c]


def test_points_outside_the_image_say_so(client: TestClient, krylon: ViewpointCloud,
                                         small_body: Callable[..., dict[str, Any]]) -> None:
    pose = camera_behind(5.0)  # camera 5 m to the side: the can projects far left of the image
    body = small_body(krylon, image=np.zeros((48, 64, 3), np.uint8), intrinsics={"fx": 50, "fy": 50, "cx": 32,
                      "cy": 24}, camera_pose=pose)
    out = client.post("/detect", json=body).json()
    assert out["grasps"]
    for g in out["grasps"]:
        assert g["crop"]["in_image"] is False and g["crop"]["png"] is None and g["crop"]["pixel"][0] < 0
    no_crops = client.post("/detect", json=small_body(krylon)).json()
    assert all("crop" not in g for g in no_crops["grasps"])
